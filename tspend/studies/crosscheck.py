"""Cross-check the MuJoCo cart-pole against the analytic ODE (docs/paper-notes.md section 7).

(a) Open loop: both backends from the scenario's x0 under the same chirp force and the
scenario's disturbance, held over each sample; the two are exact models of one machine,
so with RK4 at 1 ms they agree to ~1e-11 rad.
(b) Closed loop: the scenario's controller on each backend.  sign() in the compensator
can amplify round-off differences, so the closed loops may drift apart by more than
the open loop does: the report gives the figure, and its tracking metrics on each.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

from tspend.config import CartPoleConfig, Scenario
from tspend.studies.crosscheck_openloop import chirp_force, open_loop_compare
from tspend.errors import ScenarioError
from tspend.loop.runner import StopRequest
from tspend.plants.analytic import cartpole_ode_plant
from tspend.loop.simulation import build_plant, run
from tspend.loop.sinks import Sink

#: the open-loop force: a chirp 0.1 -> 2 Hz whose amplitude scales with the total mass
CHIRP_N_PER_KG = 100.0 / 11.0


def _require_cartpole(scenario: Scenario) -> None:
    if not isinstance(scenario.plant, CartPoleConfig):
        raise ScenarioError(f"{scenario.path}: plant.kind: the cross-check needs a cart-pole "
                            f"scenario (cartpole_mujoco or cartpole_ode), got "
                            f"'{scenario.plant.kind}'")


def open_loop(scenario: Scenario, duration: float = 10.0) -> dict:
    """Max differences between the backends under the same force and disturbance."""
    _require_cartpole(scenario)
    # the machine itself: effects (actuator, rail, noise) stay out of the open loop
    mj = build_plant(scenario, "cartpole_mujoco")
    mj = getattr(mj, "inner", mj)
    # the ODE of the very machine MuJoCo compiled (masses, inertia, damping, gear, sign)
    params = mj.params  # type: ignore[attr-defined]
    ode = cartpole_ode_plant(params)
    p = scenario.plant
    amplitude = CHIRP_N_PER_KG * (params.M + params.m) / abs(params.gear)
    dist = scenario.disturbance

    def force(t: float) -> float:
        return chirp_force(t, amplitude, 0.1, 2.0, duration)

    def disturbance(t: float) -> float:
        return float(dist(np.array([t]))[0])

    cmp = open_loop_compare(mj, ode, np.asarray(p.x0, dtype=float), force, disturbance,
                            duration, scenario.run.dt)
    return {"open_loop_duration": duration, "open_loop_max_dtheta": cmp.max_dtheta,
            "open_loop_max_dthetadot": cmp.max_dthetadot,
            "open_loop_max_dcart_pos": cmp.max_dcart_pos,
            "ode_params": dataclasses.asdict(params),
            "departures": mj.departures(scenario.run.dt)}  # type: ignore[attr-defined]


def closed_loop(scenario: Scenario, sinks: Sequence[Sink] = (),
                stop: StopRequest | None = None) -> dict:
    """The scenario's closed loop on both backends; sinks[0] sees MuJoCo, sinks[1] the ODE."""
    _require_cartpole(scenario)
    mj_sinks = [sinks[0]] if len(sinks) > 0 else []
    ode_sinks = [sinks[1]] if len(sinks) > 1 else []
    a = run(scenario, sinks=mj_sinks, plant_kind="cartpole_mujoco", stop=stop)
    b = run(scenario, sinks=ode_sinks, plant_kind="cartpole_ode", stop=stop)
    k = min(len(a.history.get("t", ())), len(b.history.get("t", ())))
    xa, xb = a.history["x"][:k], b.history["x"][:k]
    diff = np.abs(xa - xb) if k else np.full((1, 2), math.nan)
    out = {
        "closed_loop_duration": scenario.run.duration,
        "closed_loop_max_dtheta": float(diff[:, 0].max()),
        "closed_loop_max_dthetadot": float(diff[:, 1].max()),
        "closed_loop_status_mujoco": a.status, "closed_loop_status_ode": b.status,
        "closed_loop_rmse_ss_mujoco": a.metrics["rmse_ss"],
        "closed_loop_rmse_ss_ode": b.metrics["rmse_ss"],
        "closed_loop_metrics_mujoco": a.metrics, "closed_loop_metrics_ode": b.metrics,
    }
    return out


def crosscheck(scenario: Scenario, sinks: Sequence[Sink] = (), open_loop_duration: float = 10.0,
               stop: StopRequest | None = None) -> dict:
    """Both parts of the cross-check as one flat report (the CLI's JSON)."""
    report = {"scenario": scenario.name, "dt": scenario.run.dt,
              "boundary_layer": scenario.controller.boundary_layer}
    report.update(open_loop(scenario, open_loop_duration))
    report.update(closed_loop(scenario, sinks, stop))
    return report


def failure_reason(report: dict) -> str:
    """Why an open-loop cross-check can fail: the model's departures the ODE cannot follow."""
    lines = report.get("departures") or []
    if not lines:
        return "no departure from the ODE found in the model: a bug in one of the backends"
    return "the model departs from the ODE: " + "; ".join(lines)
