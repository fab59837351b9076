"""Safety filter: a control barrier function QP between any controller and the plant.

``SafetyFilter(inner, model, cfg)`` runs the controller ``inner`` (any kind: the paper's,
a baseline, ``policy``, a plug-in) and changes its command ``u_c`` as little as possible
so that the task's state constraints (:mod:`tspend.task.constraints`, ``Observation.constraints``)
stay invariant on the domain's own model ``q'' = f(s) + g(s) u``
(:meth:`tspend.plants.domain.FullModel.input_map`: the accelerations are affine in u).
docs/safety.md derives every equation below and says what it guarantees.

For a state row ``a_q q + a_v q' <= b`` of (C1) (tightened by ``margin`` of its box's
half-width), ``h = b - a_q q - a_v q'`` and

* a row on positions only (``a_v = 0``: the rail, the arm's range) has relative degree 2;
  the high-order barrier (Xiao & Belta 2019; Ames et al. 2019, sec. III) with
  ``psi_1 = h' + alpha_1 h`` asks ``psi_1' + alpha_2 psi_1 >= 0``::

      (a_q g) u <= -a_q f - (alpha_1 + alpha_2) a_q q' + alpha_1 alpha_2 h          (S1)

* a row with a velocity (``a_v != 0``) has relative degree 1: ``h' + alpha_1 h >= 0``::

      (a_v g) u <= -a_q q' - a_v f + alpha_1 h                                       (S2)

* a row on the input ``a_u u <= b - a_s s`` is kept as it is (relative degree 0).

With ``barrier = "lyapunov"`` the position rows are replaced by one ellipsoid: ``P`` the
full-state LQR's Riccati matrix at the upright (its default weights), ``h = c - s^T P s``
with ``c = min_i b_i^2 / (a_i^T P^-1 a_i)`` over the position rows ``a_i s <= b_i`` (the
largest ellipsoid inside all of them), kept by ``h' + alpha_1 h >= 0`` (relative degree
1: ``h' = -2 s^T P s'``, ``s' = [q', f + g u]``)::

      (2 s^T P_v g) u <= -2 s^T P [q'; f] + alpha_1 h                               (S5)

``P_v`` the columns of ``P`` on the velocities.  The set holds the pole and the cart
together, so keeping it does not trade the rail for a fall as (S1) on the cart alone can.

With ``v = u / u_scale`` (the input's range scaled to [-1, 1]) and every row ``c_i u <= d_i``
normalised to ``sign(c_i) v <= d_i / (|c_i| u_scale)``, the QP per sample is::

      min_{v, delta}  (v - v_c)^2 + rho delta + delta^2                              (S3)
      s.t.  sign(c_i) v - delta <= e_i,   u_lo <= u_scale v <= u_hi,   delta >= 0

``v_c`` the command clipped to the input's range.  The slack ``delta`` keeps (S3) feasible
when the conditions and the input's range conflict; its penalty is exact (rho > the largest
multiplier, 4 on this scale), so ``delta = 0`` whenever every condition can hold.
Solved by CasADi's conic interface (daqp by default: a dual active-set method, exact for
this dense 2-variable problem, and silent; qpoases and osqp selectable).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from tspend.config import SafetyConfig
from tspend.controllers.base import Controller, Diagnostic, Observation
from tspend.runtime.errors import ScenarioError

__all__ = ["SUFFIX", "SafetyFilter", "barrier_rows", "wrap"]

#: relative change of u below which a sample does not count as changed
CHANGED_REL = 1e-9
#: the slack's quadratic weight eps in (S3): 1, as the input's, so the Hessian is well
#: conditioned (daqp returned a wrong "success" with 1e-6: tests/test_safety.py); the
#: linear weight rho still makes the penalty exact
SLACK_EPS = 1.0
_TIME_BINS = np.logspace(-7, 1, 801)


def barrier_rows(A: np.ndarray, b: np.ndarray, dof: int, s: np.ndarray, f: np.ndarray,
                 g: np.ndarray, alpha_1: float, alpha_2: float) -> tuple[np.ndarray, np.ndarray]:
    """``(c, d)``: the rows ``c u <= d`` of (S1), (S2) and the input's own rows, from rows
    ``A [s, u] <= b`` over the full state ``s = [q, q']`` (``dof`` positions), the drift
    ``f = q''(s, 0)`` and the input map ``g = dq''/du``."""
    q_dot = s[dof:]
    c = np.empty(A.shape[0])
    d = np.empty(A.shape[0])
    for i in range(A.shape[0]):
        a_q, a_v, a_u = A[i, :dof], A[i, dof:2 * dof], A[i, -1]
        h = b[i] - a_q @ s[:dof] - a_v @ q_dot
        if a_u != 0.0:
            c[i], d[i] = a_u, b[i] - a_q @ s[:dof] - a_v @ q_dot                   # relative degree 0
        elif np.any(a_v != 0.0):
            c[i], d[i] = a_v @ g, -a_q @ q_dot - a_v @ f + alpha_1 * h             # (S2)
        else:
            c[i] = a_q @ g
            d[i] = -a_q @ f - (alpha_1 + alpha_2) * (a_q @ q_dot) + alpha_1 * alpha_2 * h  # (S1)
    return c, d


def braking_rows(A: np.ndarray, b: np.ndarray, dof: int, s: np.ndarray, f: np.ndarray,
                 g: np.ndarray, alpha_1: float, a_max: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(c, d)`` as :func:`barrier_rows`, but a row on positions only is kept by the
    stopping-distance barrier (S4): with ``p = a_q q``, ``v = a_q q'`` and ``h = b - p``,
    ``h_b = h - v max(v, 0) / (2 a_max)`` (the room left once braking at ``a_max`` from
    ``v``), relative degree 1, and ``h_b' + alpha_1 h_b >= 0``; for ``v > 0``::

        (v / a_max)(a_q g) u <= -v - (v / a_max) a_q f + alpha_1 h_b                  (S4)

    (``v <= 0``: moving away, ``h_b' = -v >= 0``: no condition on u, the row reads 0 u <= 1).
    ``a_max`` (per row) is the deceleration the barrier may ask for near the bound."""
    c, d = barrier_rows(A, b, dof, s, f, g, alpha_1, alpha_1)
    q, q_dot = s[:dof], s[dof:]
    for i in range(A.shape[0]):
        a_q, a_v, a_u = A[i, :dof], A[i, dof:2 * dof], A[i, -1]
        if a_u != 0.0 or np.any(a_v != 0.0):
            continue
        v = float(a_q @ q_dot)
        if v <= 0.0:
            c[i], d[i] = 0.0, 1.0
            continue
        h_b = b[i] - a_q @ q - v * v / (2.0 * a_max[i])
        c[i] = (v / a_max[i]) * (a_q @ g)
        d[i] = -v - (v / a_max[i]) * (a_q @ f) + alpha_1 * h_b
    return c, d


class SafetyFilter(Controller):
    """``inner`` behind the CBF QP (module docstring); everything else of ``inner`` shown."""

    has_snapshots = False
    #: the filter's name in the kind (``pd+cbf``) and the metrics (``safety_filter.filter``)
    FILTER = "cbf"

    def __init__(self, inner: Controller, model: Any, cfg: SafetyConfig,
                 lyapunov_P: np.ndarray | None = None) -> None:
        import casadi

        #: (S5)'s P (``barrier = "lyapunov"``) and its level c (set from the rows)
        self._P = lyapunov_P
        self._level = math.inf

        self.inner = inner
        self.model = model
        self.cfg = cfg
        self.kind = f"{inner.kind}+{self.FILTER}"
        self.order = inner.order
        self.sample_period = inner.sample_period
        self.has_snapshots = inner.has_snapshots
        self.u_lo, self.u_hi = float(model.u_lo), float(model.u_hi)
        finite = [abs(v) for v in (self.u_lo, self.u_hi) if math.isfinite(v)]
        #: an input range on both sides: v = u / u_scale lies in [-1, 1] (else per sample)
        self.bounded = len(finite) == 2
        self.u_scale = max(finite) if finite else 1.0
        w = inner.diag.size
        self.diagnostics = tuple(inner.diagnostics) + (
            Diagnostic("safety_u_commanded", w, panel="safety", description="the inner "
                       "controller's command before the safety filter"),
            Diagnostic("safety_du", w + 1, panel="safety", description="|u_filtered - "
                       "u_commanded clipped to the input's range|: the filter's intervention"),
            Diagnostic("safety_slack", w + 2, panel="safety", description="the QP's slack "
                       "(> 0: the barrier conditions could not all hold within the input's range)"))
        self.diag = np.zeros(w + 3)
        self._w = w
        self._rows: tuple | None = None
        self._casadi = casadi
        self._solver = None
        self.reset_counts()

    # -- the wrapped controller's features ------------------------------------------------
    def reset(self, rng: np.random.Generator) -> None:
        self.inner.reset(rng)
        self.reset_counts()

    def reset_counts(self) -> None:
        self.samples = self.changed = self.infeasible = 0
        self.sum_du = self.max_du = 0.0
        self.time_hist = np.zeros(_TIME_BINS.size + 1, dtype=np.int64)
        self.time_max = 0.0

    def interrupted(self) -> None:
        self.inner.interrupted()

    def parameters(self) -> dict[str, np.ndarray]:
        return self.inner.parameters()

    def snapshot(self, t: float, step: int, x: np.ndarray) -> Any:
        return self.inner.snapshot(t, step, x)

    def fuzzy_inputs(self) -> dict[str, tuple[Any, ...]]:
        return self.inner.fuzzy_inputs()

    # -- the filter ----------------------------------------------------------------------
    def _prepare(self, obs: Observation) -> None:
        """The rows the filter keeps, from the task's constraints (once: they are fixed)."""
        cs = obs.constraints
        model = self.model
        names = tuple(model.state_names)
        if cs is None:
            raise ScenarioError("safety filter: the observation carries no constraints (run it "
                                "through tspend.run or the CLI, which give the task's)")
        perm = np.array([obs.names.index(n) for n in names], dtype=np.intp)
        rows_A, rows_b = [], []
        for con in cs:
            A = con.A[:, list(perm) + [len(cs.names) - 1]]
            b = con.b.copy()
            if A.shape[0] == 2 and np.allclose(A[0], -A[1]):
                # a box (or a two-sided inequality): keep ``margin`` of its half-width inside
                b = b - self.cfg.margin * 0.5 * (b[0] + b[1])
            if A[:, -1].any() and np.allclose(A[:, :-1], 0.0) and A.shape[0] <= 2:
                # a bound on u alone: the QP's input bounds
                for row, bound in zip(A, con.b):
                    if row[-1] > 0:
                        self.u_hi = min(self.u_hi, bound / row[-1])
                    else:
                        self.u_lo = max(self.u_lo, bound / row[-1])
                continue
            rows_A.append(A)
            rows_b.append(b)
        finite = [abs(v) for v in (self.u_lo, self.u_hi) if math.isfinite(v)]
        self.bounded = len(finite) == 2
        self.u_scale = max(finite) if finite else 1.0
        A = np.vstack(rows_A) if rows_A else np.zeros((0, len(names) + 1))
        b = np.concatenate(rows_b) if rows_b else np.zeros(0)
        if self._P is not None:
            level, kept = lyapunov_level(A, b, self._P, model.dof)
            if kept is not None:
                self._level, A, b = level, A[kept], b[kept]
        self._rows = (perm, A, b)
        # (S4)'s deceleration per row: a share of what the input's range gives at rest
        g0 = model.input_map(np.zeros(model.size))[1]
        reach = max(abs(self.u_lo), abs(self.u_hi)) if self.bounded else 1.0
        self._a_max = np.array([max(self.cfg.braking * abs(row[:model.dof] @ g0) * reach, 1e-9)
                                for row in A])
        m = A.shape[0]
        cas = self._casadi
        m += int(math.isfinite(self._level))
        self._solver = cas.conic("safety_filter", self.cfg.solver,
                                 {"h": cas.Sparsity.dense(2, 2), "a": cas.Sparsity.dense(max(m, 1), 2)},
                                 qp_options(self.cfg.solver))
        self._H = np.diag([2.0, 2.0 * SLACK_EPS])

    def filter(self, s: np.ndarray, u_c: float) -> tuple[float, float]:
        """``(u, slack)``: (S3) at the full state ``s`` (the model's order) for command ``u_c``."""
        perm, A, b = self._rows  # type: ignore[misc]
        f, g = self.model.input_map(s)
        if self.cfg.barrier == "braking":
            c, d = braking_rows(A, b, self.model.dof, s, f, g, self.cfg.alpha_1, self._a_max)
        else:
            c, d = barrier_rows(A, b, self.model.dof, s, f, g, self.cfg.alpha_1, self.cfg.alpha_2)
        if math.isfinite(self._level):
            P, dof = self._P, self.model.dof
            h = self._level - s @ P @ s
            s_dot0 = np.concatenate([s[dof:], f])
            c = np.append(c, 2.0 * (s @ P[:, dof:]) @ g)                             # (S5)
            d = np.append(d, -2.0 * s @ P @ s_dot0 + self.cfg.alpha_1 * h)
        u_c = min(max(u_c, self.u_lo), self.u_hi)
        keep = np.abs(c) > 1e-12 * self.u_scale
        S = self.u_scale
        if not self.bounded:
            # no input range to scale by: scale by this sample's command and row ends, so
            # that |v_c| and every |e_i| <= 1 and the slack's penalty stays exact
            ends = np.abs(d[keep] / c[keep]) if keep.any() else np.zeros(0)
            S = max(1.0, abs(u_c), float(ends.max(initial=0.0)))
        v_c = u_c / S
        # a row the input does not reach at this state (c = 0: its relative degree is higher
        # here, or (S4) moving away) puts no condition on u at this sample
        m = max(c.size, 1)
        a = np.zeros((m, 2))
        uba = np.full(m, np.inf)
        k = np.flatnonzero(keep)
        a[k, 0] = np.sign(c[k])
        a[k, 1] = -1.0
        uba[k] = d[k] / (np.abs(c[k]) * S)
        r = self._solver(h=self._H, g=np.array([-2.0 * v_c, self.cfg.slack_weight]), a=a,
                         lba=np.full(m, -np.inf), uba=uba,
                         lbx=np.array([self.u_lo / S, 0.0]), ubx=np.array([self.u_hi / S, np.inf]))
        x = np.asarray(r["x"], dtype=float).ravel()
        if not np.all(np.isfinite(x)):
            return min(max(u_c, self.u_lo), self.u_hi), math.nan
        # the solver's answer can lie a rounding (1e-10 N) past the input's range: clipped
        return min(max(float(x[0] * S), self.u_lo), self.u_hi), float(x[1])

    def step(self, obs: Observation, dt: float) -> float:
        u_c = float(self.inner.step(obs, dt))
        c0 = time.perf_counter()
        if self._rows is None:
            self._prepare(obs)
        s = np.asarray(obs.state, dtype=float)[self._rows[0]]  # type: ignore[index]
        u, slack = self.filter(s, u_c)
        elapsed = time.perf_counter() - c0
        self.time_hist[np.searchsorted(_TIME_BINS, elapsed)] += 1
        self.time_max = max(self.time_max, elapsed)
        # the intervention is against the command as the actuator applies it (clipped to
        # its range): a clip the actuator makes anyway is not the filter's doing
        du = abs(u - min(max(u_c, self.u_lo), self.u_hi)) if math.isfinite(u_c) else math.inf
        self.samples += 1
        if du > CHANGED_REL * self.u_scale:
            self.changed += 1
        if slack > 1e-9:
            self.infeasible += 1
        if math.isfinite(du):
            self.sum_du += du
            self.max_du = max(self.max_du, du)
        w = self._w
        if w:
            self.diag[:w] = self.inner.diag
        self.diag[w], self.diag[w + 1], self.diag[w + 2] = u_c, du, slack
        return u

    def _median_ms(self) -> float | None:
        return self.time_quantile_ms(0.5)

    def time_quantile_ms(self, q: float) -> float | None:
        """The ``q`` quantile of the filter's time per sample (ms), from its histogram
        (log bins, 2 % wide)."""
        if not self.samples:
            return None
        k = int(np.searchsorted(np.cumsum(self.time_hist), max(1, math.ceil(q * self.samples))))
        lo = _TIME_BINS[k - 1] if k > 0 else _TIME_BINS[0]
        hi = _TIME_BINS[min(k, _TIME_BINS.size - 1)]
        return 1e3 * math.sqrt(lo * hi)

    def run_metrics(self) -> dict[str, Any]:
        """``safety_filter``: how often and how much the filter changed u, how often the QP needed
        its slack, and its compute per sample (the inner controller's not counted)."""
        n = self.samples
        out = {"filter": self.FILTER, "solver": self.cfg.solver, "samples": n,
               "intervention_share": self.changed / n if n else None,
               "mean_abs_du": self.sum_du / n if n else None,
               "max_abs_du": self.max_du if n else None,
               "slack_share": self.infeasible / n if n else None,
               "qp_ms": {"median": self._median_ms(),
                         "max": 1e3 * self.time_max if n else None},
               **self.more_metrics()}
        return {**self.inner.run_metrics(), "safety_filter": out}

    def more_metrics(self) -> dict[str, Any]:
        """A subclass's own entries of ``safety_filter`` (:mod:`.mpsc`'s fallbacks)."""
        return {}



def lyapunov_level(A: np.ndarray, b: np.ndarray, P: np.ndarray, dof: int
                   ) -> tuple[float, np.ndarray | None]:
    """(S5): ``(c, kept)``, the largest level ``c`` of the LQR's ellipsoid ``s^T P s <= c``
    inside every position row ``A s <= b`` (rows on positions alone), and the rows kept
    beside it (the others); ``kept`` None when no position row bounds it."""
    P_inv = np.linalg.inv(P)
    on_q = np.array([not A[i, dof:].any() and A[i, :dof].any() for i in range(len(b))],
                    dtype=bool)
    levels = [b[i] ** 2 / float(A[i, :-1] @ P_inv @ A[i, :-1])
              for i in np.flatnonzero(on_q) if b[i] > 0.0]
    if not levels:
        return math.inf, None
    return min(levels), ~on_q


def qp_options(solver: str) -> dict:
    """The QP solver's options: failures found by the answer, not raised; no printing."""
    opts: dict = {"error_on_fail": False}
    if solver == "qpoases":
        opts["printLevel"] = "none"
    elif solver == "osqp":
        opts["osqp"] = {"verbose": False, "eps_abs": 1e-10, "eps_rel": 1e-10,
                        "max_iter": 20000, "polish": True}
    return opts


#: ``--controller pd+cbf``: the kind ``pd`` behind the filter
SUFFIX = "+" + SafetyFilter.FILTER


def wrap(scenario: Any, inner: Controller, machine: Any) -> SafetyFilter:
    """``inner`` behind the scenario's ``[safety]`` filter on the domain's full-state model
    of the nominal ``machine`` (:func:`tspend.loop.simulation.nominal_machine`).

    Raises ScenarioError (one line) when the plant's domain has no full-state model."""
    from tspend.controllers.full_model import full_model, has_full_state

    if not has_full_state(scenario):
        raise ScenarioError(f"{scenario.path}: safety.filter = \"{SafetyFilter.FILTER}\": plant "
                            f"'{scenario.plant.kind}' has no full-state model (q'' = f + g u) "
                            f"for the barrier conditions; allowed: \"off\"")
    cfg = scenario.safety
    model = full_model(scenario, machine)
    P = None
    if cfg.barrier == "lyapunov":
        from tspend.controllers.lqr import default_state_weights, design_model, lqr_full_gain

        A, B = design_model(scenario, machine)
        b_pole = float(B[model.dof + model.pole, 0])
        _, P = lqr_full_gain(A, B, np.diag(default_state_weights(model)), b_pole ** 2)
    return SafetyFilter(inner, model, cfg, lyapunov_P=P)
