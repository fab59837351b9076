"""Two more figures of the cross-check for machines whose equations are derived from the MJCF.

(c) **Accelerations**: the derived ``q''(q, q', u)`` (:mod:`tspend.plants.articulated.derive`)
against MuJoCo's own ``mj_forward`` ``qacc`` at many random states: every angle over the
full circle (a limited joint within its range, where MuJoCo's limit does not act), rates
up to ``RATE_MAX``, inputs over the actuator's range.  The difference is relative to the acceleration where that exceeds 1
(absolute below): it measures the equations, free of any integration.  A state at which
MuJoCo applies a constraint the equations do not have (a joint within its limit's margin,
a contact), judged from that state's own ``mj_forward``, is skipped and counted; fewer
than ``ACCEL_MIN_STATES`` compared states is no verdict (``accel_inconclusive``).
(d) **Free motion**: both backends from the scenario's start with no input; every state
within ``TIGHT`` for the first ``FREE_MIN_S`` seconds, and how long they stay within
``LOOSE``.  On such machines the chirp of the open loop (a) is judged the same way: it
must agree within the tolerance for ``FREE_MIN_S`` (``open_loop_within_tol_s`` says how
long it did).  A chain of two or more poles is chaotic once it swings: round-off at 1e-16
grows by a factor of e every Lyapunov time, so the backends part at last; the figure
says when, the cross-check does not fail on it.
"""

from __future__ import annotations

import math

import numpy as np

from tspend.plants.base import MachinePlant, Plant, read_as
from tspend.studies.crosscheck_openloop import open_loop_compare

__all__ = ["accelerations_check", "free_motion", "RATE_MAX", "TIGHT", "LOOSE", "FREE_MIN_S",
           "ACCEL_TOL", "ACCEL_STATES", "ACCEL_MIN_STATES"]

#: the largest joint rate drawn, rad/s (or m/s)
RATE_MAX = 20.0
#: the derived accelerations must agree with mj_forward to this (relative above 1)
ACCEL_TOL = 1e-9
#: random states drawn, and the least of them compared (no limit or contact acting) that a
#: verdict on the accelerations may rest on
ACCEL_STATES, ACCEL_MIN_STATES = 1000, 100
#: free motion: every state within TIGHT for FREE_MIN_S, then how long within LOOSE
TIGHT, LOOSE, FREE_MIN_S = 1e-10, 1e-6, 1.0


def accelerations_check(plant: Plant, n_states: int = ACCEL_STATES, seed: int = 0,
                        min_states: int = ACCEL_MIN_STATES) -> dict:
    """The largest difference between the derived accelerations of ``plant``'s machine and
    ``mj_forward`` over ``n_states`` random states (module docstring, (c)), on a data of
    its own: neither the plant's state nor where an earlier test left it matters."""
    import mujoco

    from tspend.plants.mujoco_plant import active_constraint

    machine = read_as(plant, MachinePlant).machine
    model = plant.mj_model()
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    nv = machine.nv
    a = machine.actuator
    act = plant._act  # type: ignore[attr-defined]
    lo, hi = a.ctrlrange if a.ctrlrange is not None else (-10.0, 10.0)
    worst, worst_abs = 0.0, 0.0
    compared, skipped = 0, 0
    first_skip = ""
    for _ in range(n_states):
        q = np.empty(nv)
        for j, jf in enumerate(machine.tree.joints):
            # within a limited joint's range (MuJoCo's limit would act beyond it)
            r = jf.range or ((-math.pi, math.pi) if jf.kind == "hinge" else (-1.0, 1.0))
            q[j] = rng.uniform(r[0], r[1])
        qd = rng.uniform(-RATE_MAX, RATE_MAX, nv)
        u = rng.uniform(lo, hi)
        mujoco.mj_resetData(model, data)
        data.qpos[:], data.qvel[:] = q, qd
        data.ctrl[act] = u
        mujoco.mj_forward(model, data)
        # this state's own limits and contacts (mj_forward just found them in ``data``)
        active = active_constraint(model, data) if data.nefc else ""
        if active:
            skipped += 1
            first_skip = first_skip or active
            continue  # a limit or contact acting: the derived equations do not hold
        compared += 1
        mine = machine.accelerations(np.concatenate([q, qd]), u)
        diff = np.abs(mine - data.qacc)
        worst = max(worst, float(np.max(diff / np.maximum(1.0, np.abs(data.qacc)))))
        worst_abs = max(worst_abs, float(np.max(diff)))
    inconclusive = compared < min_states
    return {"accel_states": compared, "accel_drawn": int(n_states), "accel_skipped": skipped,
            "accel_skipped_first": first_skip, "accel_min_states": int(min_states),
            "accel_rate_max": RATE_MAX,
            "accel_max_diff": worst if compared else math.nan,
            "accel_max_abs_diff": worst_abs if compared else math.nan,
            "accel_tol": ACCEL_TOL, "accel_inconclusive": bool(inconclusive),
            "accel_ok": bool(not inconclusive and worst <= ACCEL_TOL)}


def free_motion(mj: Plant, ode: Plant, x0: np.ndarray, dt: float, duration: float = 10.0) -> dict:
    """Both backends from ``x0`` with no input (module docstring, (d))."""
    cmp = open_loop_compare(mj, ode, x0, lambda t: 0.0, lambda t: 0.0, duration, dt)
    diff = np.max(np.abs(cmp.state_a - cmp.state_b), axis=1)

    def within(tol: float) -> float:
        over = np.flatnonzero(~(diff <= tol))
        return float(cmp.t[over[0] - 1]) if over.size else cmp.compared_until

    first = cmp.t <= FREE_MIN_S + 1e-12
    tight_s, loose_s = within(TIGHT), within(LOOSE)
    return {"free_compared_s": cmp.compared_until, "free_stopped_by": cmp.stopped_by,
            "free_max_diff_first_s": float(diff[first].max()) if first.any() else math.nan,
            "free_within_tight_s": tight_s, "free_within_loose_s": loose_s,
            "free_tight": TIGHT, "free_loose": LOOSE,
            "free_ok": bool(tight_s >= min(FREE_MIN_S, cmp.compared_until) and cmp.compared_until > 0)}
