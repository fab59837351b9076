"""Trajectory optimisation: a planned swing-up to the upright by direct multiple shooting.

From an initial state ``s_0`` to the upright at rest ``s_T = 0`` (every joint at 0, the
cart at the rail's centre) in a fixed time ``T = N h``, the input held over each
interval ``h`` (zero-order hold, as the loop applies it), this solves (Bock and Plitt,
1984; Betts, *Practical Methods for Optimal Control*, 2nd ed., 2010, sec. 4.5):

    min  sum_{k<N} h (u_k / u_s)^2                                          (T1)
    s.t. s_{k+1} = F(s_k, u_k)   (k < N),   s_0 given,   s_N = 0,           (T2)
                                   (s_0 and s_N as bounds: met exactly)
         u_lo <= u_k <= u_hi,   q_lo + margin <= q_k <= q_hi - margin        (T3)

``u_s`` is the actuator's range (``max(|u_lo|, |u_hi|)``, 1 when unbounded), so (T1) is
the input's energy in units of the actuator's range.  ``F`` is ``h / dt`` steps of the
classical RK4 at the run's step ``dt`` of the domain's own equations (the
:class:`~tspend.plants.domain.FullModel`'s CasADi form, the one :mod:`.mpc` uses): the
integrator the analytic plants use and MuJoCo's ``RK4`` option, so a plan's states are
what the simulated machine does under its inputs up to round-off.  The NLP is solved by
IPOPT (CasADi's ``nlpsol``); the single-step map is a CasADi ``Function`` over SX,
``mapaccum`` chains it over one interval and ``map`` over the horizon.

The plan handed back (:class:`Plan`) is on the fine grid ``dt``: the states inside each
interval integrated from the solver's node by the same RK4 (so the fine grid is
continuous up to the solver's constraint tolerance), the input held.  An angle that
wraps may start at ``theta`` or ``theta - 2 pi`` (the same physical state): the
transcription tries the representation nearest zero first, then the other.
"""

from __future__ import annotations

import contextlib
import io
import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from tspend.runtime.errors import ScenarioError

if TYPE_CHECKING:
    from tspend.plants.domain import FullModel

__all__ = ["Plan", "PlanFailed", "plan_swingup", "read_plan", "write_plan",
           "PLAN_FORMAT"]

#: a bound IPOPT treats as none
_FREE = 1e19
#: the plan file's format tag (Parquet key-value metadata ``tspend:format``)
PLAN_FORMAT = "tspend-plan-1"


class PlanFailed(RuntimeError):
    """The solver found no plan (its status says why); nothing is written."""


class PlanStopped(PlanFailed):
    """The solve was cut short, not finished: a signal (CasADi turns the exception a
    signal handler raises inside IPOPT's iteration callback into the status below) or an
    error in an evaluation.  No other start is tried: the caller honours the signal."""


#: IPOPT's status when an exception left its callbacks (a signal handler's, among them)
_STOPPED = "NonIpopt_Exception_Thrown"


@dataclass
class Plan:
    """A planned trajectory on the fine grid ``dt``: ``t`` (n,), ``states`` (n, nx) named
    ``state_names`` in ``state_units``, ``u`` (n,) held over ``[t_i, t_i + dt)`` (the last
    row's is the upright's 0), and the solver's figures."""

    t: np.ndarray
    states: np.ndarray
    u: np.ndarray
    state_names: tuple[str, ...]
    state_units: tuple[str, ...]
    u_name: str
    u_unit: str
    dt: float
    interval: float
    solver: dict[str, Any] = field(default_factory=dict)

    @property
    def horizon(self) -> float:
        return float(self.t[-1] - self.t[0])


def _bounds(model: "FullModel", margin: float) -> tuple[np.ndarray, np.ndarray, float, float]:
    lo, hi = np.full(model.size, -_FREE), np.full(model.size, _FREE)
    for j in range(model.dof):
        if math.isfinite(model.q_lo[j]):
            lo[j] = model.q_lo[j] + margin
        if math.isfinite(model.q_hi[j]):
            hi[j] = model.q_hi[j] - margin
    u_lo = model.u_lo if math.isfinite(model.u_lo) else -_FREE
    u_hi = model.u_hi if math.isfinite(model.u_hi) else _FREE
    return lo, hi, u_lo, u_hi


def check_plan_input(model: "FullModel", s0: np.ndarray, horizon: float, interval: float,
                     dt: float, margin: float, where: str, step: float | None = None) -> int:
    """The number of intervals ``N`` (the horizon rounded to whole intervals); ScenarioError
    (one line) for what no solver can fix: an interval not a whole number of steps,
    fewer than 2 intervals, a step that does not divide the interval, a problem beyond
    the bounds of :mod:`tspend.runtime.bounds` (intervals, RK4 steps, rows), a start or
    goal outside the bounds, an empty input range."""
    from tspend.runtime.bounds import (MAX_PLAN_INTERVALS, MAX_PLAN_RK4_STEPS, MAX_PLAN_ROWS,
                                       MAX_PLAN_SUBSTEPS)

    steps = interval / dt
    if steps > MAX_PLAN_ROWS:
        raise ScenarioError(f"{where}.interval: {interval:g} s is more than {MAX_PLAN_ROWS:g} "
                            f"steps of run.dt = {dt:g} s")
    if abs(steps - round(steps)) > 1e-9 * max(1.0, steps) or round(steps) < 1:
        raise ScenarioError(f"{where}.interval: must be a whole multiple of run.dt = {dt:g} s, "
                            f"got {interval:g}")
    n = horizon / interval   # rounded to whole intervals
    if round(n) < 2:
        raise ScenarioError(f"{where}.horizon: {horizon:g} s is too short: at least 2 intervals "
                            f"of {interval:g} s")
    if n > MAX_PLAN_INTERVALS or n * steps > MAX_PLAN_ROWS:
        raise ScenarioError(f"{where}.horizon: {horizon:g} s is {n:.4g} intervals of "
                            f"{interval:g} s ({n * steps:.4g} rows of {dt:g} s); at most "
                            f"{MAX_PLAN_INTERVALS} intervals and {MAX_PLAN_ROWS:g} rows")
    if step is not None:
        k = interval / step
        if k > MAX_PLAN_SUBSTEPS or round(n) * k > MAX_PLAN_RK4_STEPS:
            raise ScenarioError(f"{where}.step: {step:g} s makes {k:.4g} RK4 steps an interval "
                                f"and {round(n) * k:.4g} in all; at most {MAX_PLAN_SUBSTEPS} and "
                                f"{MAX_PLAN_RK4_STEPS}")
        if abs(k - round(k)) > 1e-9 * max(1.0, k) or round(k) < 1:
            raise ScenarioError(f"{where}.step: must divide the interval {interval:g} s into "
                                f"whole steps, got {step:g}")
    lo, hi, u_lo, u_hi = _bounds(model, margin)
    if not u_lo < u_hi:
        raise ScenarioError(f"{where}: the input's range [{model.u_lo:g}, {model.u_hi:g}] is empty")
    for j in range(model.dof):
        name = model.state_names[j]
        if lo[j] > hi[j]:
            raise ScenarioError(f"{where}.margin: {margin:g} leaves nothing of {name}'s range "
                                f"[{model.q_lo[j]:g}, {model.q_hi[j]:g}]")
        for what, v in (("the start", s0[j]), ("the upright", 0.0)):
            if not lo[j] <= v <= hi[j]:
                raise ScenarioError(f"{where}: {what} has {name} = {v:g}, outside its range "
                                    f"[{lo[j]:g}, {hi[j]:g}] (margin {margin:g} included)")
    return int(round(n))


def plan_swingup(model: "FullModel", s0: np.ndarray, horizon: float, interval: float, dt: float,
                 step: float | None = None, margin: float = 0.05, max_iter: int = 1000, tolerance: float = 1e-8,
                 where: str = "plan", units: tuple[tuple[str, ...], str, str] | None = None,
                 stopped: Any = None) -> Plan:
    """Solve (T1)-(T3) (module docstring) from ``s0``; raises :class:`PlanFailed` when
    IPOPT finds no plan from any representation of the start, ScenarioError for bad input
    (:func:`check_plan_input`).  ``units``: ``(state units, input name, input unit)``.

    ``stopped``: a callable, true once a stop was requested (a signal: the CLI's guard);
    it is asked after every solve, and :class:`PlanStopped` is raised instead of trying
    the next start or handing back a plan.  IPOPT reports a signal only as an exception
    in its callback (:data:`_STOPPED`), which ends the tries as well."""
    s0 = np.asarray(s0, dtype=float)
    step = dt if step is None else step
    N = check_plan_input(model, s0, horizon, interval, dt, margin, where, step)
    nx = model.size
    solver, lbx, ubx, n_variables = _plan_nlp(model, N, interval, step, margin, max_iter,
                                              tolerance)
    attempts = []
    for start in _representations(model, s0):
        w0 = _straight_line(model, start, N, horizon)
        started = time.perf_counter()
        lbx[:nx] = ubx[:nx] = start
        # CasADi prints, through Python's stderr, a warning for the signal it caught: the
        # command says it in its own line
        with contextlib.redirect_stderr(io.StringIO()):
            sol = solver(x0=w0, lbx=lbx, ubx=ubx, lbg=0.0, ubg=0.0)
        wall = time.perf_counter() - started
        stats = solver.stats()
        if (stopped is not None and stopped()) or stats.get("return_status") == _STOPPED:
            raise PlanStopped(f"{where}: the solve was stopped after {wall:.3g} s "
                              f"({stats.get('return_status', '')}); no plan")
        attempts.append({"status": str(stats.get("return_status", "")),
                         "iterations": int(stats.get("iter_count", 0)),
                         "solve_s": wall, "success": bool(stats.get("success", False))})
        if attempts[-1]["success"]:
            wv = np.asarray(sol["x"]).ravel()
            nodes = wv[:nx * (N + 1)].reshape(N + 1, nx)
            u_nodes = wv[nx * (N + 1):]
            defect = float(np.max(np.abs(np.asarray(sol["g"]).ravel())))
            figures = dict(attempts[-1], cost=float(sol["f"]), constraint_violation=defect,
                           attempts=len(attempts), total_solve_s=sum(a["solve_s"] for a in attempts),
                           intervals=N, nlp_variables=n_variables,
                           start_state=[float(v) for v in start])
            figures["step_s"] = float(step)
            return _fine(model, model.rk4_map(dt), nodes, u_nodes,
                         int(round(interval / dt)), dt, interval, figures, units)
    why = "; ".join(f"{a['status']} after {a['iterations']} iterations" for a in attempts)
    raise PlanFailed(f"{where}: IPOPT found no plan to the upright in {horizon:g} s ({why})")


def _plan_nlp(model: "FullModel", N: int, interval: float, step: float, margin: float,
              max_iter: int, tolerance: float) -> tuple[Any, np.ndarray, np.ndarray, int]:
    """``(IPOPT on (T1)-(T3), lbx, ubx, variables)``: ``N`` intervals of ``interval`` s,
    each ``interval / step`` RK4 steps with u held; the upright at rest the last node's
    bounds (the first node's are the start's, set per try)."""
    import casadi

    nx, K = model.size, int(round(interval / step))
    G = model.rk4_map(step)
    # one interval: K steps of G with u held (mapaccum feeds each step's output to the next)
    Gk = G.mapaccum("interval", K)
    su, uu = casadi.SX.sym("s", nx), casadi.SX.sym("u")
    F = casadi.Function("F", [su, uu], [Gk(su, casadi.repmat(uu, 1, K))[:, -1]])
    FN = F.map(N, "serial")
    S = casadi.MX.sym("S", nx, N + 1)
    U = casadi.MX.sym("U", 1, N)
    lo, hi, u_lo, u_hi = _bounds(model, margin)
    u_scale = max(abs(model.u_lo), abs(model.u_hi))
    u_scale = u_scale if math.isfinite(u_scale) and u_scale > 0 else 1.0
    cost = interval * casadi.sumsqr(U / u_scale)
    # the start and the upright are bounds on the first and last nodes (met exactly)
    g = casadi.reshape(S[:, 1:] - FN(S[:, :-1], U), -1, 1)
    w = casadi.vertcat(casadi.reshape(S, -1, 1), casadi.reshape(U, -1, 1))
    solver = casadi.nlpsol("plan", "ipopt", {"x": w, "f": cost, "g": g},
                           {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                            "ipopt.max_iter": int(max_iter), "ipopt.tol": float(tolerance)})
    lbx = np.concatenate([np.tile(lo, N + 1), np.full(N, u_lo)])
    ubx = np.concatenate([np.tile(hi, N + 1), np.full(N, u_hi)])
    lbx[nx * N:nx * (N + 1)] = ubx[nx * N:nx * (N + 1)] = 0.0
    return solver, lbx, ubx, int(w.shape[0])


def _straight_line(model: "FullModel", start: np.ndarray, N: int, horizon: float) -> np.ndarray:
    """The initial guess: the straight line from ``start`` to the upright, at rest, u = 0."""
    frac = np.linspace(0.0, 1.0, N + 1)[:, None]
    guess = (1.0 - frac) * start[None, :]
    guess[:, model.dof:] = -(start[:model.dof] / horizon)[None, :]
    guess[-1, model.dof:] = 0.0
    return np.concatenate([guess.ravel(), np.zeros(N)])


def _representations(model: "FullModel", s0: np.ndarray) -> list[np.ndarray]:
    """The start with every wrapping angle nearest 0, then with those near +/-pi flipped to
    the other side (the same physical state, the other way round)."""
    near = s0.copy()
    for j in range(model.dof):
        if model.angles[j] and not (math.isfinite(model.q_lo[j]) or math.isfinite(model.q_hi[j])):
            near[j] = math.remainder(near[j], 2.0 * math.pi)
    out = [near]
    flipped = near.copy()
    for j in range(model.dof):
        if model.angles[j] and not (math.isfinite(model.q_lo[j]) or math.isfinite(model.q_hi[j])) \
                and abs(near[j]) > math.pi / 2:
            flipped[j] -= math.copysign(2.0 * math.pi, near[j])
    if not np.array_equal(flipped, near):
        out.append(flipped)
    return out


def _fine(model: "FullModel", G: Any, nodes: np.ndarray, u_nodes: np.ndarray, K: int, dt: float,
          interval: float, figures: dict, units) -> Plan:
    """The plan on the fine grid: each interval integrated from its node."""
    N, nx = u_nodes.size, model.size
    u_fine = np.repeat(u_nodes, K)
    GK = G.mapaccum("fine", K)
    states = np.empty((N * K + 1, nx))
    for k in range(N):
        traj = np.asarray(GK(nodes[k], np.full((1, K), u_nodes[k])))
        states[k * K] = nodes[k]
        states[k * K + 1:(k + 1) * K] = traj[:, :-1].T
    states[-1] = nodes[-1]
    t = dt * np.arange(N * K + 1)
    state_units, u_name, u_unit = units if units is not None else (("",) * nx, "u", "")
    return Plan(t, states, np.append(u_fine, 0.0), tuple(model.state_names), tuple(state_units),
                u_name, u_unit, float(dt), float(interval), figures)


def write_plan(plan: Plan, path: Any) -> None:
    """The plan as Parquet: columns ``t``, every state by name, ``u``; the units, the grid
    and the solver's figures in the key-value metadata (``tspend:units``, ``tspend:solver``)."""
    import json

    import pyarrow as pa
    import pyarrow.parquet as pq

    cols = {"t": plan.t}
    for i, name in enumerate(plan.state_names):
        cols[name] = plan.states[:, i]
    cols["u"] = plan.u
    units = {"t": "s", **dict(zip(plan.state_names, plan.state_units)), "u": plan.u_unit}
    meta = {"tspend:format": PLAN_FORMAT, "tspend:units": json.dumps(units),
            "tspend:input": plan.u_name,
            "tspend:grid": json.dumps({"dt": plan.dt, "interval": plan.interval}),
            "tspend:solver": json.dumps(plan.solver)}
    fields = [pa.field(k, pa.float64(), metadata={"unit": units[k]}) for k in cols]
    table = pa.table(cols, schema=pa.schema(fields, metadata=meta))
    pq.write_table(table, path)


def read_plan(path: Any, where: str = "plan") -> Plan:
    """A plan file written by :func:`write_plan`; ScenarioError (one line) for anything else."""
    import json

    import pyarrow.parquet as pq

    try:
        table = pq.read_table(path)
    except (OSError, ValueError) as exc:
        raise ScenarioError(f"{where}: {path}: cannot read a plan file ({str(exc).splitlines()[0]})") from None
    meta = {k.decode(): v.decode() for k, v in (table.schema.metadata or {}).items()}
    if meta.get("tspend:format") != PLAN_FORMAT:
        raise ScenarioError(f"{where}: {path}: not a tspend plan (written by 'tspend plan')")
    bad = f"{where}: {path}: not a valid plan"
    try:
        units = json.loads(meta["tspend:units"])
        grid = json.loads(meta["tspend:grid"])
        solver = json.loads(meta.get("tspend:solver", "{}"))
        dt, interval = float(grid["dt"]), float(grid["interval"])
        names = tuple(c for c in table.column_names if c not in ("t", "u"))
        data = {c: np.asarray(table.column(c).to_numpy(zero_copy_only=False), dtype=float)
                for c in table.column_names}
        t, u = data["t"], data["u"]
        states = np.column_stack([data[n] for n in names]) if names else np.zeros((t.size, 0))
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ScenarioError(f"{bad} ({type(exc).__name__}: {str(exc)[:100]})") from None
    # what a follower relies on: a time that runs forward on the plan's step, at least one
    # interval to follow, and numbers everywhere (a NaN would be the run's "divergence")
    if t.size < 2:
        raise ScenarioError(f"{bad}: {t.size} rows, at least 2 needed")
    if not names:
        raise ScenarioError(f"{bad}: no state columns")
    if not (math.isfinite(dt) and dt > 0):
        raise ScenarioError(f"{bad}: its step dt = {dt!r} is not a positive number")
    for label, values in (("t", t), ("u", u), *((n, data[n]) for n in names)):
        if not np.all(np.isfinite(values)):
            row = int(np.flatnonzero(~np.isfinite(values))[0])
            raise ScenarioError(f"{bad}: column {label} holds {float(values[row])} at row {row}")
    steps = np.diff(t)
    if not np.all(steps > 0):
        row = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise ScenarioError(f"{bad}: t does not increase at row {row} ({t[row - 1]:g} then "
                            f"{t[row]:g} s)")
    if np.max(np.abs(steps - dt)) > 1e-6 * dt:
        raise ScenarioError(f"{bad}: t is not on its step dt = {dt:g} s")
    return Plan(t, states, u, names, tuple(units.get(n, "") for n in names),
                meta.get("tspend:input", "u"), units.get("u", ""), dt, interval, solver)
