"""Predictive safety certification (``--safety mpsc``): a backup plan behind every input.

Model predictive safety certification (Wabersich and Zeilinger, "Linear model predictive
safety certification for learning-based control", CDC 2018; "A predictive safety filter
for learning-based control of constrained nonlinear dynamical systems", Automatica 129,
2021) on the domain's own model (:class:`~tspend.plants.domain.FullModel`, the nominal
machine).  At every controller sample, with ``s`` the measured full state and ``u_c`` the
inner controller's command clipped to the input's range, the filter looks for a backup
plan ``u_0 .. u_{N-1}`` on the model

    s_1 = F_0(s, u_0),  s_{k+1} = F(s_k, u_k)   (k >= 1)                         (P1)
    lo <= s_k <= hi  (k = 1 .. N: the hard position boxes, the fall angle, tightened)
    u_lo <= u_k <= u_hi,  soft rows C s_k + D u_k - e_k <= b, e_k >= 0          (P2)
    s_N in X_f = {s : s^T P s <= c}                                             (P3)

``F_0`` one control sample (RK4), ``F`` one ``plan_period`` (``substeps`` RK4 steps):
the first input is held for one sample only, as the runner holds it.  ``X_f`` is the
balancing LQR's sublevel set (``P`` its Riccati matrix, the weights ``lqr`` uses), ``c``
the largest level whose ellipsoid lies inside every tightened position bound, the fall
angle and ``|K s| <= u_max`` (:func:`terminal_level`), then shrunk until, from sampled
points of its boundary, the saturated LQR keeps every bound and returns inside on the
nominal model and on every vertex of the ``[randomize]`` box (:func:`recurrent_level`,
:func:`vertex_models`).  A plan is rolled out with its own LQR correction at every RK4
step, towards the plan's states interpolated between its nodes (as the fallback tracks
it at every sample)

    u(t) = U_k - K (x(t) - R(t))   (k >= 1; R the plan's states, x the rollout's)   (P5)

and certified when, on the nominal model and every vertex model (P6), it keeps the hard
bounds at every RK4 step and ends in ``X_f``.  The task's declared disturbance ``|d| <=
d_max`` moves every hard bound in by (P7) :func:`disturbance_tube`, the most it can move
the tracked state off its plan on the linearisation.

Per sample (docs/safety.md says it with the figures), each step only when the one before
found nothing:

0. the fast path: ``[u_c, the certified plan's rest]``, then ``[u_c, the saturated
   LQR]`` certified by the rollout: ``u_c`` passes unchanged, no QP;
1. the closest certifiable input between ``u_c`` and a certified tail's own input (the
   certified plan's, the LQR's), by bisection on the certificate, no QP;
2. one Gauss-Newton SQP step (:class:`~.mpc_rti.RealTimeSQP`, HPIPM) of

       min (u_0 - u_c)^2 + eps / R J_LQR(s_1.., u_1..) + slack penalties          (P4)

   under (P1), (P2) as exact-penalty rows, linearised, and (P3) as a cube inside the
   ellipsoid; ``[u_c, its plan's rest]``, else its own plan, certified;
3. else the last certified plan goes on, its states tracked by the LQR every sample (a
   **fallback**);
4. without any certified plan (``no_plan``): the recovery plan, made once by IPOPT on the
   nominal model (multiple shooting, intervals of the plan's interval / RECOVERY_REFINE)

       min t + effort,  lo_i - t w_i <= s_k,i <= hi_i + t w_i,  s_M in X_f (0.95 c)     (P8)

   (``w_i`` the half-width of constraint ``i``: t < 0 keeps -t of every half-width to
   spare, so the plan least uses the rail and the fall angle), tracked by the LQR towards
   its states until a certified plan exists again or it runs out; uncertified and
   counted.  When IPOPT fails: the QP's own plan, else the saturated LQR.

So at every sample of steps 0-3 the applied input starts a plan certified on the model
(and the vertex models): following it lands in ``X_f``, where the LQR stays.  Nothing is
claimed for a machine between the vertices or for a start with no certified plan.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from tspend.controllers.base import Controller, Observation
from tspend.controllers.safety import SafetyFilter
from tspend.runtime.errors import ScenarioError

if TYPE_CHECKING:
    from tspend.config import SafetyConfig, Scenario
    from tspend.plants.domain import FullModel

__all__ = ["PredictiveSafetyFilter", "terminal_level", "vertex_models", "wrap"]

#: eps of (P4): the weight of the backup plan's own LQR cost against the first input's
#: distance from the command (1 on the input's range)
PROXIMAL = 1e-1
#: (P3)'s level is shrunk by this factor until the decrease holds on every sampled point
SHRINK = 0.8
#: boundary points of X_f sampled per model for the recurrence check
BOUNDARY_POINTS = 64
#: the QP aims its plan's end at this share of (P3)'s level, the certificate checks all
#: of it; the plan keeps the whole margin from its second node on, the certificate (and
#: the plan's first node, one sample ahead) CHECK_MARGIN of it: the room between absorbs
#: the difference between the linearised plan and its rollout, between nodes too
TERMINAL_AIM = 0.95
CHECK_MARGIN = 0.8
#: the plan's end level costs as much as a command TERMINAL_WEIGHT x the input's range off
TERMINAL_WEIGHT = 0.1
#: bisection steps between the command and the certified plan's input (2^-8 of the gap)
BISECTIONS = 8
#: the longest plan (intervals) chosen automatically
MAX_AUTO_HORIZON = 40
#: HPIPM's options for the QP: "speed" mode's relative stopping test iterated 40-60
#: times here (6 ms per sample), "speed_abs" stops at the absolute residuals (1e-7) in
#: about 10 (1.2 ms)
QP_OPTIONS = {"mode": "speed_abs"}
#: the largest constraint residual of a QP's answer taken as a step: the QP proposes a
#: plan that the certificate (a rollout on every model) accepts or refuses, so a
#: millimetre of residual in the linearised rows costs no safety
QP_ACCEPTANCE = 1e-3
#: SQP steps per sample while no certified plan exists (its plan is then applied)
RECOVERY_ITERATIONS = 3
#: the recovery plan (step 4, (P8)): intervals of the plan's interval / RECOVERY_REFINE
#: (a manoeuvre that must catch the pole within a plan interval needs switches inside it)
RECOVERY_REFINE = 5
#: IPOPT's iterations for one recovery plan
RECOVERY_MAX_ITER = 200
#: (P8)'s weight on the input's energy (in shares of its range, per interval) beside t
RECOVERY_EFFORT = 1e-3
#: the disturbance's samples read for its bound (P7)
MAX_DISTURBANCE_SAMPLES = 10 ** 6
#: at most this many [randomize] parameters spanned by vertices (2^6 = 64 models)
MAX_VERTEX_PARAMETERS = 6


def terminal_level(P: np.ndarray, rows: list[tuple[np.ndarray, float]]) -> float:
    """The largest ``c`` with ``{s^T P s <= c}`` inside every ``|a^T s| <= b`` of ``rows``:
    ``min b^2 / (a^T P^-1 a)`` (the support function of the ellipsoid)."""
    P_inv = np.linalg.inv(P)
    return min((b * b / float(a @ P_inv @ a) for a, b in rows if b > 0.0), default=math.inf)


def recurrent_level(models: list["FullModel"], P: np.ndarray, K: np.ndarray, c: float,
                    lo: np.ndarray, hi: np.ndarray, u_lo: float, u_hi: float, T: float,
                    rng: np.random.Generator) -> float:
    """``c`` shrunk by :data:`SHRINK` until, on every model, the saturated LQR
    ``u = clip(-K s)`` from :data:`BOUNDARY_POINTS` sampled points of the ellipsoid's
    boundary keeps every bound ``lo <= s <= hi`` at every 20 ms step for ``T`` seconds and
    ends back inside the ellipsoid (a sampled check, not a proof); 0 when 15 shrinks do
    not reach it.  A Lyapunov decrease of the nominal ``P`` would be the classic test, but
    it fails at every level on the drawn machines (their ``A - B K`` is not the nominal's):
    what is checked is that the set is recurrent and safe under the LQR."""
    import casadi as ca

    n, dt = P.shape[0], 0.02
    steps = max(1, int(math.ceil(T / dt)))
    d = rng.standard_normal((BOUNDARY_POINTS, n))
    d /= np.sqrt(np.einsum("ij,jk,ik->i", d, P, d))[:, None]
    x = ca.SX.sym("x", n)
    u = ca.fmin(ca.fmax(-ca.mtimes(ca.DM(K.reshape(1, -1)), x), u_lo if math.isfinite(u_lo)
                        else -1e19), u_hi if math.isfinite(u_hi) else 1e19)
    sims = [ca.Function("lqr_step", [x], [m.rk4_map(dt, 1)(x, u)]).mapaccum(steps)
            .map(BOUNDARY_POINTS) for m in models]
    bounded = np.isfinite(lo) | np.isfinite(hi)
    for _ in range(15):
        ok = True
        for sim in sims:
            X = np.asarray(sim(math.sqrt(c) * np.repeat(d.T, 1, axis=1)), dtype=float)
            X = X.reshape(n, BOUNDARY_POINTS, steps)
            inside = np.all((X[bounded] >= lo[bounded, None, None]) &
                            (X[bounded] <= hi[bounded, None, None]))
            end = X[:, :, -1]
            if not (inside and np.all(np.einsum("ip,ij,jp->p", end, P, end) <= c)):
                ok = False
                break
        if ok:
            return c
        c *= SHRINK
    return 0.0


def disturbance_input(scenario: "Scenario", model: "FullModel") -> np.ndarray:
    """``E`` (nx,): the full state's rate per unit of the task's disturbance ``d`` at the
    upright at rest, in the model's order, read off the nominal machine itself (one
    sample from rest with ``d = 1`` against one with ``d = 0``: ``d`` enters the plant as
    the plant applies it, a hinge torque on the MuJoCo cart-pole)."""
    from tspend.plants import registry

    dt = scenario.run.dt
    rates = []
    for d in (0.0, 1.0):
        plant = registry.build(scenario)
        plant.reset(np.zeros(len(scenario.plant.x0)))
        start = np.asarray(plant.full_state(), dtype=float).copy()
        plant.step(0.0, d, dt)
        rates.append((np.asarray(plant.full_state(), dtype=float) - start) / dt)
    names = list(plant.state_names)
    order = [names.index(n) for n in model.state_names]
    E = (rates[1] - rates[0])[order]
    # the positions' share is the velocities' first step (dt/2 of them): not a rate of d
    E[:model.dof] = 0.0
    return E


def disturbance_tube(scenario: "Scenario", model: "FullModel", A_cl: np.ndarray) -> np.ndarray:
    """(P7) ``w`` (nx,): for the task's disturbance, ``d_max = max |d(t)|`` over the run
    (sampled at run.dt), the largest ``|e_i(t)|`` any ``|d| <= d_max`` can cause in
    ``e' = A_cl e + E d`` (the error between the machine and its plan while the LQR
    tracks it, linearised at the upright): ``d_max`` x the L1 norm of ``e_i``'s impulse
    response, ``int_0^inf |c_i exp(A_cl t) E| dt`` (a peak-to-peak bound that holds at
    every time, on the plan and in the terminal set after it).  Zeros without a
    disturbance."""
    from scipy.linalg import expm

    run = scenario.run
    n = int(min(round(run.duration / run.dt), MAX_DISTURBANCE_SAMPLES))
    d = np.asarray(scenario.disturbance(np.arange(max(n, 1)) * run.dt), dtype=float)
    d_max = float(np.max(np.abs(d))) if d.size else 0.0
    if not (math.isfinite(d_max) and d_max > 0.0):
        return np.zeros(model.size)
    E = disturbance_input(scenario, model)
    slowest = float(np.abs(np.linalg.eigvals(A_cl).real).min())
    step = min(1e-3, 0.05 / max(float(np.abs(np.linalg.eigvals(A_cl)).max()), 1e-9))
    # to 20 time constants of the slowest closed-loop pole (the response is e^-20 of its
    # start there), at most 1e5 steps
    steps = int(min(1e5, math.ceil(20.0 / (max(slowest, 1e-9) * step))))
    Phi = expm(A_cl * step)
    x, total = E.copy(), np.zeros(model.size)
    for _ in range(steps):
        nxt = Phi @ x
        total += 0.5 * (np.abs(x) + np.abs(nxt)) * step
        x = nxt
    return d_max * total


def vertex_models(scenario: "Scenario") -> tuple[list["FullModel"], list[str]]:
    """The full-state model at every vertex of the ``[randomize]`` parameter box (the
    initial state's draws left out: they are not the machine), and the parameters spanned.
    A normal draw spans its truncation, else mean +/- 2 standard deviations."""
    from tspend.controllers.full_model import full_model
    from tspend.plants import registry
    from tspend.plants.randomize import Draw, draw

    params = [d for d in scenario.randomize if not d.name.startswith("x0[")]
    if not params:
        return [], []
    if len(params) > MAX_VERTEX_PARAMETERS:
        raise ScenarioError(f"{scenario.path}: safety.filter = \"mpsc\" checks its terminal set "
                            f"on the vertices of the [randomize] box: at most "
                            f"{MAX_VERTEX_PARAMETERS} drawn parameters, got {len(params)}")
    ends = []
    for d in params:
        if d.dist == "uniform":
            ends.append((d.a, d.b))
        else:
            lo = d.low if math.isfinite(d.low) else d.a - 2.0 * d.b
            hi = d.high if math.isfinite(d.high) else d.a + 2.0 * d.b
            ends.append((lo, hi))
    models = []
    for corner in itertools.product(*ends):
        fixed = tuple(Draw(d.name, "uniform", v, v, d.relative, v, v)
                      for d, v in zip(params, corner))
        vertex = draw(replace(scenario, randomize=fixed)).scenario
        # each vertex is a machine of its own (built here: the runner builds the nominal one)
        models.append(full_model(vertex, registry.build(vertex)))
    return models, [d.name for d in params]


def plan_grid(K: np.ndarray, model: "FullModel", cfg: "SafetyConfig") -> tuple[float, int, int]:
    """``(plan_period, horizon, substeps)``: the settings, or where 0, from the nominal
    machine's balancing LQR ``A - B K`` at the upright: 0.5 / its fastest pole's modulus
    (0.005 to 0.1 s), 3 time constants of its slowest (10 to :data:`MAX_AUTO_HORIZON`
    intervals), and RK4 steps of at most 0.25 / the fastest pole of ``A`` or ``A - B K``."""
    A, B = model.linearisation()
    poles = np.linalg.eigvals(A - B @ K)
    h = cfg.plan_period or min(0.1, max(0.005, 0.5 / float(np.abs(poles).max())))
    slowest = float(np.abs(poles.real).min())
    horizon = cfg.horizon or int(min(MAX_AUTO_HORIZON, max(10, math.ceil(3.0 / (slowest * h)))))
    fastest = max(float(np.abs(poles).max()), float(np.abs(np.linalg.eigvals(A)).max()))
    substeps = cfg.substeps or max(1, math.ceil(h * fastest / 0.25))
    return h, horizon, substeps


class PredictiveSafetyFilter(SafetyFilter):
    """``inner`` behind the predictive safety certification (module docstring)."""

    FILTER = "mpsc"

    def __init__(self, inner: Controller, model: "FullModel", cfg: "SafetyConfig",
                 sample_s: float, bounds: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
                 u_range: tuple[float, float], rows: tuple, K: np.ndarray, P: np.ndarray,
                 level: float, Q: np.ndarray, R: float, vertices: tuple = (),
                 compiled: bool = True, tube: np.ndarray | None = None,
                 limits: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        import casadi as ca

        from tspend.controllers.mpc_rti import RealTimeSQP, compiled_function

        super().__init__(inner, model, cfg)
        #: (P7)'s tightening per state (zeros: no disturbance declared)
        self.tube = np.zeros(model.size) if tube is None else np.asarray(tube, dtype=float)
        self.u_lo, self.u_hi = u_range
        finite = [abs(v) for v in u_range if math.isfinite(v)]
        self.bounded = len(finite) == 2
        self.u_scale = max(finite) if finite else 1.0
        nx = model.size
        h, horizon, substeps = plan_grid(np.asarray(K, dtype=float).reshape(1, -1), model, cfg)
        N = horizon + 1
        self.nx, self.N, self.dt0, self.h = nx, N, float(sample_s), h
        #: the plan's hard bounds (tightened by the margin) and the certification's (half)
        self.lo, self.hi, self.lo_check, self.hi_check = bounds
        self.K, self.P, self.level = np.asarray(K, dtype=float).ravel(), P, level
        C, D, b, sel = rows
        # the hard bounds (P2) in the QP as exact-penalty rows, not as bounds: the QP
        # proposes, the certificate decides, so a softened proposal costs no safety; where
        # the linearised plan can keep them its slack is 0 (an exact penalty), where it
        # cannot (a state the certificate no longer covers) the QP still answers with the
        # plan that leaves them least, which step 4 applies, where a bound would fail it
        hard = [i for i in range(nx) if math.isfinite(self.lo[i]) and math.isfinite(self.hi[i])]
        if hard:
            eye = np.eye(nx)[hard]
            C = np.vstack([C, eye, -eye])
            D = np.concatenate([D, np.zeros(2 * len(hard))])
            b = np.concatenate([b, self.hi[hard], -self.lo[hard]])
            extra = np.vstack([np.eye(len(hard))] * 2)
            sel = np.block([[sel, np.zeros((sel.shape[0], len(hard)))],
                            [np.zeros((2 * len(hard), sel.shape[1])), extra]])
        ns = sel.shape[1]
        self.ns, self.nz = ns, nx + 1 + ns
        nz = self.nz
        F0 = model.rk4_map(self.dt0, 1, name="mpsc_first")
        F = model.rk4_map(self.h, substeps, name="mpsc_plan")
        self.substeps = substeps
        self.iterations = 1
        # (P4)'s Hessian stage by stage, times u_scale^2 (the QP in the input's unit: its
        # solver's absolute tolerances then mean something): the first input against the
        # command (weight 1), the rest of the plan a small LQR cost (eps: an input as far
        # off as the command costs eps) that makes the backup smooth and heads it upright
        w = PROXIMAL
        self._slack_scale = self.u_scale ** 2
        stages = np.zeros((N, nz, nz))
        stages[:, :nx, :nx] = 2.0 * w * Q / R
        stages[:, nx, nx] = 2.0 * w
        stages[0, nx, nx] = 2.0
        stages[:, nx + 1:, nx + 1:] = 2.0 * self._slack_scale * np.eye(ns)
        # and a cost on the plan's end level (as much as a command a tenth of the input's
        # range off at the level c), so that plans end deep inside (P3), where the next
        # sample's QP (its cube) can start from them
        terminal = 2.0 * w * P / R + 2.0 * (TERMINAL_WEIGHT * self.u_scale) ** 2 * P / level
        ulo = self.u_lo if math.isfinite(self.u_lo) else -np.inf
        uhi = self.u_hi if math.isfinite(self.u_hi) else np.inf
        lo_s, hi_s = np.full(nx, -np.inf), np.full(nx, np.inf)
        z_lo = np.concatenate([np.tile(np.concatenate([lo_s, [ulo], np.zeros(ns)]), N), lo_s])
        z_hi = np.concatenate([np.tile(np.concatenate([hi_s, [uhi], np.full(ns, np.inf)]), N),
                               hi_s])
        # (P3) in the QP: the cube |L^T s_N|_inf <= sqrt(0.95 c / n) (P = L L^T) inside the
        # ellipsoid, linear, so the QP's plan ends inside whatever its step (the tangent
        # of the ellipsoid, linearised, lies outside it: plans slid out along it)
        L = np.linalg.cholesky(P)
        xN = ca.SX.sym("xN", nx)
        cube = ca.mtimes(ca.DM(L.T), xN) / math.sqrt(TERMINAL_AIM * level / nx)
        inner_box = ca.Function("mpsc_terminal", [xN], [ca.vertcat(cube, -cube) - 1.0])
        G = np.hstack([C, D[:, None], -sel]) if ns else None
        self.sqp = RealTimeSQP(F, nx, N, stages, terminal, z_lo, z_hi,
                               "hpipm", compiled, stage_rows=G, stage_bound=b if ns else None,
                               stage_gradient=np.concatenate([np.zeros(nx + 1),
                                                              np.full(ns, cfg.slack_weight * self._slack_scale)]),
                               nz=nz, first_map=F0, terminal_constraint=inner_box,
                               qp_options=QP_OPTIONS, acceptance=QP_ACCEPTANCE)
        # (P5): the backup plan's own rollout, each interval's input corrected by the LQR
        # towards the plan's state at the interval's start (held over the interval)
        s0, U, Rf = ca.SX.sym("s0", nx), ca.SX.sym("U", N), ca.SX.sym("R", nx, N)
        Kd = ca.DM(self.K.reshape(1, -1))
        lo_u = self.u_lo if math.isfinite(self.u_lo) else -1e19
        hi_u = self.u_hi if math.isfinite(self.u_hi) else 1e19
        # every RK4 step's state is returned, so that the certificate checks the bounds
        # between the plan's nodes too (a cart at 3 m/s moves 0.3 m in one interval); the
        # same plan rolled out on every vertex model of the [randomize] box below the
        # nominal's (P6): the certificate asks it of all of them
        blocks = []
        for m in (model, *vertices):
            F0m = m.rk4_map(self.dt0, 1, name="mpsc_first")
            F_step = m.rk4_map(self.h / substeps, 1, name="mpsc_step")
            x, cols, used = s0, [s0], []
            for k in range(N):
                if k == 0:
                    x = F0m(x, U[0])
                    cols.append(x)
                    used.append(U[0])
                    continue
                for j in range(substeps):
                    # the reference between the nodes as the fallback interpolates it
                    # (tracking_input), the correction at every RK4 step
                    a = j / substeps
                    ref = Rf[:, k] if k + 1 >= N else (1.0 - a) * Rf[:, k] + a * Rf[:, k + 1]
                    u = ca.fmin(ca.fmax(U[k] - ca.mtimes(Kd, x - ref), lo_u), hi_u)
                    x = F_step(x, u)
                    cols.append(x)
                    if j == 0:
                        used.append(u)
            used += [0.0] * (len(cols) - N)
            blocks.append(ca.vertcat(ca.horzcat(*cols), ca.horzcat(*used)))
        self._cols, self._models = len(cols), 1 + len(vertices)
        roll = ca.Function("tspend_mpsc_rollout", [s0, U, Rf], [ca.vertcat(*blocks)])
        self.rollout = compiled_function(roll) if compiled else roll
        # evaluated through CasADi's buffer interface on persistent arrays (a Python call
        # with its conversions costs 3-4 times the compiled rollout itself)
        self._roll_in = (np.zeros(nx), np.zeros(N), np.zeros(nx * N))
        self._roll_out = np.zeros((nx + 1) * self._models * self._cols)
        self._roll_buffer, self._roll_eval = self.rollout.buffer()
        for i, array in enumerate(self._roll_in):
            self._roll_buffer.set_arg(i, memoryview(array))
        self._roll_buffer.set_res(0, memoryview(self._roll_out))
        self._maps = (F0, F)
        #: the states with a bound the certificate checks, and those bounds
        self._checked = np.flatnonzero(np.isfinite(self.lo_check) | np.isfinite(self.hi_check))
        self._check_lo = self.lo_check[self._checked]
        self._check_hi = self.hi_check[self._checked]
        self._angles = np.flatnonzero(model.angles)
        # (P8)'s grid, and its relaxation's unit per checked bound: the half-width of the
        # constraint itself (a share of the rail, of the fall angle), so that minimising
        # the relaxation minimises the largest share of any bound the plan uses
        self.h_rec = h / RECOVERY_REFINE
        self.M_rec = 1 + int(round((N - 1) * h / self.h_rec))
        raw_lo, raw_hi = (self.lo, self.hi) if limits is None else limits
        half_raw = 0.5 * (np.asarray(raw_hi, dtype=float) - np.asarray(raw_lo, dtype=float))
        unit = np.where(np.isfinite(half_raw), half_raw,
                        np.maximum(np.abs(self.lo), np.abs(self.hi)))
        unit = unit[self._checked]
        self._room_hi = self._room_lo = np.where(np.isfinite(unit) & (unit > 0), unit, 1.0)
        self._recovery = None
        self._rec_maps = (model.rk4_map(self.dt0, 1), model.rk4_map(self.h_rec, 1))
        self.reset_plan()

    # -- state ----------------------------------------------------------------------------
    def reset_plan(self) -> None:
        #: the last certified plan's inputs (N,) and the samples since it was certified
        #: the last certified plan: (U (N,), R (nx, N)) of (P5)
        self.plan: tuple | None = None
        self.plan_age = 0
        #: the QP's last answer (its next warm start), certified or not
        self.iterate_plan: tuple | None = None
        #: the fallback's input for the interval it is in: (interval, u)
        self._held: tuple[int, float] | None = None
        self.fallbacks = self.infeasible_qp = self.rejected = self.no_plan = self.bisected = 0
        #: samples passed by the fast path (no QP), and samples on an uncertified QP plan
        self.fast = self.uncertified = 0
        #: the last uncertified QP plan applied without a certified one, and its age
        self.effort: tuple | None = None
        self.effort_age = 0
        #: the recovery plan (P8) being tracked, its age in samples, and how many were made
        self.rescue: tuple | None = None
        self.rescue_age = 0
        self.recoveries = 0
        self.rescue_relaxation = -math.inf
        self.max_slack = 0.0

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        self.reset_plan()

    def _prepare(self, obs: Observation) -> None:
        perm = np.array([obs.names.index(n) for n in self.model.state_names], dtype=np.intp)
        self._rows = (perm,)

    # -- the certificate ------------------------------------------------------------------
    def stage_at(self, tau: float) -> int | None:
        """The plan's interval ``tau`` seconds after it was made (None: past its end)."""
        if tau < self.dt0 - 1e-12:
            return 0
        k = 1 + int(math.floor((tau - self.dt0) / self.h + 1e-9))
        return k if k < self.N else None

    def shifted(self, plan: tuple | None, age: int, s: np.ndarray) -> tuple | None:
        """``plan = (U, R)`` made ``age`` samples ago, on this sample's grid from state
        ``s``: each new interval takes the input of the old interval it starts in and the
        old reference state at its start, interpolated between the old nodes as the
        fallback does (past the plan's end: the LQR, U = 0 and R = 0)."""
        if plan is None:
            return None
        U, R = plan
        N, h, dt0 = self.N, self.h, self.dt0
        t = age * dt0 + np.concatenate([[0.0], dt0 + h * np.arange(N - 1)])
        k = np.where(t < dt0 - 1e-12, 0, 1 + np.floor((t - dt0) / h + 1e-9).astype(np.intp))
        live = k < N
        U2, R2 = np.zeros(N), np.zeros((self.nx, N))
        kl = k[live]
        a = np.where(kl == 0, 0.0, np.clip((t[live] - (dt0 + (kl - 1) * h)) / h, 0.0, 1.0))
        nxt = np.minimum(kl + 1, N - 1)
        U2[live] = U[kl]
        R2[:, live] = (1.0 - a) * R[:, kl] + a * R[:, nxt]
        R2[:, 0] = s
        return U2, R2

    def lqr_tail(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The saturated LQR as a backup plan from ``s`` (U = 0, R = 0 in (P5))."""
        R = np.zeros((self.nx, self.N))
        R[:, 0] = s
        return np.zeros(self.N), R

    def roll(self, s: np.ndarray, U: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(P5) from ``s``: the states at the plan's nodes (nx, N+1), the inputs applied
        (N,), and the states after every RK4 step (nx, 2 + (N-1) substeps)."""
        a, b, c = self._roll_in
        a[:], b[:], c[:] = s, U, np.asarray(R, dtype=float).ravel(order="F")
        self._roll_eval()
        rows = (self.nx + 1) * self._models
        out = self._roll_out.reshape(self._cols, rows).T             # column-major
        every = out[:self.nx].copy()
        nodes = np.hstack([every[:, :2], every[:, 1 + self.substeps::self.substeps]])
        # every model's states stacked: (models, nx, steps)
        allm = out.reshape(self._models, self.nx + 1, self._cols)[:, :self.nx]
        return nodes, out[self.nx, :self.N].copy(), allm

    def certifies(self, s: np.ndarray, U: np.ndarray, R: np.ndarray) -> bool:
        """Whether the plan ``(U, R)`` from ``s``, rolled out by (P5) on the nonlinear
        model, keeps the hard bounds at every RK4 step and ends in the terminal ellipsoid
        (P3), on every model (P6); if so it becomes the certified plan.  Read in place
        from the compiled rollout's output (no copies: this runs up to a dozen times a
        sample)."""
        a, b, c = self._roll_in
        a[:], b[:] = s, U
        c.reshape(self.N, self.nx)[:] = np.asarray(R, dtype=float).T
        self._roll_eval()
        # column-major (rows, steps) with rows = models x (nx + 1): [step, model, row]
        V = self._roll_out.reshape(self._cols, self._models, self.nx + 1)
        end = V[-1, :, :self.nx]
        # a non-finite state anywhere reaches the end (RK4 carries it): the level test fails
        if not np.all(np.einsum("mi,ij,mj->m", end, self.P, end) <= self.level):
            return False
        inner = V[1:, :, self._checked]
        if np.any(inner < self._check_lo) or np.any(inner > self._check_hi):
            return False
        R = np.array(R, dtype=float)
        R[:, 0] = s
        self.plan, self.plan_age, self._held = (U.copy(), R), 1, None
        # a later start outside the certified set plans its recovery afresh
        self.rescue = None
        return True

    def terminal_input(self, s: np.ndarray) -> float:
        return min(max(float(-self.K @ s), self.u_lo), self.u_hi)

    def filter(self, s: np.ndarray, u_c: float) -> tuple[float, float]:
        """``(u, slack)``: steps 0-4 of the module docstring at full state ``s``."""
        s = np.array(s, dtype=float)
        s[self._angles] = (s[self._angles] + math.pi) % (2.0 * math.pi) - math.pi
        u_c = min(max(u_c, self.u_lo), self.u_hi) if math.isfinite(u_c) else math.nan
        # the last certified plan from now on, (P5) as it would go on (the fallback)
        going_on = self.shifted(self.plan, self.plan_age, s) if self.plan is not None else None
        if math.isfinite(u_c):
            # 0: the fast path: the command followed by the certified plan's rest, or by
            # the saturated LQR: a rollout certified on every model IS a backup plan, so
            # u_c passes without the QP (the certificate is the same as after it)
            for tail in (going_on, self.lqr_tail(s)):
                if tail is not None:
                    candidate = tail[0].copy()
                    candidate[0] = u_c
                    if self.certifies(s, candidate, tail[1]):
                        self.fast += 1
                        # the QP's next warm start: this plan, not its older answer
                        self.iterate_plan = None
                        return u_c, 0.0
        # 1: the closest certifiable input on a certified tail: between u_c and the
        # tail's own input now (the fallback's, or the LQR's), by bisection on the
        # certificate (a few rollouts, no QP)
        k = self.stage_at(self.plan_age * self.dt0) if self.plan is not None else None
        tails = []
        if going_on is not None and k is not None:
            tails.append((going_on, self.tracking_input(s, k, self.plan_age * self.dt0)))
        tails.append((self.lqr_tail(s), self.terminal_input(s)))
        kept = (self.plan, self.plan_age, self._held)
        for tail, own in tails:
            candidate = tail[0].copy()
            candidate[0] = own
            if not self.certifies(s, candidate, tail[1]):
                continue
            good, bad = own, u_c if math.isfinite(u_c) else None
            for _ in range(BISECTIONS if bad is not None else 0):
                mid = 0.5 * (good + bad)
                candidate[0] = mid
                # a certified candidate becomes the plan: the last one is the answer's
                if self.certifies(s, candidate, tail[1]):
                    good = mid
                else:
                    bad = mid
            self.bisected += 1
            self.iterate_plan = None
            return good, 0.0
        self.plan, self.plan_age, self._held = kept
        if k is None:
            # 4: no certified plan: the recovery plan (P8), made once from this state and
            # tracked by the LQR until a certified plan exists again or it runs out
            # (made afresh every interval from the measured state, it did worse: from a
            # state off the nominal's path the nominal model needs more of the rail)
            u = self.recovery_input(s, self.rescue_age * self.dt0) if self.rescue else None
            if u is None:
                found = self.recovery_plan(s)
                if found is not None:
                    self.rescue, self.rescue_age = found, 0
                    self.recoveries += 1
                    self.rescue_relaxation = max(self.rescue_relaxation, found[2])
                    u = self.recovery_input(s, 0.0)
            if u is not None:
                self.rescue_age += 1
                self.no_plan += 1
                self.uncertified += 1
                self.iterate_plan = None
                return u, 0.0
        nz, nx, N = self.nz, self.nx, self.N
        # 2: no certified tail takes any input: one real-time iteration of the QP (P4),
        # from its own last answer (a real-time iteration converges over samples),
        # certified or not, else from the certified plan, else from the LQR's rollout
        warm = (self.shifted(self.iterate_plan, 1, s) or going_on)
        cold = warm is None
        if cold:
            warm = self.lqr_tail(s)
        S0, U0, _ = self.roll(s, *warm)
        if cold:
            U0[0] = self.terminal_input(s)
            S0, U0, _ = self.roll(s, U0, warm[1])
        z = np.zeros(N * nz + nx)
        body = z[:N * nz].reshape(N, nz)
        body[:, :nx], body[:, nx] = S0[:, :N].T, U0
        z[N * nz:] = S0[:, N]
        # (P4)'s reference: the command for u_0, the upright at rest for the rest; without
        # a certified plan (recovery: step 4 applies the QP's u_0) the plan's own u_0, so
        # that the command does not pull the plan it applies towards itself
        zr = np.zeros_like(z)
        zr[nx] = u_c if math.isfinite(u_c) and going_on is not None else U0[0]
        plan = None
        slack = 0.0
        # without a certified plan to fall back on, the QP iterates further: its plan is
        # then what the filter applies
        steps = 10 if cold else (RECOVERY_ITERATIONS if going_on is None else self.iterations)
        if np.all(np.isfinite(z)):
            try:
                z, _ = self.sqp.iterate(z, s, zr, steps, 1e-8)
                body = z[:N * nz].reshape(N, nz)
                plan = (np.clip(body[:, nx], self.u_lo, self.u_hi), body[:, :nx].T.copy())
                slack = float(body[:, nx + 1:].max(initial=0.0))
            except RuntimeError:
                self.infeasible_qp += 1
                self.sqp.reset()
        else:
            self.infeasible_qp += 1
        self.iterate_plan = plan
        if plan is not None:
            # the command followed by the QP's plan, else the QP's own input
            if math.isfinite(u_c):
                candidate = plan[0].copy()
                candidate[0] = u_c
                if self.certifies(s, candidate, plan[1]):
                    return u_c, slack
            if self.certifies(s, *plan):
                self.max_slack = max(self.max_slack, slack)
                return float(plan[0][0]), slack
            self.rejected += 1
        # 3: the last certified plan goes on, its states tracked by the LQR at every
        # sample (the certificate's rollout (P5) corrects at every RK4 step towards the
        # same interpolated states); past its end: 4
        self.plan_age += 1
        if k is None:
            # 4: no certified plan (a start outside the certified set, or a plan run out):
            # the QP's own plan, which keeps every bound on the nominal model's
            # linearisation, uncertified (counted); the saturated LQR when the QP failed
            self.no_plan += 1
            if plan is not None:
                self.uncertified += 1
                self.effort, self.effort_age = plan, 1
                return float(plan[0][0]), slack
            # the QP failed too: the last such plan tracked as the fallback tracks its own
            k_e = self.stage_at(self.effort_age * self.dt0) if self.effort is not None else None
            if k_e is not None:
                self.effort_age += 1
                self.uncertified += 1
                return self.tracking_input(s, k_e, (self.effort_age - 1) * self.dt0,
                                           self.effort), 0.0
            return self.terminal_input(s), 0.0
        self.fallbacks += 1
        return self.tracking_input(s, k, (self.plan_age - 1) * self.dt0), 0.0

    # -- recovery (P8) -----------------------------------------------------------------
    def _recovery_nlp(self) -> Any:
        """(P8) as a CasADi nlpsol on the nominal model, multiple shooting (built on first
        use: most runs never need it).  The same over the 17 models of (P6) (a state copy
        per model, each corrected by the LQR towards the nominal's path) took minutes per
        plan: it is not done."""
        import casadi as ca

        if self._recovery is not None:
            return self._recovery
        nx, M, scale = self.nx, self.M_rec, self.u_scale
        X, V = ca.SX.sym("X", nx, M + 1), ca.SX.sym("V", M)
        t, s0 = ca.SX.sym("t"), ca.SX.sym("s0", nx)
        F0 = self.model.rk4_map(self.dt0, 1, name="mpsc_rec_first")
        F = self.model.rk4_map(self.h_rec, 1, name="mpsc_rec")
        g, lbg, ubg = [], [], []

        def rows(expr, lo, hi):
            g.append(expr)
            lbg.extend(np.broadcast_to(lo, (expr.numel(),)))
            ubg.extend(np.broadcast_to(hi, (expr.numel(),)))

        rows(X[:, 0] - s0, 0.0, 0.0)
        for k in range(M):
            rows(X[:, k + 1] - (F0 if k == 0 else F)(X[:, k], scale * V[k]), 0.0, 0.0)
        # every hard bound relaxed by t of its constraint's half-width
        for a, i in enumerate(self._checked):
            row = X[i, 1:].T
            if math.isfinite(self.hi[i]):
                rows(row - t * self._room_hi[a], -np.inf, float(self.hi[i]))
            if math.isfinite(self.lo[i]):
                rows(row + t * self._room_lo[a], float(self.lo[i]), np.inf)
        end = X[:, M]
        rows(ca.bilin(ca.DM(self.P), end, end), -np.inf, TERMINAL_AIM * self.level)
        # min t, and a little of the input's energy (in shares of its range) so that the
        # plan is unique where t does not bind
        obj = t + RECOVERY_EFFORT * ca.sumsqr(V) / M
        solver = ca.nlpsol("mpsc_recovery", "ipopt",
                           {"x": ca.vertcat(ca.vec(X), V, t), "p": s0, "f": obj,
                            "g": ca.vertcat(*g)},
                           {"print_time": False, "ipopt": {
                               "print_level": 0, "sb": "yes", "max_iter": RECOVERY_MAX_ITER}})
        lo_u = self.u_lo / scale if math.isfinite(self.u_lo) else -np.inf
        hi_u = self.u_hi / scale if math.isfinite(self.u_hi) else np.inf
        # t down to -1: below 0 the plan keeps that share of every bound's half-width to
        # spare (the least peak travel), not just the bounds
        lbx = np.concatenate([np.full(nx * (M + 1), -np.inf), np.full(M, lo_u), [-1.0]])
        ubx = np.concatenate([np.full(nx * (M + 1), np.inf), np.full(M, hi_u), [np.inf]])
        self._recovery = (solver, lbx, ubx, np.array(lbg, dtype=float),
                          np.array(ubg, dtype=float))
        return self._recovery

    def recovery_plan(self, s: np.ndarray) -> tuple | None:
        """(P8) from ``s``: ``(U (M,), X (nx, M+1), t)`` or None when IPOPT fails; warm
        started from the tracked recovery plan where there is one, else from the saturated
        LQR's rollout on the model."""
        solver, lbx, ubx, lbg, ubg = self._recovery_nlp()
        nx, M = self.nx, self.M_rec
        grid = np.concatenate([[0.0], self.dt0 + self.h_rec * np.arange(M)])
        if self.rescue is not None:
            # the tracked plan from now on, on the new grid (its last state held)
            U_old, X_old, t_old = self.rescue
            at = grid + self.rescue_age * self.dt0
            X = np.array([np.interp(at, grid, row) for row in X_old])
            X[:, 0] = s
            k = np.minimum(np.searchsorted(grid, at[:-1], side="right") - 1, M - 1)
            V = U_old[k] / self.u_scale
            t0 = t_old
        else:
            X = np.zeros((nx, M + 1))
            V = np.zeros(M)
            X[:, 0] = s
            F0, F = self._rec_maps
            for k in range(M):
                V[k] = self.terminal_input(X[:, k]) / self.u_scale
                X[:, k + 1] = np.asarray((F0 if k == 0 else F)(X[:, k],
                                                               self.u_scale * V[k])).ravel()
            t0 = 1.0
        if not np.all(np.isfinite(X)):
            X[:] = s[:, None]
        x0 = np.concatenate([X.ravel(order="F"), V, [t0]])
        sol = solver(x0=x0, p=s, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
        if not solver.stats()["success"]:
            return None
        z = np.asarray(sol["x"], dtype=float).ravel()
        X = z[:nx * (M + 1)].reshape(nx, M + 1, order="F")
        return self.u_scale * z[nx * (M + 1):nx * (M + 1) + M], X, float(z[-1])

    def recovery_input(self, s: np.ndarray, tau: float) -> float | None:
        """The recovery plan's input ``tau`` seconds into it, corrected by the LQR towards
        its state there (interpolated between its nodes); None past its end."""
        U, X, _ = self.rescue
        if tau < self.dt0 - 1e-12:
            return float(U[0])
        k = 1 + int(math.floor((tau - self.dt0) / self.h_rec + 1e-9))
        if k >= self.M_rec:
            return None
        a = min(max((tau - (self.dt0 + (k - 1) * self.h_rec)) / self.h_rec, 0.0), 1.0)
        ref = (1.0 - a) * X[:, k] + a * X[:, k + 1]
        return min(max(float(U[k] - self.K @ (s - ref)), self.u_lo), self.u_hi)

    def tracking_input(self, s: np.ndarray, k: int, tau: float, plan: tuple | None = None) -> float:
        """The certified plan's (or ``plan``'s) input in interval ``k`` at ``tau`` seconds
        into the plan, corrected by the LQR towards its state there (interpolated between
        the nodes)."""
        U, R = self.plan if plan is None else plan
        if k == 0:
            return float(U[0])
        start = self.dt0 + (k - 1) * self.h
        a = min(max((tau - start) / self.h, 0.0), 1.0)
        ref = R[:, k] if k + 1 >= self.N else (1.0 - a) * R[:, k] + a * R[:, k + 1]
        return min(max(float(U[k] - self.K @ (s - ref)), self.u_lo), self.u_hi)

    def more_metrics(self) -> dict[str, Any]:
        n = self.samples
        return {"solver": "hpipm", "horizon_s": self.dt0 + (self.N - 1) * self.h,
                "fallbacks": self.fallbacks, "no_plan": self.no_plan,
                "infeasible_samples": self.infeasible_qp, "rejected_samples": self.rejected,
                "bisected_samples": self.bisected, "fast_path_samples": self.fast,
                "uncertified_samples": self.uncertified,
                "fallback_share": (self.fallbacks + self.no_plan) / n if n else None,
                "max_slack": self.max_slack, "terminal_level": self.level,
                "recovery_plans": self.recoveries,
                "recovery_relaxation_max": (self.rescue_relaxation if self.recoveries
                                            else None),
                # (P7): how far each bounded state's bound was moved in for the disturbance
                "disturbance_tube": {name: float(self.tube[i])
                                     for i, name in enumerate(self.model.state_names)
                                     if self.tube[i] > 0.0}}


def wrap(scenario: "Scenario", inner: Controller, machine: Any) -> PredictiveSafetyFilter:
    """``inner`` behind the predictive safety filter on the scenario's nominal ``machine``
    (:func:`tspend.loop.simulation.nominal_machine`)."""
    from tspend.controllers.full_model import full_model_and_constraints, has_full_state
    from tspend.controllers.lqr import default_state_weights, design_model, lqr_full_gain
    from tspend.controllers.mpc import ocp_constraints
    from tspend.plants import registry
    from tspend.task import build_task

    if not has_full_state(scenario):
        raise ScenarioError(f"{scenario.path}: safety.filter = \"mpsc\": plant "
                            f"'{scenario.plant.kind}' has no full-state model to plan on; "
                            f"allowed: \"off\"")
    from tspend.runtime.extras import missing_extra

    problem = missing_extra("casadi", "safety.filter = \"mpsc\"")
    if problem:
        raise ScenarioError(problem)
    cfg = scenario.safety
    model, cs = full_model_and_constraints(scenario, machine)
    nx = model.size
    lo, hi, u_lo, u_hi, rows, _ = ocp_constraints(model, cs, 0.0)
    lo = np.where(lo <= -1e19, -np.inf, lo)
    hi = np.where(hi >= 1e19, np.inf, hi)
    # the fall angle is a constraint of the safe set: the certified plans keep the pole up
    task = build_task(machine, scenario.task, scenario.effects,
                      where=str(scenario.path))
    for j, limit in enumerate(task.lo_limits):
        if limit is not None and limit.status == "fell":
            i = model.state_names.index(task.names[j])
            lo[i], hi[i] = max(lo[i], task.lo[j]), min(hi[i], task.hi[j])
    A, B = design_model(scenario, machine)
    b_pole = float(B[model.dof + model.pole, 0])
    Q = np.diag(default_state_weights(model))
    K, P = lqr_full_gain(A, B, Q, b_pole ** 2)
    K = np.asarray(K, dtype=float).ravel()
    # the task's declared disturbance (P7): every bound tightened by the most it can move
    # the state off the plan while the LQR tracks it
    tube = disturbance_tube(scenario, model, A - np.outer(B[:, 0], K))
    limits = (lo.copy(), hi.copy())
    lo, hi = lo + tube, hi - tube
    # the margin: a share of each two-sided bound's half-width (the room a machine that
    # is not the model needs), kept by the plan at its nodes and by the certificate at
    # every RK4 step
    half = np.where(np.isfinite(lo) & np.isfinite(hi), 0.5 * (hi - lo), 0.0)
    bounds = (lo + cfg.margin * half, hi - cfg.margin * half,
              lo + CHECK_MARGIN * cfg.margin * half, hi - CHECK_MARGIN * cfg.margin * half)
    # (P3): inside every tightened bound and |K s| <= the input's reach
    ell_rows = []
    for i in range(nx):
        if math.isfinite(bounds[0][i]) and math.isfinite(bounds[1][i]):
            e = np.zeros(nx)
            e[i] = 1.0
            ell_rows.append((e, min(-bounds[0][i], bounds[1][i])))
    reach = min(abs(u_lo), abs(u_hi))
    if math.isfinite(reach):
        ell_rows.append((K, reach))
    level = terminal_level(P, ell_rows)
    if not math.isfinite(level):
        raise ScenarioError(f"{scenario.path}: safety.filter = \"mpsc\": no bound limits the "
                            f"terminal set (no position bound, fall angle or input range)")
    models, _ = vertex_models(scenario)
    h, horizon, _ = plan_grid(K.reshape(1, -1), model, cfg)
    level = recurrent_level([model] + models, P, K, level, bounds[0], bounds[1], u_lo, u_hi,
                            horizon * h, np.random.default_rng(0))
    if level <= 0.0:
        raise ScenarioError(f"{scenario.path}: safety.filter = \"mpsc\": the LQR's ellipsoid "
                            f"shrank to nothing without the LQR keeping it safe on the "
                            f"machine and its [randomize] vertices")
    sample = inner.sample_period or scenario.run.dt
    return PredictiveSafetyFilter(inner, model, cfg, sample, bounds, (u_lo, u_hi), rows, K, P,
                                  level, Q, b_pole ** 2, tuple(models), tube=tube, limits=limits)
