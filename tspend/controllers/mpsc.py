"""Predictive safety certification (``--safety mpsc``): a backup plan behind every input.

Model predictive safety certification (Wabersich and Zeilinger, "Linear model predictive
safety certification for learning-based control", CDC 2018; "A predictive safety filter
for learning-based control of constrained nonlinear dynamical systems", Automatica 129,
2021) on the domain's own model (:class:`~tspend.plants.domain.FullModel`, the nominal
machine) and on every corner of the ``[randomize]`` parameter box.  At every controller
sample, with ``s`` the measured full state and ``u_c`` the inner controller's command
clipped to the input's range, the filter asks for a backup plan ``u_0 .. u_{N-1}``:

    s_1 = F_0(s, u_0),  s_{k+1} = F(s_k, u_k)   (k >= 1)                         (P1)
    lo <= s_k <= hi  (the hard position boxes, the fall angle, tightened)       (P2)
    s_N in X_f = {s : s^T P s <= c}                                             (P3)
    u(t) = U_k - K (x(t) - R(t))   (k >= 1; R the plan's states, x the rollout's)   (P5)

``F_0`` one control sample (RK4), ``F`` one ``plan_period``; (P5) is the plan as it is
followed (the LQR ``K`` towards the plan's states).  Where a plan period spans at most
:data:`MAX_HELD_SAMPLES` control samples, the plan's grid is put on the samples (the
period a whole number of samples, one RK4 step per sample) and ``u`` is evaluated at each
step's start and held over it, as the runner holds it over a sample; with shorter samples
than that (the cart-pole's 1 ms against 50 ms steps) it is evaluated at every RK4 stage,
the runner's sampling taken as continuous.  **The
certificate** (P6): a plan is certified when (P5) rolled out on the nominal model *and on
every corner model* keeps (P2) at every RK4 step and ends in (P3).  Every candidate the
filter may apply is such a rollout (compiled CasADi functions, one per model, in one source:
:func:`certificate_rollout`), so an input is applied as certified only when its plan was
checked on all of them: what is solved is what is certified.  (P7) tightens (P2) by the
declared disturbance's tube; :func:`design` states every margin.

The design (:class:`Certificate`: bounds, margins, the LQR, the terminal set, the corner
models the caller built) is made once by :func:`design`; :func:`build_solvers` compiles
the rollout and the QP (cached by their C source's hash); the filter that runs per sample
only reads them.

Per sample, within ``safety.budget_ms`` (P9): the answer of step 3 (the certified plan's
input, tracked) is computed first, so a cheap certified answer is always ready; then every
step below (a rollout, an SQP step, a recovery plan) is started only when

    now + (an upper estimate of its time) <= sample start + budget - reserve         (P9)

(``now`` the wall clock, read at each start: the Python between steps is on it), else
skipped, never started (a skipped solve is dropped, not continued off the loop).  A step's
estimate is a high quantile of its recent times (about the 95th percentile:
:class:`StepCost`), not an average: a step dearer than its average ran past.  The reserve
is the same estimate of the work that always follows the last step (from its end to the
answer: the fallback's bookkeeping), measured at every sample.  The times are this
thread's time on the CPU, which is the wall time of a call not preempted: a wait for a
core, on a shared machine, is not the step's cost, no estimate predicts it, and an
estimate that took it in (wall times) blocked every rollout for tens of samples after
each preemption.  A rollout is checked model by model (:meth:`Rollout.check`, one
compiled call): each model starts only when :data:`MODEL_GUARD` times its share of the
rollout's estimate fits before the deadline less the estimate of the check's verdict, so
a rollout slower than its estimate (or a probe) stops between two models, its verdict
unknown (``rollouts_cut_short``), rather than run past; it also stops at the first model
that breaks a bound (checked first next time).  A model's rollout, like the QP's step,
cannot be interrupted once started (a compiled call, in Python): a thread preempted in
it, or work slower than its estimate, runs past, and ``over_budget_samples`` counts it.

1. on each certified tail in turn (the last certified plan's rest, tracked; the saturated
   LQR): ``[u_c, tail]`` (the fast path: a certified rollout passes ``u_c`` unchanged),
   else ``[the tail's own input, tail]``, then the closest certifiable input to ``u_c``
   between the two by bisection, halving while the budget allows;
2. one Gauss-Newton SQP step (:class:`~.mpc_rti.RealTimeSQP`, HPIPM) of

       min (u_0 - u_c)^2 + eps / R J_LQR(s_1.., u_1..) + slack penalties          (P4)

   its plan applied only when certified on every model;
3. else the last certified plan goes on, tracked by the LQR, and past its end the LQR in
   X_f (a **fallback**: certified at an earlier sample, on the models; X_f is invariant
   under the LQR (P10), so the plan never runs out: the recursive feasibility of MPSC);
4. without any certified plan yet (a start not admitted): **uncertified**, counted: the
   recovery plan (P8) made at admission (IPOPT on the nominal model, tracked by the LQR),
   else the QP's own plan, else the saturated LQR.

The terminal set X_f is invariant on every vertex model's linearisation:

    (A_i - B_i K)^T P + P (A_i - B_i K) <= r P,  r < 0,  |K s| <= u_max in X_f      (P10)

(:func:`terminal_set`; its nonlinear recurrence sampled).

**Admission** (before the first sample is filtered, outside the budget: a rig's
pre-flight check at its start): steps 1-2 with the QP iterated, then the robust plan

    min eps |W (z - z_w)|^2 over z = (U, R),  (P5) on every model keeps the bounds at
    every RK4 step and ends in (P3)                                             (P11)

(:class:`RobustAdmission`: the certificate's own rollouts as IPOPT's constraints, warm
from (P8)), then (P8) alone; the metrics say whether the start was admitted (a certified
plan from it) and why not.  With ``safety.refuse_unadmitted`` a start not admitted is
refused before its first input (:class:`~tspend.runtime.errors.RunRefused`).  So at every
sample of steps 1-2 the applied input starts a plan certified from
this state on the nominal model and every corner; at step 3 from an earlier state.
Nothing is claimed for machines between the corners, for MuJoCo's integrator against the
ODE beyond the margins stated in the metrics, or at step 4.
"""

from __future__ import annotations

import collections
import gc
import itertools
import math
import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from tspend.controllers.base import Controller, Observation
from tspend.controllers.safety import SafetyFilter
from tspend.runtime.errors import RunRefused, ScenarioError

if TYPE_CHECKING:
    from tspend.config import SafetyConfig, Scenario
    from tspend.plants.domain import FullModel

__all__ = ["Certificate", "PredictiveSafetyFilter", "StepCost", "build_solvers", "design",
           "terminal_level", "vertex_models", "wrap"]

#: eps of (P4): the weight of the backup plan's own LQR cost against the first input's
#: distance from the command (1 on the input's range)
PROXIMAL = 1e-1
#: (P3)'s level is shrunk by this factor until the decrease holds on every sampled point
SHRINK = 0.8
#: boundary points of X_f sampled per model for the recurrence check
BOUNDARY_POINTS = 64
#: the QP aims its plan's end at this share of (P3)'s level, the certificate checks all
#: of it; the plan keeps the whole margin from its second node on, the certificate
#: CHECK_MARGIN of it: the room between absorbs the difference between the linearised
#: plan and its rollout, between nodes too
TERMINAL_AIM = 0.95
CHECK_MARGIN = 0.8
#: the plan's end level costs as much as a command TERMINAL_WEIGHT x the input's range off
TERMINAL_WEIGHT = 0.1
#: the most bisection steps between the command and the certified plan's input (2^-8 of
#: the gap); the budget may allow fewer
BISECTIONS = 8
#: the longest plan (intervals) chosen automatically
MAX_AUTO_HORIZON = 40
#: (P5) holds u over each control sample, as the runner does, where a plan period spans
#: at most this many samples (one RK4 step each: a controller held for 10 ms against a
#: 19 ms RK4 step, tracked at every stage, left the double cart-pole's box); with shorter
#: samples the rollout tracks at every RK4 stage
MAX_HELD_SAMPLES = 8
#: HPIPM's options for the QP: "speed_abs" stops at the absolute residuals (1e-7), and at
#: most QP_ITERATIONS interior-point iterations bound a step's time (uncapped, 100: behind
#: the double cart-pole's policy, 8 ms budget, a sample's QP took 2.3 ms median and up to
#: 14 ms; capped at 30, at most 5.2 ms, with as many plans certified, seeds 0-19).  An
#: answer cut short is a proposal like any other: the certificate decides
QP_ITERATIONS = 30
QP_OPTIONS = {"mode": "speed_abs", "iter_max": QP_ITERATIONS}
#: the largest constraint residual of a QP's answer taken as a step (the certificate
#: decides: a millimetre of residual in the linearised rows costs no safety)
QP_ACCEPTANCE = 1e-3
#: SQP steps at admission (no budget there), and the step below which they stop
ADMISSION_ITERATIONS = 10
SQP_TOLERANCE = 1e-8
#: the recovery plan (P8): intervals of the plan's interval / RECOVERY_REFINE
RECOVERY_REFINE = 5
#: IPOPT's iterations for one recovery plan
RECOVERY_MAX_ITER = 200
#: (P8)'s weight on the input's energy (in shares of its range, per interval) beside t
RECOVERY_EFFORT = 1e-3
#: (P11), the robust admission plan: IPOPT's iterations at most (it stops at the first
#: iterate whose rollouts keep every bound on every model: about 10 on the cart-pole)
ADMISSION_MAX_ITER = 40
#: (P11) keeps this share of each checked bound's half-width to spare and aims its end at
#: ADMISSION_AIM of (P3)'s level: room for IPOPT's tolerance (the certificate, which
#: checks the whole bounds, then decides)
ADMISSION_SPARE = 0.01
ADMISSION_AIM = 0.9
#: (P11)'s weight on the plan's distance from its warm start (in the input's range and the
#: bounds' half-widths): a feasibility problem, regularised so that IPOPT's steps are small
ADMISSION_PROXIMAL = 1e-2
#: the disturbance's samples read for its bound (P7)
MAX_DISTURBANCE_SAMPLES = 10 ** 6
#: at most this many [randomize] parameters spanned by corners (2^6 = 64 models)
MAX_VERTEX_PARAMETERS = 6
#: (P9): the default budget, a share of the control period (the rest is the inner
#: controller's and the loop's)
BUDGET_SHARE = 0.8
#: (P10): the Nelder-Mead search for a Lyapunov function common to the vertex models
LYAPUNOV_EVALUATIONS = 2000
#: (P10): the decay rate (1/s) the search asks of the common Lyapunov function
DECAY_MARGIN = 0.05
#: (P9): a step's estimate is the COST_RANK-th largest of its times in the last
#: COST_WINDOW samples (about their 95th percentile: the largest, on the shared machine, was
#: a call slowed by another process's use of the caches often enough to block most
#: rollouts).  The window is counted in samples, not calls: a spell of slow calls (or
#: admission's first, cold ones) leaves it after COST_WINDOW samples even when the step
#: was blocked meanwhile (a window of calls was refilled only by the rare calls that fit,
#: and blocked the rollout for thousands of samples).  With fewer than COST_RANK times in
#: it the rollout's estimate is 0 for one call a sample (a probe, which may run past: the
#: rollout is the only way to certify again, and its first call after a pause is slow
#: with cold caches), else their largest; the QP's and the recovery plan's keep their
#: last time (measured at admission, the QP's by its slowest SQP step: at 1 kHz it
#: rarely if ever runs)
COST_WINDOW = 64
COST_RANK = 4
#: (P9): the work of fixed size a sample always does after a step (the reserve, a
#: check's verdict) is estimated by the largest of its times in the window: after a
#: rollout, with the caches cold, it ran up to three times its usual time, and with the
#: second largest samples went over the budget by a few tens of microseconds (15 against
#: 4 with the largest, cart-pole seeds 0-9 run twice, closed loop and paced alike).  A
#: sample in which the garbage collector made a full collection is left out of it
#: (:func:`collections_run`): one would otherwise block the rollouts for a window
FIXED_COST_RANK = 1
#: (P9): a rollout's next model starts only when this many times its share of the
#: rollout's estimate fits before the deadline (a model slower than its share by up to
#: this factor still ends in time)
MODEL_GUARD = 1.5
#: why a sample ran past the budget (the metrics' ``over_budget_by_cause``): its CPU time
#: fits the budget (the thread waited for a core: no estimate predicts it), a rollout
#: started as a probe, or a step that took longer than its estimate
OVER_BUDGET_CAUSES = ("waited_for_a_core", "probe", "step_over_its_estimate")


def collections_run() -> int:
    """How many full collections (the oldest generation, which walks every object: a
    millisecond or more) the garbage collector has made in this process.  The young
    generations' collections are short and frequent: part of a step's own cost."""
    return gc.get_stats()[-1]["collections"]


class StepCost:
    """(P9): an upper estimate of one step's time (s): the :data:`COST_RANK`-th largest of
    its times in the last :data:`COST_WINDOW` samples; with fewer, their largest, or 0 for
    a ``probe`` step not yet run in this sample; a step that is not a probe keeps its last
    time.  Unmeasured: infinite (only admission's unbounded deadline starts the step)."""

    __slots__ = ("estimate", "probe", "times", "sample", "last", "rank")

    def __init__(self, probe: bool = False, rank: int = COST_RANK) -> None:
        #: (sample, time) of its calls
        self.times: collections.deque = collections.deque()
        self.estimate = math.inf
        self.probe = probe
        self.sample = 0
        #: the estimate is the rank-th largest time in the window
        self.rank = rank
        #: the last time measured (a probe's zero estimate says nothing of its length)
        self.last = math.inf

    def _rank(self) -> None:
        times = sorted(t for _, t in self.times)
        if len(times) >= self.rank:
            self.estimate = times[-self.rank]
        elif self.probe and not (times and self.times[-1][0] == self.sample):
            self.estimate = 0.0
        else:
            self.estimate = times[-1]

    def measured(self, time_s: float) -> None:
        self.last = time_s
        self.times.append((self.sample, time_s))
        self._rank()

    def new_sample(self) -> None:
        """A new sample: the times older than the window forgotten."""
        self.sample += 1
        times, oldest = self.times, self.sample - COST_WINDOW
        expired = False
        while times and times[0][0] < oldest and (self.probe or len(times) > 1):
            times.popleft()
            expired = True
        if expired or (self.probe and len(times) < self.rank):
            self._rank()


def terminal_level(P: np.ndarray, rows: list[tuple[np.ndarray, float]]) -> float:
    """The largest ``c`` with ``{s^T P s <= c}`` inside every ``|a^T s| <= b`` of ``rows``:
    ``min b^2 / (a^T P^-1 a)`` (the support function of the ellipsoid)."""
    P_inv = np.linalg.inv(P)
    return min((b * b / float(a @ P_inv @ a) for a, b in rows if b > 0.0), default=math.inf)


def decay_rate(closed_loops: list[np.ndarray], P: np.ndarray) -> float:
    """``max_i lambda_max(P^-1/2 (A_i^T P + P A_i) P^-1/2)``: ``V' <= rate V`` for ``V = s^T P
    s`` on every closed loop ``A_i`` (inf when ``P`` is not positive definite)."""
    w, V = np.linalg.eigh(0.5 * (P + P.T))
    if w.min() <= 1e-12 * max(w.max(), 1e-300):
        return math.inf
    root = V @ np.diag(w ** -0.5) @ V.T
    return max(float(np.linalg.eigvalsh(root @ (A.T @ P + P @ A) @ root).max())
               for A in closed_loops)


def common_lyapunov(closed_loops: list[np.ndarray], start: np.ndarray,
                    rows: list) -> tuple[np.ndarray, float]:
    """``(P, rate)``: a quadratic Lyapunov function common to every closed loop ``A_i - B_i K``
    (the vertex models' linearisations, (P10)) and its decay rate (:func:`decay_rate`).
    The search (Nelder-Mead over ``P``'s Cholesky factor from ``start``, the nominal Riccati
    matrix) maximises the least share of the Riccati set's reach along each state kept by
    ``{s^T P s <= c}`` at its level inside ``rows`` (:func:`terminal_level`) while ``rate <=
    -``:data:`DECAY_MARGIN`; it only proposes: the
    rate is the eigenvalue check of the ``P`` it returns.  Why not the Riccati ``P``: its
    decrease fails on the corners whose ``A - B K`` is not the nominal's."""
    from scipy.optimize import minimize

    n = start.shape[0]
    lower = np.tril_indices(n)

    def unpack(p: np.ndarray) -> np.ndarray:
        L = np.zeros((n, n))
        L[lower] = p
        return L @ L.T

    # the Riccati set's reach along each state: the search keeps as much of it as it can
    reach_lqr = np.sqrt(terminal_level(start, rows) * np.diag(np.linalg.inv(start)))

    def cost(p: np.ndarray) -> float:
        P = unpack(p)
        rate = decay_rate(closed_loops, P)
        if not math.isfinite(rate):
            return math.inf
        reach = np.sqrt(terminal_level(P, rows) * np.diag(np.linalg.inv(P)))
        return -float(np.min(reach / reach_lqr)) + 1e3 * max(rate + DECAY_MARGIN, 0.0)

    p0 = np.linalg.cholesky(start / np.trace(start))[lower]
    found = minimize(cost, p0, method="Nelder-Mead", options={"maxfev": LYAPUNOV_EVALUATIONS})
    P = unpack(found.x)
    return P, decay_rate(closed_loops, P)


def recurrent_level(models: list["FullModel"], P: np.ndarray, K: np.ndarray, c: float,
                    lo: np.ndarray, hi: np.ndarray, u_lo: float, u_hi: float, T: float,
                    rng: np.random.Generator) -> float:
    """``c`` shrunk by :data:`SHRINK` until, on every model, the saturated LQR
    ``u = clip(-K s)`` from :data:`BOUNDARY_POINTS` sampled points of the ellipsoid's
    boundary keeps every bound ``lo <= s <= hi`` at every 20 ms step for ``T`` seconds and
    ends back inside the ellipsoid (a sampled check, not a proof); 0 when 15 shrinks do
    not reach it.  (P10) proves the decrease on the vertex models' linearisations; this is
    the nonlinear models' part: the set recurrent and safe under the LQR, sampled."""
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
    intervals), and RK4 steps of at most 0.25 / the fastest pole of ``A`` or ``A - B K``
    (:func:`held_grid` may then put it on the control samples)."""
    A, B = model.linearisation()
    poles = np.linalg.eigvals(A - B @ K)
    h = cfg.plan_period or min(0.1, max(0.005, 0.5 / float(np.abs(poles).max())))
    slowest = float(np.abs(poles.real).min())
    horizon = cfg.horizon or int(min(MAX_AUTO_HORIZON, max(10, math.ceil(3.0 / (slowest * h)))))
    fastest = max(float(np.abs(poles).max()), float(np.abs(np.linalg.eigvals(A)).max()))
    substeps = cfg.substeps or max(1, math.ceil(h * fastest / 0.25))
    return h, horizon, substeps


def held_grid(h: float, horizon: int, substeps: int,
              sample_s: float) -> tuple[float, int, int, bool]:
    """``(plan_period, horizon, substeps, held)``: where ``h`` spans at most
    :data:`MAX_HELD_SAMPLES` samples, the period rounded to a whole number ``k`` of
    samples, ``k`` RK4 steps of one sample each and the horizon keeping its length in
    time, held (P5); else the grid as it was, not held."""
    k = max(1, round(h / sample_s))
    if k > MAX_HELD_SAMPLES:
        return h, horizon, substeps, False
    held_h = k * sample_s
    return held_h, max(1, math.ceil(horizon * h / held_h - 1e-9)), k, True


@dataclass(frozen=True)
class Certificate:
    """The filter's design, made once by :func:`design` on the nominal machine and the
    corner machines the caller built: what the certificate checks and the numbers the
    filter reads at every sample (nothing here is changed by a run)."""

    model: "FullModel"
    #: the corner models of the [randomize] box (P6), and the parameters they span
    corners: tuple
    corner_names: tuple[str, ...]
    sample_s: float
    h: float
    N: int
    substeps: int
    #: the plan's bounds (the QP's, tightened by the margin) and the certificate's
    lo: np.ndarray
    hi: np.ndarray
    lo_check: np.ndarray
    hi_check: np.ndarray
    #: the hard bounds before any tightening (the recovery plan's unit of relaxation)
    limits: tuple[np.ndarray, np.ndarray]
    #: (P7)'s tightening per state
    tube: np.ndarray
    u_lo: float
    u_hi: float
    #: the soft rows of the run's constraint set (C, D, b, selection) for the QP
    rows: tuple
    K: np.ndarray
    P: np.ndarray
    level: float
    Q: np.ndarray
    R: float
    #: (P9): seconds per sample
    budget_s: float
    #: how X_f's invariance was shown (P10): "vertex_lyapunov" (a Lyapunov decrease common
    #: to every vertex model's linearisation, the nonlinear models sampled), else "sampled"
    terminal: str = "sampled"
    #: the balancing LQR's Riccati matrix (the QP's cost to go; ``P`` is X_f's)
    P_cost: np.ndarray | None = None
    #: (P5): u held over each RK4 step (one control sample), else tracked at every stage
    held: bool = False
    #: (P10)'s proven decay rate of ``s^T P s`` on the vertex linearisations (1/s; < 0: shown)
    decay_rate: float = math.nan


def hard_bounds(scenario: "Scenario", machine: Any, model: "FullModel",
                cs: Any) -> tuple[np.ndarray, np.ndarray, float, float, tuple]:
    """``(lo, hi, u_lo, u_hi, rows)``: the hard boxes of the run's constraint set and the
    task's fall angle (a constraint of the safe set: certified plans keep the pole up),
    the input's range and the soft rows."""
    from tspend.controllers.mpc import ocp_constraints
    from tspend.task import build_task

    lo, hi, u_lo, u_hi, rows, _ = ocp_constraints(model, cs, 0.0)
    lo = np.where(lo <= -1e19, -np.inf, lo)
    hi = np.where(hi >= 1e19, np.inf, hi)
    task = build_task(machine, scenario.task, scenario.effects, where=str(scenario.path))
    for j, limit in enumerate(task.lo_limits):
        if limit is not None and limit.status == "fell":
            i = model.state_names.index(task.names[j])
            lo[i], hi[i] = max(lo[i], task.lo[j]), min(hi[i], task.hi[j])
    return lo, hi, u_lo, u_hi, rows


def ellipsoid_rows(bounds: tuple, K: np.ndarray, u_lo: float, u_hi: float) -> list:
    """(P3)'s rows: every two-sided tightened bound, and ``|K s| <= `` the input's reach."""
    rows = []
    for i in range(bounds[0].size):
        if math.isfinite(bounds[0][i]) and math.isfinite(bounds[1][i]):
            e = np.zeros(bounds[0].size)
            e[i] = 1.0
            rows.append((e, min(-bounds[0][i], bounds[1][i])))
    reach = min(abs(u_lo), abs(u_hi))
    if math.isfinite(reach):
        rows.append((K, reach))
    return rows


def design(scenario: "Scenario", machine: Any, corners: list, names: list[str],
           sample_s: float) -> Certificate:
    """The certificate's numbers for ``scenario`` on its nominal ``machine`` and the
    ``corners`` (FullModels of the [randomize] box's corners, :func:`vertex_models`),
    for a controller sampled every ``sample_s`` seconds."""
    from tspend.controllers.full_model import full_model_and_constraints
    from tspend.controllers.lqr import default_state_weights, design_model, lqr_full_gain

    cfg = scenario.safety
    model, cs = full_model_and_constraints(scenario, machine)
    lo, hi, u_lo, u_hi, rows = hard_bounds(scenario, machine, model, cs)
    A, B = design_model(scenario, machine)
    b_pole = float(B[model.dof + model.pole, 0])
    Q = np.diag(default_state_weights(model))
    K, P = lqr_full_gain(A, B, Q, b_pole ** 2)
    K = np.asarray(K, dtype=float).ravel()
    # (P7): every bound moved in by the most the disturbance can move the tracked state
    tube = disturbance_tube(scenario, model, A - np.outer(B[:, 0], K))
    limits = (lo.copy(), hi.copy())
    lo, hi = lo + tube, hi - tube
    # the margin: a share of each two-sided bound's half-width, kept by the plan at its
    # nodes and (CHECK_MARGIN of it) by the certificate at every RK4 step
    half = np.where(np.isfinite(lo) & np.isfinite(hi), 0.5 * (hi - lo), 0.0)
    bounds = (lo + cfg.margin * half, hi - cfg.margin * half,
              lo + CHECK_MARGIN * cfg.margin * half, hi - CHECK_MARGIN * cfg.margin * half)
    h, horizon, substeps, held = held_grid(*plan_grid(K.reshape(1, -1), model, cfg),
                                           sample_s)
    P_set, level, rate = terminal_set([model] + list(corners), P, K, bounds, u_lo, u_hi,
                                      horizon * h)
    if not math.isfinite(level):
        raise ScenarioError(f"{scenario.path}: safety.filter = \"mpsc\": no bound limits the "
                            f"terminal set (no position bound, fall angle or input range)")
    if level <= 0.0:
        raise ScenarioError(f"{scenario.path}: safety.filter = \"mpsc\": the LQR's ellipsoid "
                            f"shrank to nothing without the LQR keeping it safe on the "
                            f"machine and its [randomize] corners")
    budget = cfg.budget_ms * 1e-3 if cfg.budget_ms > 0.0 else BUDGET_SHARE * sample_s
    return Certificate(model, tuple(corners), tuple(names), float(sample_s), h, horizon + 1,
                       substeps, *bounds, limits, tube, float(u_lo), float(u_hi), rows, K,
                       P_set, level, Q, b_pole ** 2, budget,
                       terminal="vertex_lyapunov" if rate < 0.0 else "sampled",
                       P_cost=P, decay_rate=rate, held=held)


def terminal_set(models: list["FullModel"], P_lqr: np.ndarray, K: np.ndarray, bounds: tuple,
                 u_lo: float, u_hi: float, T: float) -> tuple[np.ndarray, float, float]:
    """(P3) and (P10): ``(P, c, rate)``.  ``P`` a Lyapunov function common to every model's
    linearised closed loop under the LQR (:func:`common_lyapunov`; the Riccati ``P_lqr``
    when none is found, ``rate >= 0``), ``c`` the largest level inside every tightened bound
    and ``|K s| <= `` the input's reach (so the LQR does not saturate in the set: on each
    vertex linearisation the set is invariant, ``V' <= rate V``), then shrunk until the
    sampled check on the nonlinear models holds (:func:`recurrent_level`)."""
    closed = []
    for m in models:
        A, B = m.linearisation()
        closed.append(A - np.outer(B[:, 0], K))
    rows = ellipsoid_rows(bounds, K, u_lo, u_hi)
    P, rate = P_lqr, decay_rate(closed, P_lqr)
    if rate >= 0.0:
        # the Riccati P decreases on the nominal loop, not always on the corners'
        P, rate = common_lyapunov(closed, P_lqr, rows)
        if rate >= 0.0:
            P, rate = P_lqr, decay_rate(closed, P_lqr)
    level = terminal_level(P, rows)
    if math.isfinite(level):
        level = recurrent_level(models, P, K, level, bounds[0], bounds[1], u_lo, u_hi, T,
                                np.random.default_rng(0))
    return P, level, rate


def tracked_step(m: "FullModel", dt: float, K: np.ndarray, u_lo: float, u_hi: float,
                 name: str, held: bool = False) -> Any:
    """One RK4 step of (P5) on ``m``: ``u = clip(U_k - K (x - ref))``, ``ref`` moving
    linearly from ``ref_0`` to ``ref_1`` over the step, evaluated at every stage (the
    runner's sampling taken as continuous) or, ``held``, at the step's start and held
    over it (a step is one control sample); ``(x, U_k, ref_0, ref_1) -> (x_next, u at
    the step's start)``."""
    import casadi as ca

    x, Uk = ca.SX.sym("x", m.size), ca.SX.sym("u")
    r0, r1 = ca.SX.sym("r0", m.size), ca.SX.sym("r1", m.size)
    f, gain = m.symbolic(), ca.DM(K)
    lo, hi = (u_lo if math.isfinite(u_lo) else -1e19), (u_hi if math.isfinite(u_hi) else 1e19)

    def law(y, ref):
        return ca.fmin(ca.fmax(Uk - ca.dot(gain, y - ref), lo), hi)

    mid, u0 = 0.5 * (r0 + r1), law(x, r0)
    if held:
        k1 = f(x, u0)
        k2 = f(x + dt / 2 * k1, u0)
        k3 = f(x + dt / 2 * k2, u0)
        k4 = f(x + dt * k3, u0)
    else:
        k1 = f(x, u0)
        k2 = f(x + dt / 2 * k1, law(x + dt / 2 * k1, mid))
        k3 = f(x + dt / 2 * k2, law(x + dt / 2 * k2, mid))
        k4 = f(x + dt * k3, law(x + dt * k3, r1))
    return ca.Function(name, [x, Uk, r0, r1],
                       [x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4), u0])


def model_paths(cert: Certificate, s0: Any, Un: Any, Rn: Any) -> list:
    """(P5) from ``s0`` for the plan ``(Un (N,), Rn (nx, N))`` (CasADi MX) on the nominal
    model and every corner (P6): per model ``(path, used)``, its states after the first
    sample and after every RK4 step ``(nx, 1 + steps)`` and the inputs it applied."""
    steps = plan_steps(cert, Un, Rn)
    return [model_path(cert, i, s0, Un[0], *steps) for i in range(1 + len(cert.corners))]


def plan_steps(cert: Certificate, Un: Any, Rn: Any) -> tuple:
    """The plan on (P5)'s RK4 steps after the first sample: each step's ``U_k`` (1, steps)
    and its reference at the step's start and end (nx, steps): interval k's RK4 step j
    goes towards ``R_k + a (R_{k+1} - R_k)`` with a from j/sub to (j+1)/sub over the step
    (``R_k`` throughout the last interval).  The same for every model."""
    import casadi as ca

    nx, N, sub = cert.model.size, cert.N, cert.substeps
    k = np.repeat(np.arange(1, N), sub)
    last = k + 1 >= N
    j = np.tile(np.arange(sub), N - 1)
    nxt = [int(i) for i in np.where(last, k, k + 1)]

    def ref(a: np.ndarray) -> Any:
        a = ca.DM(np.where(last, 0.0, a)).T
        return (Rn[:, [int(i) for i in k]] * ca.repmat(1.0 - a, nx, 1)
                + Rn[:, nxt] * ca.repmat(a, nx, 1))

    return Un[[int(i) for i in k]].T, ref(j / sub), ref((j + 1) / sub)


def model_path(cert: Certificate, i: int, s0: Any, U0: Any, U: Any, start: Any,
               end: Any) -> tuple:
    """(P5) on model ``i`` (0 the nominal, then the corners) from ``s0``: ``U0`` over the
    first sample, then the RK4 steps of :func:`plan_steps`; ``(path, used)``."""
    import casadi as ca

    m = (cert.model, *cert.corners)[i]
    x1 = m.rk4_map(cert.sample_s, 1, name=f"mpsc_first_{i}")(s0, U0)
    step = tracked_step(m, cert.h / cert.substeps, cert.K, cert.u_lo, cert.u_hi,
                        f"mpsc_step_{i}", cert.held)
    X, used = step.mapaccum(f"mpsc_plan_{i}", U.shape[1])(x1, U, start, end)
    return ca.horzcat(x1, X), ca.horzcat(U0, used)


def certificate_rollout(cert: Certificate) -> list:
    """(P5) on the nominal model and every corner (P6) as CasADi functions: first
    ``tspend_mpsc_plan_steps`` ``(U (N,), R (nx, N)) -> (`` :func:`plan_steps` ``)``,
    shared by all, then one per model ``(s, U, the plan's steps) -> (summary, excess[,
    nominal])``: the least and the largest value of each state after ``s`` and the last
    state ``(3 nx,)`` (what the certificate reads), the most the rollout breaks a
    certified bound or (P3) by (> 0: broken; a non-finite state is left to the full
    check), and for the nominal model its states (``s``, after the first sample, after
    every RK4 step) over the inputs it applied ``(nx + 1, 2 + steps)``.  One function per
    model, so that a check stops at the first model that breaks a bound and at the
    budget's end (:meth:`Rollout.check`).  One RK4 step per model, iterated by
    ``mapaccum``: the C source grows with the models, not with the horizon (the unrolled
    rollout for 17 models was 9.3 MB, 453 s of gcc)."""
    import casadi as ca

    nx, N = cert.model.size, cert.N
    Un, Rn = ca.MX.sym("U", N), ca.MX.sym("R", nx, N)
    steps = plan_steps(cert, Un, Rn)
    fns = [ca.Function("tspend_mpsc_plan_steps", [Un, Rn], list(steps))]
    s0 = ca.MX.sym("s0", nx)
    symbols = [ca.MX.sym(f"steps_{j}", *x.shape) for j, x in enumerate(steps)]
    for i in range(1 + len(cert.corners)):
        path, used = model_path(cert, i, s0, Un[0], *symbols)
        least = [ca.mmin(path[j, :]) for j in range(nx)]
        most = [ca.mmax(path[j, :]) for j in range(nx)]
        last = path[:, -1]
        excess = [last.T @ ca.DM(cert.P) @ last - cert.level]
        excess += [cert.lo_check[j] - least[j] for j in range(nx) if np.isfinite(cert.lo_check[j])]
        excess += [most[j] - cert.hi_check[j] for j in range(nx) if np.isfinite(cert.hi_check[j])]
        outputs = [ca.vertcat(*least, *most, last), ca.mmax(ca.vertcat(*excess))]
        if i == 0:
            outputs.append(ca.vertcat(ca.horzcat(s0, path), ca.horzcat(Un[0], used)))
        fns.append(ca.Function(f"tspend_mpsc_model_{i}", [s0, Un, *symbols], outputs))
    return fns


class Rollout:
    """:func:`certificate_rollout` evaluated in place, one model after another: compiled,
    one call of ``mpsc_check.c`` per check (:meth:`check`); else CasADi's buffer interface
    on persistent arrays (a Python call with its conversions costs several times the
    compiled rollout)."""

    def __init__(self, fns: list, cert: Certificate, library: Any = None) -> None:
        nx, N, sub = cert.model.size, cert.N, cert.substeps
        self.fns, self.nx, self.N, self.sub = fns, nx, N, sub
        self.models, self.cols = len(fns) - 1, 2 + (N - 1) * sub
        self._in = (np.zeros(nx), np.zeros(N), np.zeros((N, nx)))
        # column-major outputs: [model, summary], each model's excess, [step, state..., u]
        # of the nominal model; the plan on the RK4 steps (plan_steps), made once a check
        self._summary = np.zeros((self.models, 3 * nx))
        self.excess = np.zeros(self.models)
        self._nominal = np.zeros((self.cols, nx + 1))
        steps = self.cols - 2
        self._steps = (np.zeros(steps), np.zeros((steps, nx)), np.zeros((steps, nx)))
        self._buffers, self._evals = [], []
        for m, fn in enumerate(fns):
            buffer, evaluate = fn.buffer()
            for i, array in enumerate(self._arguments(m)):
                buffer.set_arg(i, memoryview(array.reshape(-1)))
            for i, array in enumerate(self._results(m)):
                buffer.set_res(i, memoryview(array.reshape(-1)))
            self._buffers.append(buffer)
            self._evals.append(evaluate)
        #: the order the models are checked in: the last that broke a bound first
        self.order = np.arange(self.models, dtype=np.int32)
        self._compiled = None if library is None else compiled_check(library, self)

    def _arguments(self, f: int) -> tuple:
        """Function ``f``'s inputs (0 :func:`plan_steps`, then the models)."""
        return self._in[1:] if f == 0 else self._in[:2] + self._steps

    def _results(self, f: int) -> tuple:
        m = f - 1
        if f == 0:
            return self._steps
        return (self._summary[m], self.excess[m:m + 1]) + ((self._nominal,) if m == 0 else ())

    def load(self, s: np.ndarray, U: np.ndarray, R: np.ndarray) -> None:
        s_in, U_in, R_in = self._in
        s_in[:], U_in[:], R_in[:] = s, U, R.T

    def run(self, s: np.ndarray, U: np.ndarray, R: np.ndarray) -> np.ndarray:
        """(P5) from ``s`` on every model: per model ``[least state, largest state, last
        state]`` (a view, valid until the next call)."""
        self.load(s, U, R)
        for evaluate in self._evals:
            evaluate()
        return self._summary

    def check(self, s: np.ndarray, U: np.ndarray, R: np.ndarray, until_s: float,
              guard_s: float) -> tuple[np.ndarray | bool | None, int, float]:
        """(P5) from ``s``, model after model (:attr:`order`), each started only when
        ``guard_s`` fits before ``until_s`` (``time.perf_counter``'s clock; the first model
        regardless while ``guard_s`` is infinite, unmeasured): ``(the summary
        of every model, models run, their CPU time)`` when no model broke a bound by its
        excess (the caller's full check decides), ``(False, ...)`` at the first that did
        (it moves to the front), ``(None, ...)`` when the next did not fit."""
        self.load(s, U, R)
        if self._compiled is not None:
            return self._compiled(until_s, guard_s)
        self._evals[0]()
        order, excess, evals, clock = self.order, self.excess, self._evals, time.perf_counter
        started = time.thread_time()
        for n, m in enumerate(order):
            # the first model too, unless its guard is unmeasured (a first probe runs one)
            if (n or math.isfinite(guard_s)) and clock() + guard_s > until_s:
                return None, n, time.thread_time() - started
            evals[m + 1]()
            if excess[m] > 0.0:
                order[1:n + 1] = order[:n].copy()
                order[0] = m
                return False, n + 1, time.thread_time() - started
        return self._summary, self.models, time.thread_time() - started

    def nominal(self, s: np.ndarray, U: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The nominal model's states at the plan's nodes (nx, N + 1) and the inputs it
        applied at each interval's start (N,)."""
        self.load(s, U, R)
        self._evals[0]()
        self._evals[1]()
        V = self._nominal
        every = V[:, :self.nx].T
        nodes = np.hstack([every[:, :2], every[:, 1 + self.sub::self.sub]])
        return nodes.copy(), V[1::self.sub, self.nx][:self.N].copy()


#: a time beyond any deadline, in ns (half of C's long long: sums of two stay in range)
_FAR_NS = 2 ** 62


def compiled_check(library: Any, roll: Rollout) -> Any:
    """``mpsc_check.c`` in ``library`` bound to ``roll``'s arrays: ``check(until_s,
    guard_s)`` as :meth:`Rollout.check` returns it."""
    import ctypes

    lib = ctypes.CDLL(str(library))
    ptr, n_fns = ctypes.c_void_p, roll.models + 1
    names = [fn.name() for fn in roll.fns]
    sizes = np.zeros((n_fns, 4), dtype=np.int64)
    for f, name in enumerate(names):
        size = [ctypes.c_longlong() for _ in range(4)]
        getattr(lib, name + "_work")(*map(ctypes.byref, size))
        sizes[f] = [v.value for v in size]
    n_arg, n_res, n_iw, n_w = (int(x) + 1 for x in sizes.max(axis=0))

    def pointers(arrays: tuple, n: int) -> Any:
        return (ptr * n)(*[a.ctypes.data for a in arrays])

    prepare_arg, prepare_res = pointers(roll._arguments(0), n_arg), pointers(roll._results(0), n_res)
    arg = pointers(roll._arguments(1), n_arg)
    res = [pointers(roll._results(f), n_res) for f in range(1, n_fns)]
    res_of = (ptr * roll.models)(*[ctypes.addressof(r) for r in res])
    fns = (ptr * n_fns)(*[ctypes.cast(getattr(lib, name), ptr).value for name in names])
    iw, w = np.zeros(n_iw, dtype=np.int64), np.zeros(n_w)
    status, cpu_s = ctypes.c_int(), ctypes.c_double()
    check = lib.tspend_mpsc_check
    check.restype = ctypes.c_int
    check.argtypes = [ptr] * 3 + [ctypes.c_int] + [ptr] * 7 + [ctypes.c_longlong] * 2 + [ptr] * 2
    at = ctypes.addressof
    fixed = (fns[0], at(prepare_arg), at(prepare_res), roll.models, at(fns) + ctypes.sizeof(ptr),
             at(arg), at(res_of), iw.ctypes.data, w.ctypes.data, roll.excess.ctypes.data,
             roll.order.ctypes.data)
    # what the addresses point into, alive as long as the check
    keep = (lib, prepare_arg, prepare_res, arg, res, res_of, fns, iw, w)
    outcome = {0: lambda: roll._summary, 1: lambda: False, 2: lambda: None}

    def run(until_s: float, guard_s: float) -> tuple:
        # no deadline (admission): every model; an unmeasured guard: the first model only;
        # a deadline gone: none (the first too once its guard is measured)
        until_ns = (int(until_s * 1e9) if math.isfinite(until_s) else
                    _FAR_NS if until_s > 0 else -_FAR_NS)
        guard_ns = (0 if until_ns == _FAR_NS else
                    int(guard_s * 1e9) if math.isfinite(guard_s) else _FAR_NS)
        n = check(*fixed, until_ns, guard_ns, ctypes.byref(status), ctypes.byref(cpu_s))
        if status.value == 3:
            raise RuntimeError(f"the compiled rollout failed ({keep[0]._name})")
        return outcome[status.value](), n, cpu_s.value

    return run


def plan_qp(cert: Certificate, cfg: "SafetyConfig", compiled: bool) -> Any:
    """(P4) as a :class:`~.mpc_rti.RealTimeSQP`: the hard bounds (P2) as exact-penalty rows
    (the QP proposes, the certificate decides), (P3) as the cube ``|L^T s_N| <= sqrt(0.95 c
    / n)`` (``P = L L^T``) inside the ellipsoid and a cost on the end's level."""
    import casadi as ca

    from tspend.controllers.mpc_rti import RealTimeSQP

    nx, N, model = cert.model.size, cert.N, cert.model
    G, bG, ns = qp_rows(cert)
    nz = nx + 1 + ns
    scale = max([abs(v) for v in (cert.u_lo, cert.u_hi) if math.isfinite(v)], default=1.0)
    # the Hessian in the input's unit, times scale^2: the first input against the command
    # (weight 1), the rest of the plan a small LQR cost (eps), the slacks
    stages = np.zeros((N, nz, nz))
    stages[:, :nx, :nx] = 2.0 * PROXIMAL * cert.Q / cert.R
    stages[:, nx, nx] = 2.0 * PROXIMAL
    stages[0, nx, nx] = 2.0
    stages[:, nx + 1:, nx + 1:] = 2.0 * scale ** 2 * np.eye(ns)
    terminal = (2.0 * PROXIMAL * (cert.P if cert.P_cost is None else cert.P_cost) / cert.R
                + 2.0 * (TERMINAL_WEIGHT * scale) ** 2 * cert.P / cert.level)
    free = np.full(nx, np.inf)
    z_lo = np.concatenate([np.tile(np.concatenate([-free, [cert.u_lo], np.zeros(ns)]), N), -free])
    z_hi = np.concatenate([np.tile(np.concatenate([free, [cert.u_hi], np.full(ns, np.inf)]), N),
                           free])
    L = np.linalg.cholesky(cert.P)
    xN = ca.SX.sym("xN", nx)
    cube = ca.mtimes(ca.DM(L.T), xN) / math.sqrt(TERMINAL_AIM * cert.level / nx)
    inner_box = ca.Function("mpsc_terminal", [xN], [ca.vertcat(cube, -cube) - 1.0])
    gradient = np.concatenate([np.zeros(nx + 1), np.full(ns, cfg.slack_weight * scale ** 2)])
    return RealTimeSQP(model.rk4_map(cert.h, cert.substeps, name="mpsc_plan"), nx, N, stages,
                       terminal, z_lo, z_hi, "hpipm", compiled, stage_rows=G, stage_bound=bG,
                       stage_gradient=gradient, nz=nz,
                       first_map=model.rk4_map(cert.sample_s, 1, name="mpsc_first"),
                       terminal_constraint=inner_box, qp_options=QP_OPTIONS,
                       acceptance=QP_ACCEPTANCE)


def qp_rows(cert: Certificate) -> tuple[np.ndarray, np.ndarray, int]:
    """``(G, b, ns)``: the soft rows and the hard two-sided bounds as rows ``G z_k <= b``
    over a stage ``z_k = [s, u, slacks]``, one slack per row group."""
    nx = cert.model.size
    C, D, b, sel = cert.rows
    hard = [i for i in range(nx) if math.isfinite(cert.lo[i]) and math.isfinite(cert.hi[i])]
    if hard:
        eye = np.eye(nx)[hard]
        C = np.vstack([C, eye, -eye])
        D = np.concatenate([D, np.zeros(2 * len(hard))])
        b = np.concatenate([b, cert.hi[hard], -cert.lo[hard]])
        extra = np.vstack([np.eye(len(hard))] * 2)
        sel = np.block([[sel, np.zeros((sel.shape[0], len(hard)))],
                        [np.zeros((2 * len(hard), sel.shape[1])), extra]])
    ns = sel.shape[1]
    return np.hstack([C, D[:, None], -sel]), b, ns


@dataclass(frozen=True)
class Solvers:
    """What :func:`build_solvers` compiled for a :class:`Certificate`."""

    rollout: Rollout
    qp: Any
    recovery: "Recovery"
    admission: "RobustAdmission | None" = None


def build_solvers(cert: Certificate, cfg: "SafetyConfig", compiled: bool = True) -> Solvers:
    """The rollout (one C function per model, in one source) and the QP, compiled (cached
    by their C source's hash: :func:`~.mpc_rti.compiled_casadi`), and (P8)'s NLP."""
    import casadi

    from tspend.controllers.mpc_rti import compiled_casadi

    from importlib import resources

    fns = certificate_rollout(cert)
    check = (resources.files("tspend.controllers") / "mpsc_check.c").read_bytes()

    def load(library: Any) -> Rollout:
        return Rollout([casadi.external(fn.name(), str(library)) for fn in fns], cert, library)

    rollout = compiled_casadi(fns, "tspend_mpsc_rollout", load, check) if compiled else None
    return Solvers(rollout or Rollout(fns, cert),
                   plan_qp(cert, cfg, compiled), Recovery(cert), RobustAdmission(cert))


def first_feasible_stop(nz: int, ng: int, n_p: int, lbg: np.ndarray, ubg: np.ndarray) -> Any:
    """IPOPT's iteration callback that stops it at the first iterate keeping every
    constraint ``lbg <= g <= ubg`` (a feasibility problem needs no more)."""
    import casadi as ca

    sizes = {"x": nz, "lam_x": nz, "g": ng, "lam_g": ng, "f": 1, "lam_p": n_p}

    class FirstFeasible(ca.Callback):
        def __init__(self) -> None:
            ca.Callback.__init__(self)
            self.construct("mpsc_first_feasible", {})

        def get_n_in(self) -> int:
            return ca.nlpsol_n_out()

        def get_n_out(self) -> int:
            return 1

        def get_name_in(self, i: int) -> str:
            return ca.nlpsol_out(i)

        def get_name_out(self, i: int) -> str:
            return "stop"

        def get_sparsity_in(self, i: int) -> Any:
            return ca.Sparsity.dense(sizes[ca.nlpsol_out(i)], 1)

        def eval(self, arg: list) -> list:
            g = np.asarray(arg[2], dtype=float).ravel()
            return [1.0 if np.all((g >= lbg) & (g <= ubg)) else 0.0]

    return FirstFeasible()


class Recovery:
    """(P8), the recovery plan from a start with no certified plan, on the nominal model
    (multiple shooting, intervals of the plan's / RECOVERY_REFINE; IPOPT, built on first
    use: most runs never need it)

        min t + effort,  lo_i - t w_i <= s_k,i <= hi_i + t w_i,  s_M in X_f (0.95 c)     (P8)

    (``w_i`` the half-width of constraint ``i``: t < 0 keeps -t of every half-width to
    spare, so the plan least uses the rail and the fall angle).  Uncertified: the same
    over every corner model took minutes per plan."""

    def __init__(self, cert: Certificate) -> None:
        self.cert = cert
        self.h = cert.h / RECOVERY_REFINE
        self.M = 1 + int(round((cert.N - 1) * cert.h / self.h))
        finite = [abs(v) for v in (cert.u_lo, cert.u_hi) if math.isfinite(v)]
        self.u_scale = max(finite) if finite else 1.0
        self.checked = np.flatnonzero(np.isfinite(cert.lo_check) | np.isfinite(cert.hi_check))
        half = 0.5 * (cert.limits[1] - cert.limits[0])
        unit = np.where(np.isfinite(half), half, np.maximum(np.abs(cert.lo), np.abs(cert.hi)))
        unit = unit[self.checked]
        #: the relaxation's unit per checked bound: the constraint's own half-width
        self.room = np.where(np.isfinite(unit) & (unit > 0), unit, 1.0)
        self.maps = (cert.model.rk4_map(cert.sample_s, 1), cert.model.rk4_map(self.h, 1))
        self._nlp: tuple | None = None

    def nlp(self) -> tuple:
        """(P8) as a CasADi nlpsol and its bounds (built once)."""
        import casadi as ca

        if self._nlp is not None:
            return self._nlp
        cert, nx, M, scale = self.cert, self.cert.model.size, self.M, self.u_scale
        X, V = ca.SX.sym("X", nx, M + 1), ca.SX.sym("V", M)
        t, s0 = ca.SX.sym("t"), ca.SX.sym("s0", nx)
        F0, F = self.maps
        g, lbg, ubg = [X[:, 0] - s0], [0.0] * nx, [0.0] * nx
        for k in range(M):
            g.append(X[:, k + 1] - (F0 if k == 0 else F)(X[:, k], scale * V[k]))
            lbg += [0.0] * nx
            ubg += [0.0] * nx
        # every hard bound relaxed by t of its constraint's half-width
        for a, i in enumerate(self.checked):
            for sign, bound in ((1.0, cert.hi[i]), (-1.0, -cert.lo[i])):
                if math.isfinite(bound):
                    g.append(sign * X[i, 1:].T - t * self.room[a])
                    lbg += [-np.inf] * M
                    ubg += [float(bound)] * M
        g.append(ca.bilin(ca.DM(cert.P), X[:, M], X[:, M]))
        lbg.append(-np.inf)
        ubg.append(TERMINAL_AIM * cert.level)
        solver = ca.nlpsol("mpsc_recovery", "ipopt",
                           {"x": ca.vertcat(ca.vec(X), V, t), "p": s0,
                            "f": t + RECOVERY_EFFORT * ca.sumsqr(V) / M, "g": ca.vertcat(*g)},
                           {"print_time": False, "ipopt": {
                               "print_level": 0, "sb": "yes", "max_iter": RECOVERY_MAX_ITER}})
        lo_u = cert.u_lo / scale if math.isfinite(cert.u_lo) else -np.inf
        hi_u = cert.u_hi / scale if math.isfinite(cert.u_hi) else np.inf
        # t down to -1: below 0 the plan keeps that share of every half-width to spare
        lbx = np.concatenate([np.full(nx * (M + 1), -np.inf), np.full(M, lo_u), [-1.0]])
        ubx = np.concatenate([np.full(nx * (M + 1), np.inf), np.full(M, hi_u), [np.inf]])
        self._nlp = (solver, lbx, ubx, np.array(lbg, dtype=float), np.array(ubg, dtype=float))
        return self._nlp

    def plan(self, s: np.ndarray) -> tuple | None:
        """(P8) from ``s``: ``(U (M,), X (nx, M+1), t)``, or None when IPOPT fails; warm
        started from the saturated LQR's rollout on the model."""
        solver, lbx, ubx, lbg, ubg = self.nlp()
        cert, nx, M = self.cert, self.cert.model.size, self.M
        X, V = np.zeros((nx, M + 1)), np.zeros(M)
        X[:, 0] = s
        for k in range(M):
            V[k] = lqr_input(cert, X[:, k]) / self.u_scale
            X[:, k + 1] = np.asarray(self.maps[k > 0](X[:, k], self.u_scale * V[k])).ravel()
        if not np.all(np.isfinite(X)):
            X[:] = s[:, None]
        sol = solver(x0=np.concatenate([X.ravel(order="F"), V, [1.0]]), p=s, lbx=lbx,
                     ubx=ubx, lbg=lbg, ubg=ubg)
        if not solver.stats()["success"]:
            return None
        z = np.asarray(sol["x"], dtype=float).ravel()
        X = z[:nx * (M + 1)].reshape(nx, M + 1, order="F")
        return self.u_scale * z[nx * (M + 1):nx * (M + 1) + M], X, float(z[-1])

    def input(self, plan: tuple, s: np.ndarray, tau: float) -> float | None:
        """``plan``'s input ``tau`` seconds into it, corrected by the LQR towards its state
        there (interpolated between its nodes); None past its end."""
        U, X, _ = plan
        dt0 = self.cert.sample_s
        if tau < dt0 - 1e-12:
            return float(U[0])
        k = 1 + int(math.floor((tau - dt0) / self.h + 1e-9))
        if k >= self.M:
            return None
        a = min(max((tau - (dt0 + (k - 1) * self.h)) / self.h, 0.0), 1.0)
        ref = (1.0 - a) * X[:, k] + a * X[:, k + 1]
        return clip_input(self.cert, float(U[k] - self.cert.K @ (s - ref)))


class RobustAdmission:
    """(P11), a plan certified by construction from a start no tail and no QP plan covers:

        min eps |W (z - z_w)|^2   over the plan z = (U, R) of (P5),
        s.t. (P5) on every model (P6) keeps each checked bound, less a share of its
             half-width, at every RK4 step and ends in (P3) (a share of its level)     (P11)

    (``z_w`` the warm start, the recovery plan (P8) put on the plan's grid; ``W`` the
    input's range and the bounds' half-widths): its constraints are the certificate's own
    rollouts (:func:`model_paths`), so what IPOPT finds is what the certificate checks
    (again, before it is used).  IPOPT stops at the first iterate keeping them.  Built on
    first use: most starts never need it."""

    def __init__(self, cert: Certificate) -> None:
        self.cert = cert
        self._nlp: tuple | None = None

    def nlp(self) -> tuple:
        """(P11) as a CasADi nlpsol (single shooting over the plan) and its bounds."""
        import casadi as ca

        if self._nlp is not None:
            return self._nlp
        cert, nx, N = self.cert, self.cert.model.size, self.cert.N
        s0, Un, Rn = ca.MX.sym("s0", nx), ca.MX.sym("U", N), ca.MX.sym("R", nx, N - 1)
        checked = np.flatnonzero(np.isfinite(cert.lo_check) | np.isfinite(cert.hi_check))
        half = 0.5 * (cert.hi_check - cert.lo_check)
        spare = np.where(np.isfinite(half), ADMISSION_SPARE * half, 0.0)
        g, lbg, ubg = [], [], []
        for path, _ in model_paths(cert, s0, Un, ca.horzcat(s0, Rn)):
            for i in checked:
                g.append(path[int(i), :].T)
                lbg.append(np.full(path.shape[1], cert.lo_check[i] + spare[i]))
                ubg.append(np.full(path.shape[1], cert.hi_check[i] - spare[i]))
            g.append(ca.bilin(ca.DM(cert.P), path[:, -1], path[:, -1]))
            lbg.append([-np.inf])
            ubg.append([ADMISSION_AIM * cert.level])
        z, warm = ca.vertcat(Un, ca.vec(Rn)), ca.MX.sym("warm", N + nx * (N - 1))
        scale = max([abs(v) for v in (cert.u_lo, cert.u_hi) if math.isfinite(v)], default=1.0)
        width = np.where(np.isfinite(half) & (half > 0.0), half, 1.0)
        W = ca.DM(np.concatenate([np.full(N, 1.0 / scale), np.tile(1.0 / width, N - 1)]))
        lbg, ubg = np.concatenate(lbg), np.concatenate(ubg)
        stop = first_feasible_stop(z.shape[0], lbg.size, nx + z.shape[0], lbg, ubg)
        solver = ca.nlpsol("mpsc_admission", "ipopt", {
            "x": z, "p": ca.vertcat(s0, warm), "g": ca.vertcat(*g),
            "f": ADMISSION_PROXIMAL * ca.sumsqr((z - warm) * W) / N},
            {"print_time": False, "iteration_callback": stop, "ipopt": {
                "print_level": 0, "sb": "yes", "max_iter": ADMISSION_MAX_ITER,
                "hessian_approximation": "limited-memory"}})
        self._nlp = (solver, lbg, ubg, stop)
        return self._nlp

    def plan(self, s: np.ndarray, warm: tuple) -> tuple:
        """(P11) from ``s``, warm started from ``warm = (U (N,), R (nx, N))``: the plan
        ``(U, R)`` IPOPT ended on (the caller certifies it)."""
        solver, lbg, ubg, _ = self.nlp()
        cert, N = self.cert, self.cert.N
        z0 = np.concatenate([warm[0], np.asarray(warm[1])[:, 1:].ravel(order="F")])
        lbx = np.concatenate([np.full(N, cert.u_lo), np.full(z0.size - N, -np.inf)])
        ubx = np.concatenate([np.full(N, cert.u_hi), np.full(z0.size - N, np.inf)])
        sol = solver(x0=np.clip(z0, lbx, ubx), p=np.concatenate([s, z0]), lbx=lbx, ubx=ubx,
                     lbg=lbg, ubg=ubg)
        z = np.asarray(sol["x"], dtype=float).ravel()
        R = np.hstack([s[:, None], z[N:].reshape(-1, N - 1, order="F")])
        return z[:N], R

    def warm_start(self, recovery: tuple) -> tuple:
        """The recovery plan (P8) ``(U, X, t)`` on the certificate's grid: its first input,
        then per interval the mean of its inputs there and its state at the start (its
        intervals divide the plan's, :data:`RECOVERY_REFINE`)."""
        U, X, _ = recovery
        N, refine = self.cert.N, RECOVERY_REFINE
        starts = 1 + refine * np.arange(N - 1)
        U2 = np.concatenate([[U[0]], U[1:1 + refine * (N - 1)].reshape(N - 1, refine).mean(1)])
        return U2, np.hstack([X[:, :1], X[:, starts]])


def clip_input(cert: Certificate, u: float) -> float:
    return min(max(u, cert.u_lo), cert.u_hi)


def lqr_input(cert: Certificate, s: np.ndarray) -> float:
    """The saturated LQR: the terminal set's law."""
    return clip_input(cert, float(-cert.K @ s))


class PredictiveSafetyFilter(SafetyFilter):
    """``inner`` behind the predictive safety certification (module docstring): the
    per-sample law over a :class:`Certificate` and its :class:`Solvers`."""

    FILTER = "mpsc"
    checks_start = True

    def __init__(self, inner: Controller, cert: Certificate, solvers: Solvers,
                 cfg: "SafetyConfig") -> None:
        super().__init__(inner, cert.model, cfg)
        self.cert, self.roll = cert, solvers.rollout
        self.sqp, self.recovery, self.robust = solvers.qp, solvers.recovery, solvers.admission
        self.u_lo, self.u_hi = cert.u_lo, cert.u_hi
        self._checked = np.flatnonzero(np.isfinite(cert.lo_check) | np.isfinite(cert.hi_check))
        #: the certificate's bounds on every state (+/-inf: none), for one comparison each
        self._lo, self._hi = cert.lo_check, cert.hi_check
        #: (shifted's grid per plan age: the old intervals the new ones start in)
        self._shift_grid: dict[int, tuple] = {}
        self._angles = np.flatnonzero(cert.model.angles)
        #: (P9): each step's time estimate (the QP's and (P8)'s measured at admission), and
        #: the reserve for the work after a sample's last step
        self._cost = {"roll": StepCost(probe=True), "qp": StepCost(), "recovery": StepCost(),
                      # a check's work after its models when every model passed (the full
                      # check of the summary, the plan kept): its last model leaves room
                      "verdict": StepCost(rank=FIXED_COST_RANK)}
        # none measured yet (a start not admitted has no whole check before its first
        # sample): none, until the first
        self._cost["verdict"].measured(0.0)
        self._reserve = StepCost(rank=FIXED_COST_RANK)
        #: a model's rollout's CPU time in the last check that ran every model (s)
        self._model_s = math.inf
        self._deadline = math.inf
        #: (P9): the deadline's clock (wall, s) and the steps' (this thread's time on the
        #: CPU, s); when the running step started, and the sample's last step ended (CPU)
        self._clock, self._cpu_clock = time.perf_counter, time.thread_time
        self._started = self._step_end = 0.0
        #: the collector's runs when the sample (or admission) started
        self._collections = -1
        self._stepped = False
        self.reset_plan()

    # -- state ----------------------------------------------------------------------------
    def reset_plan(self) -> None:
        #: the last certified plan (U (N,), R (nx, N)) of (P5), and the samples since
        self.plan: tuple | None = None
        self.plan_age = 0
        #: the QP's last answer (its next warm start), certified or not
        self.iterate_plan: tuple | None = None
        #: the recovery plan (P8) tracked without a certified plan, and its age
        self.rescue: tuple | None = None
        self.rescue_age = 0
        self.fast = self.bisected = self.qp_certified = self.fallbacks = 0
        self.uncertified = self.rejected = self.infeasible_qp = self.recoveries = 0
        #: samples where a step was skipped for the budget, and samples over it
        self.skipped = 0
        #: rollouts stopped between two models at the budget's end (their verdict unknown)
        self.cut_short = 0
        self.over_budget_by_cause = dict.fromkeys(OVER_BUDGET_CAUSES, 0)
        self._skipped_now = self._probed_now = False
        self.rescue_relaxation = -math.inf
        self.max_slack = 0.0
        #: admission (before the first sample): None until made, then whether a plan was
        #: certified from the start, why not, and its time
        self.admitted: bool | None = None
        self.refusal = ""
        #: whether the start was admitted by the robust plan (P11)
        self.robust_admitted = False
        self.admission_ms = 0.0
        #: whether the last call (before_start, or a step) made the admission
        self._call_admits = False

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        self.reset_plan()

    def _prepare(self, obs: Observation) -> None:
        perm = np.array([obs.names.index(n) for n in self.model.state_names], dtype=np.intp)
        self._rows = (perm,)

    def before_start(self, obs: Observation) -> str | None:
        """Admission from ``obs`` (:meth:`admit`); with ``safety.refuse_unadmitted`` the
        refusal of a start no certified plan leaves (a rig then never starts it)."""
        if self._rows is None:
            self._prepare(obs)
        self._call_admits = True
        self.admit(np.asarray(obs.state, dtype=float)[self._rows[0]])
        if not self.admitted and self.cfg.refuse_unadmitted:
            return f"safety.refuse_unadmitted: {self.refusal}"
        return None

    def step(self, obs: Observation, dt: float) -> float:
        self._call_admits = False
        if self.admitted is None:
            self.before_start(obs)
        if not self.samples and not self.admitted and self.cfg.refuse_unadmitted:
            # before the first input: a start no certified plan leaves is not started
            raise RunRefused(f"safety.refuse_unadmitted: {self.refusal}")
        return super().step(obs, dt)

    def interrupted(self) -> None:
        """A signal cut the last call short: an admission made in it claims no verdict
        (CasADi turns a signal in IPOPT into a failed solve, read as "no plan"), nor is
        the first sample filtered after it in the same call counted."""
        super().interrupted()
        if self._call_admits:
            self.reset_counts()
            self.reset_plan()

    # -- the certificate ------------------------------------------------------------------
    def _affords(self, what: str) -> bool:
        """(P9): whether ``what``, by its estimate, ends before the deadline if started now
        (else it is skipped)."""
        cost = self._cost[what]
        if self._clock() + cost.estimate <= self._deadline:
            self._started = self._cpu_clock()
            self._probed_now |= cost.probe and cost.estimate == 0.0
            return True
        self._skipped_now = True
        if not self._stepped:
            # no step yet this sample: the reserve counts from here
            self._step_end = self._cpu_clock()
        return False

    def _measured(self, what: str, unrun_s: float = 0.0, spared_s: float = 0.0) -> None:
        """The step started by :meth:`_affords` ended now: its time on the CPU, with
        ``unrun_s`` for the part of it not run (a check stopped early) and without
        ``spared_s`` that a sample's step does not run (admission's SQP steps but the
        slowest)."""
        end = self._cpu_clock()
        self._cost[what].measured(end - self._started - spared_s + unrun_s)
        self._step_end, self._stepped = end, True

    def certifies(self, s: np.ndarray, U: np.ndarray, R: np.ndarray) -> bool | None:
        """Whether the plan ``(U, R)`` from ``s``, rolled out by (P5) on every model (P6),
        keeps the certificate's bounds at every RK4 step and ends in (P3); if so it
        becomes the certified plan.  None: not tried, the budget has no room for it."""
        if not self._affords("roll"):
            return None
        cost = self._cost["roll"]
        # the guard before each model: a share of a whole rollout's estimate (a probe's:
        # its last time), with room for a model slower than its share
        per_model = MODEL_GUARD * max(cost.estimate, cost.last) / self.roll.models
        verdict = self._cost["verdict"]
        V, run, models_s = self.roll.check(s, U, R, self._deadline - verdict.estimate,
                                           per_model)
        checked = self._cpu_clock()
        # every model run and none broke a bound by its excess: the full check decides
        whole = isinstance(V, np.ndarray)
        ok = whole and self.verdict(V) is None
        if ok:
            R = np.array(R, dtype=float)
            R[:, 0] = s
            self.plan, self.plan_age, self.rescue = (np.array(U, dtype=float), R), 1, None
        # a whole rollout's time, from the models run and the models not run at the last
        # whole check's time per model, so every check measures it (at the partial check's
        # own pace, a check cut short, the slowest ones, priced the rest at up to twice a
        # whole check's: 37-45 us a model against 22, and blocked every rollout)
        if run == self.roll.models:
            self._model_s = models_s / run
        per_model_s = self._model_s if math.isfinite(self._model_s) else models_s / max(run, 1)
        self._measured("roll", unrun_s=(self.roll.models - run) * per_model_s)
        if whole and collections_run() == self._collections:
            verdict.measured(self._step_end - checked)
        if V is None:
            self.cut_short += 1
            self._skipped_now = True
            return None
        return ok

    def verdict(self, V: np.ndarray) -> str | None:
        """None when the rollout's summary ``V`` (per model: least, largest, last state)
        keeps every bound and ends in (P3) on every model, else what it breaks first and
        on which model."""
        cert, nx = self.cert, self.roll.nx
        below, above = V[:, :nx] < self._lo, V[:, nx:2 * nx] > self._hi
        if not (below.any() or above.any()):
            end = V[:, 2 * nx:]
            levels = ((end @ cert.P) * end).sum(axis=1)
            # a non-finite state anywhere reaches the end (RK4 carries it)
            return None if (levels <= cert.level).all() else \
                f"ends outside the terminal set on {self.model_name(int(np.argmax(levels)))}"
        m, i = np.argwhere(below | above)[0]
        return (f"leaves {cert.model.state_names[i]}'s certified bound "
                f"[{cert.lo_check[i]:.4g}, {cert.hi_check[i]:.4g}] on {self.model_name(m)}")

    def model_name(self, m: int) -> str:
        if m == 0:
            return "the nominal model"
        cert = self.cert
        return f"corner {m} of {len(cert.corners)} ({', '.join(cert.corner_names)})"

    def stage_at(self, tau: float) -> int:
        """The plan's interval ``tau`` seconds after it was made; ``N`` past its end: the
        plan ended in X_f, where the LQR goes on (X_f invariant under it, (P10))."""
        dt0 = self.cert.sample_s
        if tau < dt0 - 1e-12:
            return 0
        k = 1 + int(math.floor((tau - dt0) / self.cert.h + 1e-9))
        return min(k, self.cert.N)

    def shifted(self, plan: tuple | None, age: int, s: np.ndarray) -> tuple | None:
        """``plan = (U, R)`` made ``age`` samples ago, on this sample's grid from state
        ``s``: each new interval takes the input of the old interval it starts in and the
        old reference state at its start, interpolated between the old nodes as the
        fallback does (past the plan's end: the LQR, U = 0 and R = 0)."""
        if plan is None:
            return None
        U, R = plan
        live, kl, a, nxt = self.shift_grid(age)
        U2, R2 = np.zeros(self.cert.N), np.zeros((self.roll.nx, self.cert.N))
        U2[live] = U[kl]
        R2[:, live] = (1.0 - a) * R[:, kl] + a * R[:, nxt]
        R2[:, 0] = s
        return U2, R2

    def shift_grid(self, age: int) -> tuple:
        """For :meth:`shifted`: which new nodes lie within the old plan, the old interval
        each starts in, its share of that interval, and the next old node (per age)."""
        grid = self._shift_grid.get(age)
        if grid is None:
            N, h, dt0 = self.cert.N, self.cert.h, self.cert.sample_s
            t = age * dt0 + np.concatenate([[0.0], dt0 + h * np.arange(N - 1)])
            k = np.where(t < dt0 - 1e-12, 0, 1 + np.floor((t - dt0) / h + 1e-9).astype(np.intp))
            live = k < N
            kl = k[live]
            a = np.where(kl == 0, 0.0, np.clip((t[live] - (dt0 + (kl - 1) * h)) / h, 0.0, 1.0))
            grid = (live, kl, a, np.minimum(kl + 1, N - 1))
            if len(self._shift_grid) < 100000:
                self._shift_grid[age] = grid
        return grid

    def lqr_tail(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The saturated LQR as a backup plan from ``s`` (U = 0, R = 0 in (P5))."""
        R = np.zeros((self.roll.nx, self.cert.N))
        R[:, 0] = s
        return np.zeros(self.cert.N), R

    def tracking_input(self, s: np.ndarray, k: int, tau: float, plan: tuple | None = None) -> float:
        """The certified plan's (or ``plan``'s) input in interval ``k`` at ``tau`` seconds
        into the plan, corrected by the LQR towards its state there (interpolated between
        the nodes)."""
        U, R = self.plan if plan is None else plan
        cert = self.cert
        if k == 0:
            return float(U[0])
        if k >= cert.N:
            return self.terminal_input(s)
        start = cert.sample_s + (k - 1) * cert.h
        a = min(max((tau - start) / cert.h, 0.0), 1.0)
        ref = R[:, k] if k + 1 >= cert.N else (1.0 - a) * R[:, k] + a * R[:, k + 1]
        return clip_input(cert, float(U[k] - cert.K @ (s - ref)))

    def terminal_input(self, s: np.ndarray) -> float:
        return lqr_input(self.cert, s)

    # -- per sample (module docstring, steps 1-4) -------------------------------------------
    def filter(self, s: np.ndarray, u_c: float) -> tuple[float, float]:
        """``(u, slack)``: steps 1-4 at full state ``s`` within the budget (P9): step 3's
        answer first, then each step only if it fits before the deadline less the reserve."""
        clock = self._clock
        t0, self._step_end = clock(), self._cpu_clock()
        # a sample with a collection in it measures no fixed work (FIXED_COST_RANK)
        self._collections = collections_run()
        if self.admitted is not None:
            # the reserve unmeasured (the first sample): no step, step 3 answers
            reserve = self._reserve.estimate
            self._deadline = t0 + (self.cert.budget_s - reserve if math.isfinite(reserve) else 0.0)
        for cost in (*self._cost.values(), self._reserve):
            cost.new_sample()
        self._skipped_now = self._stepped = self._probed_now = False
        cpu0 = self._step_end
        s = np.array(s, dtype=float)
        s[self._angles] = (s[self._angles] + math.pi) % (2.0 * math.pi) - math.pi
        u_c = clip_input(self.cert, u_c) if math.isfinite(u_c) else math.nan
        k = ready = going_on = None
        if self.plan is not None:
            # step 3's answer, ready before any step starts
            tau = self.plan_age * self.cert.sample_s
            k = self.stage_at(tau)
            ready = self.tracking_input(s, k, tau)
            # the plan's rest on this sample's grid, built only when a rollout fits
            if self._affords("roll"):
                going_on = self.shifted(self.plan, self.plan_age, s)
        answer = self.on_tails(s, u_c, going_on, ready)
        if answer is None and k is None:
            answer = self.rescue_input(s)
        qp_plan = None
        if answer is None:
            answer, qp_plan = self.solve_qp(s, u_c, going_on)
        if answer is None:
            answer = self.fallback(s, qp_plan, ready)
        self.skipped += self._skipped_now
        if self.admitted is not None and collections_run() == self._collections:
            # the work after the last step (after none: after the last one refused)
            self._reserve.measured(self._cpu_clock() - self._step_end)
        if clock() - t0 > self.cert.budget_s:
            self.over_budget_by_cause[self._over_budget_cause(self._cpu_clock() - cpu0)] += 1
        return answer

    @property
    def over_budget(self) -> int:
        """Samples whose filter took longer than the budget (wall clock), every cause."""
        return sum(self.over_budget_by_cause.values())

    def _over_budget_cause(self, cpu_s: float) -> str:
        """Why a sample ran past the budget: its CPU time within it (the thread waited for
        a core), else a rollout started on a probe's zero estimate, else a step that took
        longer than its estimate."""
        if cpu_s <= self.cert.budget_s:
            return "waited_for_a_core"
        return "probe" if self._probed_now else "step_over_its_estimate"

    def on_tails(self, s: np.ndarray, u_c: float, going_on: tuple | None,
                 ready: float | None) -> tuple | None:
        """1 on each certified tail in turn (the last plan's rest, tracked: its input now
        ``ready``; the saturated LQR): ``[u_c, tail]`` (the fast path: ``u_c``
        passes unchanged), else the tail's own input now, then the closest to ``u_c``
        between them by bisection, halving while the budget allows."""

        def tails():
            if going_on is not None and ready is not None:
                yield going_on, ready
            if self._affords("roll"):  # the LQR's tail built only when its rollout fits
                yield self.lqr_tail(s), self.terminal_input(s)

        for tail, own in tails():
            candidate = tail[0].copy()
            if math.isfinite(u_c):
                candidate[0] = u_c
                if self.certifies(s, candidate, tail[1]):
                    self.fast += 1
                    self.iterate_plan = None
                    return u_c, 0.0
            candidate[0] = own
            if not self.certifies(s, candidate, tail[1]):
                continue
            good, bad = own, u_c if math.isfinite(u_c) else None
            for _ in range(BISECTIONS if bad is not None else 0):
                candidate[0] = 0.5 * (good + bad)
                ok = self.certifies(s, candidate, tail[1])
                if ok is None:
                    break
                good, bad = (candidate[0], bad) if ok else (good, candidate[0])
            self.bisected += 1
            self.iterate_plan = None
            return good, 0.0
        return None

    def solve_qp(self, s: np.ndarray, u_c: float,
                 going_on: tuple | None) -> tuple[tuple | None, tuple | None]:
        """2: SQP steps of (P4) (one per sample; to convergence at admission), warm from
        the QP's last answer, else the certified plan, else the LQR's rollout; its plan
        (after ``u_c``, else its own) applied when certified.  ``(answer, the QP's plan)``."""
        if not self._affords("qp"):
            return None, None
        warm = self.shifted(self.iterate_plan, 1, s) or going_on
        S0, U0 = self.roll.nominal(s, *(warm or self.lqr_tail(s)))
        if warm is None:
            U0[0] = self.terminal_input(s)
            S0, U0 = self.roll.nominal(s, U0, self.lqr_tail(s)[1])
        cert, nx, N = self.cert, self.roll.nx, self.cert.N
        nz = self.sqp.nz
        z = np.zeros(N * nz + nx)
        body = z[:N * nz].reshape(N, nz)
        body[:, :nx], body[:, nx] = S0[:, :N].T, U0
        z[N * nz:] = S0[:, N]
        zr = np.zeros_like(z)
        # (P4)'s reference: the command for u_0, else the plan's own
        zr[nx] = u_c if math.isfinite(u_c) and going_on is not None else U0[0]
        plan, slack, spared_s = None, 0.0, 0.0
        steps = ADMISSION_ITERATIONS if self.admitted is None else 1
        try:
            if not np.all(np.isfinite(z)):
                raise RuntimeError("non-finite warm start")
            z, spared_s = self.sqp_steps(z, s, zr, steps)
            body = z[:N * nz].reshape(N, nz)
            plan = (np.clip(body[:, nx], cert.u_lo, cert.u_hi), body[:, :nx].T.copy())
            slack = float(body[:, nx + 1:].max(initial=0.0))
        except RuntimeError:
            self.infeasible_qp += 1
            self.sqp.reset()
        self._measured("qp", spared_s=spared_s)
        self.iterate_plan = plan
        return self.certified_qp(s, u_c, plan, slack), plan

    def sqp_steps(self, z: np.ndarray, s: np.ndarray, zr: np.ndarray,
                  steps: int) -> tuple[np.ndarray, float]:
        """``(z, spared_s)`` after up to ``steps`` SQP steps of (P4) from ``z`` (fewer once
        one moves ``z`` by less than :data:`SQP_TOLERANCE`), timed one by one: ``spared_s``
        the CPU time of all but the slowest.  A sample runs one step, and admission's
        first, cold one costs several times its later ones: their average priced a sample's
        step at 0.46-0.57 ms that then took 3.5 ms (the cart-pole's max)."""
        times: list[float] = []
        z, _ = self.sqp.iterate(z, s, zr, steps, SQP_TOLERANCE, self._cpu_clock, times)
        return z, sum(times) - max(times)

    def certified_qp(self, s: np.ndarray, u_c: float, plan: tuple | None,
                     slack: float) -> tuple | None:
        """``[u_c, the QP's rest]``, else the QP's own plan, when certified."""
        if plan is None:
            return None
        if math.isfinite(u_c):
            candidate = plan[0].copy()
            candidate[0] = u_c
            if self.certifies(s, candidate, plan[1]):
                self.qp_certified += 1
                return u_c, slack
        if self.certifies(s, *plan):
            self.qp_certified += 1
            self.max_slack = max(self.max_slack, slack)
            return float(plan[0][0]), slack
        self.rejected += 1
        return None

    def fallback(self, s: np.ndarray, qp_plan: tuple | None, ready: float | None) -> tuple:
        """3: the last certified plan goes on, tracked by the LQR (its input now ``ready``,
        computed before any step); 4 without one (``ready`` None): uncertified (counted),
        the QP's own plan, else the saturated LQR."""
        self.plan_age += 1
        if ready is not None:
            self.fallbacks += 1
            return ready, 0.0
        self.uncertified += 1
        if qp_plan is not None:
            return float(qp_plan[0][0]), 0.0
        return self.terminal_input(s), 0.0

    def rescue_input(self, s: np.ndarray) -> tuple | None:
        """4 without a certified plan: the recovery plan (P8) tracked, made from this
        state when none is (at admission, or when the budget has room for IPOPT)."""
        dt0 = self.cert.sample_s
        u = self.recovery.input(self.rescue, s, self.rescue_age * dt0) if self.rescue else None
        if u is None and self._affords("recovery"):
            found = self.recovery.plan(s)
            self._measured("recovery")
            if found is not None:
                self.rescue, self.rescue_age = found, 0
                self.recoveries += 1
                self.rescue_relaxation = max(self.rescue_relaxation, found[2])
                u = self.recovery.input(found, s, 0.0)
        if u is None:
            self.rescue = None
            return None
        self.rescue_age += 1
        self.uncertified += 1
        self.iterate_plan = None
        return u, 0.0

    # -- admission and metrics --------------------------------------------------------------
    def admit(self, s: np.ndarray) -> None:
        """Before the first sample, with no budget (a rig's pre-flight check at its start):
        a certified plan from ``s`` by steps 1-2 (the QP iterated), else the recovery plan
        (P8); the QP's and (P8)'s costs measured for the budget (P9)."""
        t0 = time.perf_counter()
        self._deadline = math.inf
        self._collections = collections_run()
        s = np.array(s, dtype=float)
        s[self._angles] = (s[self._angles] + math.pi) % (2.0 * math.pi) - math.pi
        lqr = self.lqr_tail(s)
        found = self.on_tails(s, math.nan, None, None)
        if found is None:
            found, _ = self.solve_qp(s, math.nan, None)
        else:
            # the QP's cost, measured once for the budget, its plan not used
            self.solve_qp(s, math.nan, None)
        if self.plan is None:
            self.rescue_input(s)
            self.rescue_age = 0
            robust = self.robust_plan(s)
        self.admitted = self.plan is not None
        if not self.admitted:
            lqr[0][0] = self.terminal_input(s)
            why = self.verdict(self.roll.run(s, *lqr))
            self.refusal = (f"no plan certified from the start on the {self.roll.models} "
                            f"models: the saturated LQR {why}, the QP's plan too, and the "
                            f"robust plan (P11) {robust}")
        self.plan_age = 0
        self.bisected = self.qp_certified = self.rejected = self.uncertified = 0
        self.admission_ms = 1e3 * (time.perf_counter() - t0)

    def robust_plan(self, s: np.ndarray) -> str:
        """(P11) at admission, warm from the recovery plan (P8) made there (else the LQR's
        tail): certified, it is the plan the filter starts on (and the recovery plan is
        dropped); else what it breaks first and on which model."""
        if self.robust is None:
            return "was not tried"
        warm = self.robust.warm_start(self.rescue) if self.rescue else self.lqr_tail(s)
        try:
            U, R = self.robust.plan(s, warm)
        except RuntimeError as exc:  # IPOPT's own failure (a non-finite rollout)
            return f"failed ({exc})"
        if self.certifies(s, U, R):
            self.robust_admitted = True
            return "is certified"
        # the rollout again, for the reason only (a plan that fails is rolled out twice)
        return self.verdict(self.roll.run(s, U, R)) or "was not certified"

    def more_metrics(self) -> dict[str, Any]:
        n, cert = self.samples, self.cert
        certified = self.fast + self.bisected + self.qp_certified
        names = cert.model.state_names
        return {"solver": "hpipm", "horizon_s": cert.sample_s + (cert.N - 1) * cert.h,
                "budget_ms": 1e3 * cert.budget_s,
                "time_per_sample_ms": {"median": self.time_quantile_ms(0.5),
                                       "p99": self.time_quantile_ms(0.99),
                                       "max": 1e3 * self.time_max if n else None},
                "over_budget_samples": self.over_budget,
                "over_budget_by_cause": dict(self.over_budget_by_cause),
                "budget_skipped_samples": self.skipped,
                "rollouts_cut_short": self.cut_short,
                "certified_samples": certified, "certified_share": certified / n if n else None,
                # steps 1-3: certified at this sample, or the plan certified at an earlier one
                # going on (its rest, then X_f under the LQR: [3]'s recursive feasibility)
                "on_certified_plan_samples": certified + self.fallbacks,
                "on_certified_plan_share": (certified + self.fallbacks) / n if n else None,
                "fast_path_samples": self.fast, "bisected_samples": self.bisected,
                "qp_certified_samples": self.qp_certified, "fallbacks": self.fallbacks,
                "fallback_share": self.fallbacks / n if n else None,
                "uncertified_samples": self.uncertified, "no_plan": self.uncertified,
                "rejected_samples": self.rejected,
                "infeasible_samples": self.infeasible_qp,
                "start_admitted": self.admitted, "start_refusal": self.refusal or None,
                "start_admitted_by_robust_plan": self.robust_admitted,
                "admission_ms": self.admission_ms,
                "certificate": {"models": self.roll.models,
                                # (P5): u held over each control sample, or tracked at
                                # every RK4 stage; the sample and the plan's interval
                                "held": cert.held, "sample_s": cert.sample_s,
                                "plan_period_s": cert.h, "substeps": cert.substeps,
                                "corner_parameters": list(cert.corner_names),
                                "terminal_set": cert.terminal, "terminal_level": cert.level,
                                "terminal_decay_rate": cert.decay_rate,
                                # every margin the certificate keeps, per bounded state
                                "bounds": {names[i]: [float(cert.lo_check[i]),
                                                      float(cert.hi_check[i])]
                                           for i in self._checked},
                                "margin_share": CHECK_MARGIN * self.cfg.margin,
                                "disturbance_tube": {names[i]: float(cert.tube[i])
                                                     for i in range(len(names))
                                                     if cert.tube[i] > 0.0}},
                "max_slack": self.max_slack, "recovery_plans": self.recoveries,
                "recovery_relaxation_max": (self.rescue_relaxation if self.recoveries
                                            else None)}


def wrap(scenario: "Scenario", inner: Controller, machine: Any) -> PredictiveSafetyFilter:
    """``inner`` behind the predictive safety filter on the scenario's nominal ``machine``
    (:func:`tspend.loop.simulation.nominal_machine`): the corner machines built here (the
    caller that builds plants), the design, the compiled solvers, then the filter."""
    from tspend.controllers.full_model import has_full_state
    from tspend.runtime.extras import missing_extra

    if not has_full_state(scenario):
        raise ScenarioError(f"{scenario.path}: safety.filter = \"mpsc\": plant "
                            f"'{scenario.plant.kind}' has no full-state model to plan on; "
                            f"allowed: \"off\"")
    problem = missing_extra("casadi", "safety.filter = \"mpsc\"")
    if problem:
        raise ScenarioError(problem)
    # the period the runner holds u over (tspend.loop.simulation's rule): run.control_period,
    # else the controller's own, else every step
    sample = scenario.run.control_period or inner.sample_period or scenario.run.dt
    cfg = scenario.safety
    if cfg.plan_period and cfg.plan_period < sample:  # the scenario checked run's period only
        raise ScenarioError(f"{scenario.path}: safety.plan_period = {cfg.plan_period:g} s is "
                            f"shorter than the controller's sample ({sample:g} s)")
    corners, names = vertex_models(scenario)
    cert = design(scenario, machine, corners, names, sample)
    return PredictiveSafetyFilter(inner, cert, build_solvers(cert, cfg), cfg)
