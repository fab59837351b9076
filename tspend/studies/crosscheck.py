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
from tspend.runtime.errors import ScenarioError
from tspend.loop.runner import StopRequest
from tspend.loop.simulation import build_plant, run
from tspend.loop.sinks import Sink
from tspend.plants.domain import CHIRP_F0_HZ, CHIRP_F1_HZ, Domain
from tspend.plants.registry import DOMAINS, domain_of
from tspend.studies.crosscheck_openloop import chirp_force, open_loop_compare
from tspend.task import TERMINATIONS


#: the open loop's tolerance on every state (the report's ``open_loop_within_tol_s``)
OPEN_LOOP_TOL = 1e-8
#: the least open loop, s, a verdict may rest on: less (a joint at its limit or a contact
#: at the start, say) is "inconclusive", never "agrees"
MIN_COMPARED_S = 0.5


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
    disturbance, ``open_loop_max_d<state name>``, up to the first time MuJoCo applies a
    constraint the ODE does not have (a joint limit, a contact): ``open_loop_compared_s``
    and ``open_loop_stopped_by`` say when and which."""
    domain, mj_kind, _ = backends(scenario)
    # the machine itself: effects (actuator, rail, noise) stay out of the open loop
    mj = build_plant(scenario, mj_kind).underlying()
    # the ODE of the very machine MuJoCo compiled
    ode = domain.ode_of(mj)
    amplitude = domain.chirp_amplitude(mj)
    dist = scenario.disturbance

    def force(t: float) -> float:
        return chirp_force(t, amplitude, CHIRP_F0_HZ, CHIRP_F1_HZ, duration)

    def disturbance(t: float) -> float:
        return float(dist(np.array([t]))[0])

    cmp = open_loop_compare(mj, ode, np.asarray(scenario.plant.x0, dtype=float), force,
                            disturbance, duration, scenario.run.dt)
    tracked = domain.view_names(mj)[0]
    from tspend.plants.articulated.tree import INTEGRATOR_NAMES

    integrator = mj.mj_model().opt.integrator  # type: ignore[attr-defined]
    out: dict = {"open_loop_duration": duration, "open_loop_tracked": tracked,
                 # the ODE twin is stepped by RK4 (tspend.plants.analytic)
                 "mujoco_integrator": INTEGRATOR_NAMES.get(integrator, str(int(integrator))),
                 "open_loop_compared_s": cmp.compared_until,
                 "open_loop_stopped_by": cmp.stopped_by}
    out.update({f"open_loop_max_d{name}": float(v) for name, v in zip(cmp.names, cmp.max_diff)})
    out["open_loop_max_tracked"] = cmp.max_of(tracked)
    diff = np.max(np.abs(cmp.state_a - cmp.state_b), axis=1)
    over = np.flatnonzero(~(diff <= OPEN_LOOP_TOL))
    out["open_loop_within_tol_s"] = float(cmp.t[over[0] - 1]) if over.size else cmp.compared_until
    if domain.derives_equations:
        from tspend.studies.crosscheck_derived import accelerations_check, free_motion

        out.update(accelerations_check(mj))
        out.update(free_motion(mj, domain.ode_of(mj), np.asarray(scenario.plant.x0, dtype=float),
                               scenario.run.dt))
    out["ode_params"] = ode.parameters()
    # only what the ODE leaves out can explain a difference
    out["departures"] = mj.unmodelled(scenario.run.dt)
    return out


def parting(t: np.ndarray, a: np.ndarray, b: np.ndarray, tol: float) -> tuple[float | None, float]:
    """``(first time |a - b| > tol on any column, max |a - b|)``; None: they never part."""
    if not len(t):
        return None, math.nan
    diff = np.abs(a - b).max(axis=1)
    over = np.flatnonzero(~(diff <= tol))
    return (float(t[over[0]]) if over.size else None), float(np.nanmax(diff))


def closed_loop(scenario: Scenario, sinks: Sequence[Sink] = (),
                stop: StopRequest | None = None, tol: float = 1e-8) -> dict:
    """The scenario's closed loop on both backends; sinks[0] sees MuJoCo, sinks[1] the ODE.
    ``closed_loop_parted_at_s``: the first time the views differ by more than ``tol``
    (None: never), ``closed_loop_max_d<view name>`` the largest difference."""
    domain, mj_kind, ode_kind = backends(scenario)
    mj_sinks = [sinks[0]] if len(sinks) > 0 else []
    ode_sinks = [sinks[1]] if len(sinks) > 1 else []
    a = run(scenario, sinks=mj_sinks, plant_kind=mj_kind, stop=stop)
    b = run(scenario, sinks=ode_sinks, plant_kind=ode_kind, stop=stop)
    k = min(len(a.history.get("t", ())), len(b.history.get("t", ())))
    if k and (a.status in TERMINATIONS or b.status in TERMINATIONS):
        # the step into a joint's limit already felt MuJoCo's constraint (the ODE has none)
        k -= 1
    xa, xb = a.history["x"][:k], b.history["x"][:k]
    diff = np.abs(xa - xb) if k else np.full((1, len(domain.task.view)), math.nan)
    parted, _ = parting(a.history["t"][:k] if k else np.zeros(0), xa, xb, tol)
    out: dict = {"closed_loop_duration": scenario.run.duration, "closed_loop_tol": tol,
                 "closed_loop_parted_at_s": parted}
    out.update({f"closed_loop_max_d{name}": float(diff[:, i].max())
                for i, name in enumerate(domain.view_names(a.plant))})
    out.update({
        "closed_loop_status_mujoco": a.status, "closed_loop_status_ode": b.status,
        "closed_loop_rmse_ss_mujoco": a.metrics["rmse_ss"],
        "closed_loop_rmse_ss_ode": b.metrics["rmse_ss"],
        "closed_loop_metrics_mujoco": a.metrics, "closed_loop_metrics_ode": b.metrics,
    })
    return out


def crosscheck(scenario: Scenario, sinks: Sequence[Sink] = (), open_loop_duration: float = 10.0,
               stop: StopRequest | None = None, tol: float = 1e-8) -> dict:
    """Both parts of the cross-check as one flat report (the CLI's JSON), with its verdict."""
    report = {"scenario": scenario.name, "dt": scenario.run.dt,
              "boundary_layer": scenario.controller.boundary_layer}
    report.update(open_loop(scenario, open_loop_duration))
    report.update(closed_loop(scenario, sinks, stop, tol))
    report["tolerance"] = tol
    report["open_loop_min_compared_s"] = MIN_COMPARED_S
    report["inconclusive"] = bool(report["open_loop_compared_s"] < MIN_COMPARED_S)
    report["open_loop_ok"] = bool(report["open_loop_max_tracked"] <= tol)
    if "accel_ok" in report:
        # a chain of poles is chaotic: the chirp's open loop must agree for FREE_MIN_S (or
        # all it compared), the accelerations everywhere, the free motion as (d) says
        from tspend.studies.crosscheck_derived import FREE_MIN_S

        chirp_ok = report["open_loop_within_tol_s"] >= min(FREE_MIN_S, report["open_loop_compared_s"])
        report["open_loop_ok"] = bool(chirp_ok and report["accel_ok"] and report["free_ok"])
    if report.get("accel_inconclusive"):
        # too few random states free of limits and contacts to judge the equations by
        report["inconclusive"] = True
    if report["inconclusive"]:
        # nothing (or too little) was compared: no agreement can be claimed
        report["open_loop_ok"] = False
    report["verdict"] = verdict(report)
    return report


def verdict(report: dict) -> str:
    """The cross-check's finding in words: the open loop (how far it was compared, what
    ended it), the closed loop (when and by how much the backends part) and, on a
    failure, the departures the ODE leaves out."""
    tol = report.get("tolerance", 1e-8)
    tracked = report.get("open_loop_tracked", "x1")
    worst = max((v for k, v in report.items() if k.startswith("open_loop_max_d")
                 and isinstance(v, float)), default=math.nan)
    word = ("INCONCLUSIVE" if report.get("inconclusive")
            else "agrees" if report.get("open_loop_ok") else "DISAGREES")
    compared_s = report.get("open_loop_compared_s", 0.0)
    # a verdict states only what was compared: with nothing compared, no difference (nan)
    # and no claim on how the backends part
    open_part = (f"open loop {word}: nothing compared" if compared_s == 0.0 else
                 f"open loop {word}: max "
                 f"|d{tracked}| = {report.get('open_loop_max_tracked', math.nan):.3g} (every "
                 f"state within {worst:.3g}) over {compared_s:.6g} s")
    if report.get("open_loop_stopped_by"):
        open_part += f", compared up to {report['open_loop_stopped_by']} (the ODE has no limits or contacts)"
    if "accel_ok" in report and report.get("open_loop_within_tol_s", 0.0) < report.get("open_loop_compared_s", 0.0):
        open_part += (f"; every state within {OPEN_LOOP_TOL:g} for the first "
                      f"{report['open_loop_within_tol_s']:.4g} s (the chirp drives a chaotic chain)")
    short = report.get("open_loop_compared_s", 0.0) < report.get("open_loop_min_compared_s",
                                                                     MIN_COMPARED_S)
    if report.get("inconclusive") and short:
        compared = report.get("open_loop_compared_s", 0.0)
        if "nothing compared" not in open_part:
            open_part += "; nothing compared" if compared == 0.0 else f"; only {compared:.4g} s compared"
        open_part += (f" (a verdict needs at least {report.get('open_loop_min_compared_s', MIN_COMPARED_S):g} s "
                      f"of open loop before MuJoCo applies a constraint the ODE does not have)")
    integrator = report.get("mujoco_integrator", "RK4")
    parts = []
    if integrator != "RK4" and compared_s > 0.0:
        # the backends part at the first step: nothing else can be judged before this
        parts.append(f"MuJoCo steps the model with {integrator}, the ODE with RK4: the backends "
                     f"part from the first step by the integrators' truncation error "
                     f"(plant.integrator = \"RK4\" compares the equations)")
        open_part = open_part.replace(" (the chirp drives a chaotic chain)", "")
    parts.append(open_part)
    if "accel_max_diff" in report:
        drawn = report.get("accel_drawn", report["accel_states"])
        skipped = report.get("accel_skipped", 0)
        accel = (f"derived accelerations vs mj_forward: max {report['accel_max_diff']:.3g} "
                 f"(relative above 1) at {report['accel_states']} of {drawn} random states")
        if skipped:
            accel += (f" ({skipped} skipped: MuJoCo applies a limit or contact there, e.g. "
                      f"{report.get('accel_skipped_first', '')})")
        if report.get("accel_inconclusive"):
            accel += (f"; INCONCLUSIVE: a verdict on the equations needs at least "
                      f"{report.get('accel_min_states', 0)} states compared")
        parts.append(accel)
        parts.append(f"free motion from the start: every state within {report['free_tight']:g} for "
                     f"{report['free_within_tight_s']:.4g} s, within {report['free_loose']:g} for "
                     f"{report['free_within_loose_s']:.4g} s of {report['free_compared_s']:.4g} s compared"
                     + (f" (then {report['free_stopped_by']})" if report['free_stopped_by'] else "")
                     + ("" if integrator != "RK4" else
                        "; a chain of poles is chaotic: the backends part as round-off grows"))
    if not report.get("open_loop_ok") and not report.get("inconclusive"):
        parts.append(failure_reason(report))
    if "closed_loop_parted_at_s" in report:
        parted = report["closed_loop_parted_at_s"]
        status = (report.get("closed_loop_status_mujoco"), report.get("closed_loop_status_ode"))
        biggest = max((v for k, v in report.items() if k.startswith("closed_loop_max_d")
                       and isinstance(v, float)), default=math.nan)
        if parted is None:
            parts.append(f"closed loop: the backends stay within {tol:g} (max {biggest:.3g})")
        else:
            parts.append(f"closed loop: the backends part at t = {parted:.6g} s (difference > "
                         f"{tol:g}) and differ by up to {biggest:.3g}")
        if status[0] != status[1]:
            parts.append(f"closed loop ends differ: MuJoCo {status[0]}, ODE {status[1]}")
    return "; ".join(parts)


def failure_reason(report: dict) -> str:
    """Why an open-loop cross-check can fail: what the ODE leaves out of the model."""
    lines = report.get("departures") or []
    if not lines:
        return ("the model holds nothing the ODE leaves out: a bug in one of the backends "
                "(no departure found)")
    return "the ODE leaves out: " + "; ".join(lines)
