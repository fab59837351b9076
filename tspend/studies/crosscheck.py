"""Cross-check a domain's MuJoCo plant against its analytic ODE (docs/paper-notes.md section 7).

(a) Open loop: both backends from the scenario's x0 under the same chirp force and the
scenario's disturbance, held over each sample; the two are exact models of one machine,
so with RK4 at 1 ms they agree to ~1e-11 rad.
(b) Closed loop: the scenario's controller on each backend.  sign() in the compensator
can amplify round-off differences, so the closed loops may drift apart by more than
the open loop does: the report gives the figure, and its tracking metrics on each.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from tspend.config import Scenario
from tspend.errors import ScenarioError
from tspend.loop.runner import StopRequest
from tspend.loop.simulation import build_plant, run
from tspend.loop.sinks import Sink
from tspend.plants.domain import Domain
from tspend.plants.effects import EffectsPlant
from tspend.plants.registry import DOMAINS, domain_of
from tspend.studies.crosscheck_openloop import chirp_force, open_loop_compare


def backends(scenario: Scenario) -> tuple[Domain, str, str]:
    """``(domain, mujoco kind, ode kind)`` of the scenario's plant; ScenarioError when its
    domain has not both backends."""
    domain = domain_of(scenario.plant.kind)
    mj, ode = domain.mujoco_kind(), domain.ode_kind()
    if mj is None or ode is None:
        both = [k for d in DOMAINS.values() if d.mujoco_kind() and d.ode_kind() for k in d.kinds]
        raise ScenarioError(f"{scenario.path}: plant.kind: the cross-check needs a plant with "
                            f"a MuJoCo and an analytic backend ({', '.join(both)}), got "
                            f"'{scenario.plant.kind}'")
    return domain, mj, ode


def open_loop(scenario: Scenario, duration: float = 10.0) -> dict:
    """Max differences of every state between the backends under the same force and
    disturbance: ``open_loop_max_d<state name>``."""
    domain, mj_kind, _ = backends(scenario)
    # the machine itself: effects (actuator, rail, noise) stay out of the open loop
    mj = build_plant(scenario, mj_kind)
    if isinstance(mj, EffectsPlant):
        mj = mj.inner
    # the ODE of the very machine MuJoCo compiled
    ode = domain.ode_of(mj)
    amplitude = domain.chirp_amplitude(mj)
    dist = scenario.disturbance

    def force(t: float) -> float:
        return chirp_force(t, amplitude, 0.1, 2.0, duration)

    def disturbance(t: float) -> float:
        return float(dist(np.array([t]))[0])

    cmp = open_loop_compare(mj, ode, np.asarray(scenario.plant.x0, dtype=float), force,
                            disturbance, duration, scenario.run.dt)
    tracked = domain.view_names(mj)[0]
    out: dict = {"open_loop_duration": duration, "open_loop_tracked": tracked}
    out.update({f"open_loop_max_d{name}": float(v) for name, v in zip(cmp.names, cmp.max_diff)})
    out["open_loop_max_tracked"] = cmp.max_of(tracked)
    out["ode_params"] = ode.parameters()
    out["departures"] = mj.departures(scenario.run.dt)  # type: ignore[attr-defined]
    return out


def closed_loop(scenario: Scenario, sinks: Sequence[Sink] = (),
                stop: StopRequest | None = None) -> dict:
    """The scenario's closed loop on both backends; sinks[0] sees MuJoCo, sinks[1] the ODE."""
    domain, mj_kind, ode_kind = backends(scenario)
    mj_sinks = [sinks[0]] if len(sinks) > 0 else []
    ode_sinks = [sinks[1]] if len(sinks) > 1 else []
    a = run(scenario, sinks=mj_sinks, plant_kind=mj_kind, stop=stop)
    b = run(scenario, sinks=ode_sinks, plant_kind=ode_kind, stop=stop)
    k = min(len(a.history.get("t", ())), len(b.history.get("t", ())))
    xa, xb = a.history["x"][:k], b.history["x"][:k]
    diff = np.abs(xa - xb) if k else np.full((1, len(domain.task.view)), math.nan)
    out: dict = {"closed_loop_duration": scenario.run.duration}
    out.update({f"closed_loop_max_d{name}": float(diff[:, i].max())
                for i, name in enumerate(domain.task.view)})
    out.update({
        "closed_loop_status_mujoco": a.status, "closed_loop_status_ode": b.status,
        "closed_loop_rmse_ss_mujoco": a.metrics["rmse_ss"],
        "closed_loop_rmse_ss_ode": b.metrics["rmse_ss"],
        "closed_loop_metrics_mujoco": a.metrics, "closed_loop_metrics_ode": b.metrics,
    })
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
