"""``mpc``: nonlinear model-predictive control with CasADi (CasADi, a core dependency).

Every control period ``h`` (default 20 ms, :attr:`MPCController.sample_period`; the
runner holds ``u`` in between) it solves, by multiple shooting (Bock and Plitt, 1984;
Rawlings, Mayne and Diehl, *Model Predictive Control*, 2nd ed., 2017, sec. 8.5),

    min  h sum_{k<N} [(s_k - s_r,k)^T Q (s_k - s_r,k) + R (u_k - u_r,k)^2]
         + (s_N - s_r,N)^T P (s_N - s_r,N)
         + sum_{k<N} (rho 1^T e_k + e_k^T e_k)                                    (M1)
    s.t. s_0 = s(t),  s_{k+1} = F(s_k, u_k),  u_lo <= u_k <= u_hi,
         q_lo + margin <= q_k <= q_hi - margin   (the rail, the joints' ranges)
         lo_c <= s_k <= hi_c              (k >= 1: the task's hard boxes on positions) (M2)
         C s_k + D u_k - S e_k <= b,  e_k >= 0   (k < N: every other row of the task) (M3)

``F`` is ``substeps`` RK4 steps over ``h`` of the domain's own ODE, built symbolically
from the one source of its equations: the domain's
:class:`~tspend.plants.domain.FullModel` (:meth:`~tspend.plants.domain.Domain.full_model`),
whose ``accel_factory`` is the domain's equations over CasADi's sin, cos, tanh, so the
model is the simulated machine, not a copy.  The bounds (the actuator's range, the
positions' ranges: a rail, a joint's range, a task's state bound) are the domain's too
(:func:`.full_model.full_model`).  With ``constraints = true`` (the default) the OCP
also keeps the run's constraint set (:mod:`tspend.task.constraints`, the ``ConstraintSet`` the
run measures, ``Observation.constraints``): a hard box on a position is a bound on the
predicted states (M2), like the rail; a box on the input narrows ``u_lo, u_hi``; every
other row (a hard box on a velocity: a measured speed at its bound would leave no
feasible ``s_1``; a soft box on a state; a linear row ``[task.constraints.linear]`` on
state and input) is (M3), one slack ``e >= 0`` per
constraint and stage, penalised by ``slack_weight`` (``rho``) linearly and quadratically:
the linear term makes the penalty exact (the slack is 0 whenever the rows can hold and
``rho`` exceeds their multipliers: Fletcher, *Practical Methods of Optimization*, 1987,
sec. 12.3; Kerrigan and Maciejowski, "Soft constraints and exact penalty functions in
model predictive control", UKACC 2000), the quadratic one keeps the QP strictly convex.
(M3) holds on stages ``k < N`` (``s_N`` is held by the terminal cost; HPIPM's stage
structure gives the last stage no input, so no slack).  Every box keeps ``margin`` (in
its state's unit) from its ends, a linear row none.  The kind declares what it needs of a domain
(``needs``: a full-state model and its symbolic equations); on any other it is refused
before anything is built.  ``P`` is the full-state LQR's
Riccati matrix (the terminal cost of the unconstrained tail), and the reference states
``s_r, u_r`` over the horizon are the LQR's feedforward (:mod:`.lqr`) on the reference
continued by its harmonic model (``r(t + tau) = r cos(omega tau) + r'/omega sin(omega tau)``,
exact for the scenario's sine; ``r`` held when ``omega = 0``).

With ``scheme = "rti"`` (the default) each sample takes one Gauss-Newton SQP step of the
problem from the last plan shifted by one period, over a QP solver (:mod:`.mpc_rti`);
``sqp`` takes up to ``sqp_iterations`` such steps; ``ipopt`` (the reference) solves the NLP
to convergence with IPOPT (its options as settings), warm-started the same way.  Over 11
shipped scenarios the closed-loop cost of ``rti`` is within 1.2e-5 of IPOPT's
(docs/benchmarks.md), at 1/30 of its compute per sample.  A
solve that fails (IPOPT's status not success; a QP's answer infeasible) or takes longer
than the period (wall clock) is counted in the ``solve_failures`` and ``solve_overruns``
diagnostics, which the metrics report (``counters.*``), beside ``solve_cpu_overruns``
(the thread's CPU time over the period: on a loaded machine the wall clock also counts
waits for a core); after a failure the previous plan's next input is applied (the LQR's,
clipped, if there is none).
"""

from __future__ import annotations

import contextlib
import io
import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from tspend.controllers.base import Controller, Observation, diag_width, diagnostics
from tspend.plants.domain import FULL_STATE, SYMBOLIC
from tspend.controllers.full_model import FullModel, wrap_angle
from tspend.controllers.settings import KindSettings, setting, settings_for
from tspend.controllers.mpc_rti import QP_SOLVERS, RealTimeSQP
from tspend.runtime.errors import ScenarioError
from tspend.runtime.bounds import MAX_MPC_HORIZON, MAX_MPC_SUBSTEPS

if TYPE_CHECKING:
    from tspend.plants.base import Plant
    from tspend.config import Scenario
    from tspend.controllers.lqr import FullStateLQR
    from tspend.task.constraints import ConstraintSet

__all__ = ["MPCDesign", "MPCSettings", "MPCController", "SCHEMES", "build", "design",
           "ocp_constraints"]

#: how each sample's problem is solved (:attr:`MPCSettings.scheme`)
SCHEMES = ("ipopt", "rti", "sqp")

#: a bound IPOPT treats as none
_FREE = 1e19

#: the slacks' quadratic weight in (M1): enough to make the QP strictly convex; the
#: linear weight rho does the penalising (rho as quadratic weight too left the QP's
#: Hessian with a 1e9 spread that stalled qrqp's active set)
_SLACK_QUADRATIC = 1.0


@dataclass(frozen=True)
class MPCSettings(KindSettings):
    """``[controllers.mpc]``."""

    #: what tspend tune searches: the input weight against the state weights
    SEARCH = {"R": (1e-6, 1e2, "log")}

    period: float = setting(0.02, "s: control period (a whole multiple of run.dt); "
                                  "run.control_period overrides", low=0.0, strict=True)
    horizon: int = setting(30, "N, shooting intervals of one period each", kind="integer",
                           low=1, high=MAX_MPC_HORIZON)
    substeps: int = setting(2, "RK4 steps per interval", kind="integer", low=1,
                            high=MAX_MPC_SUBSTEPS)
    state_weights: tuple[float, ...] | None = setting(
        None, "diagonal of Q on the full state (default: the full LQR's)", kind="list", low=0.0)
    R: float | None = setting(None, "input weight (default: the full LQR's)", low=0.0,
                              strict=True)
    margin: float = setting(0.05, "kept from every position bound and every box of the "
                                  "task (in its state's unit: m, rad, m/s, rad/s)", low=0.0)
    max_iter: int = setting(100, "IPOPT's iteration limit per solve", kind="integer", low=1)
    tolerance: float = setting(1e-6, "IPOPT's tol; the sqp scheme's step size to stop at",
                               low=0.0, strict=True)
    scheme: str = setting("rti", "how each sample's problem is solved: ipopt (the NLP to "
                                   "convergence), rti (one Gauss-Newton SQP step from the "
                                   "shifted plan), sqp (up to sqp_iterations such steps)",
                          kind="choice", choices=SCHEMES)
    solver: str = setting("auto", "the QP solver of the rti and sqp schemes (auto: qrqp, "
                                  "hpipm when the OCP has soft rows (M3))",
                          kind="choice", choices=("auto",) + QP_SOLVERS)
    sqp_iterations: int = setting(5, "SQP steps per sample of the sqp scheme (and of either "
                                     "scheme's cold start)", kind="integer", low=1)
    compiled: bool = setting(True, "rti, sqp: the linearisation as C compiled with gcc "
                                   "(cached); false: CasADi's virtual machine", kind="bool")
    constraints: bool = setting(True, "keep the run's constraint set (task.constraints: "
                                      "hard boxes as bounds, soft boxes and linear rows with "
                                      "penalised slacks) in the OCP; false: only the model's "
                                      "bounds", kind="bool")
    slack_weight: float = setting(1e4, "rho of a soft row's slack, linear and quadratic "
                                       "(an exact penalty above the rows' multipliers)",
                                  low=0.0, strict=True)


class MPCController(Controller):
    """The ``mpc`` kind (module docstring)."""

    kind = "mpc"
    Settings = MPCSettings

    @classmethod
    def from_scenario(cls, scenario: "Scenario", machine: "Plant | None" = None) -> Controller:
        return build(scenario, machine)
    needs = (FULL_STATE, SYMBOLIC)
    guarantees = ("the actuator's range and the positions' ranges (rail, joint ranges, task "
                  "state bounds, hard boxes) hold on every predicted trajectory of a "
                  "successful solve, the task's other constraints wherever their slack is 0; "
                  "failed or late solves counted, never silent; no stability proof, no "
                  "recursive feasibility")

    def __init__(self, design: "MPCDesign") -> None:
        # stores the design (:func:`design`): the OCP and its solvers are made there, once
        d = design
        self.design, self.model, self.s, self.lqr = d, d.model, d.settings, d.lqr
        self.order, self.sample_period = d.order, d.settings.period
        self.Q, self.R, self.rows, self.soft_names = d.Q, d.R, d.rows, d.soft_names
        self.qp_solver, self.solver, self.rti = d.qp_solver, d.nlp_solver, d.rti
        self.lbx, self.ubx, self.lbg, self.ubg = d.lbx, d.ubx, d.lbg, d.ubg
        self.state_lo, self.state_hi, self.u_lo, self.u_hi = d.state_lo, d.state_hi, d.u_lo, d.u_hi
        self._reference_map = d.reference_map
        self.N, self.nx, self.ns = d.settings.horizon, d.model.size, d.rows[3].shape[1]
        self.nz, self.ng = self.nx + 1 + self.ns, self.nx * (self.N + 1)
        self._u_ref = 0.0
        self.diagnostics = DIAGNOSTICS
        self.diag = np.zeros(diag_width(self.diagnostics))
        self.reset(None)

    def reset(self, rng: np.random.Generator | None) -> None:
        self.w0: np.ndarray | None = None
        self.lam_g0: np.ndarray | None = None
        self.failures = self.overruns = self.cpu_overruns = 0
        #: the last solution: predicted states (nx, N+1) and inputs (N,), for tests
        self.plan_states = np.zeros((self.nx, self.N + 1))
        self.plan_inputs = np.zeros(self.N)
        #: and its slacks (ns, N) of (M3), one row per constraint of ``soft_names``
        self.plan_slacks = np.zeros((self.ns, self.N))
        self._plan_age = self.N
        self.z: np.ndarray | None = None
        if self.rti is not None:
            self.rti.reset()

    def references(self, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(S_r (nx, N+1), U_r (N,))`` over the horizon from the reference row now."""
        h, om, N = self.s.period, self.lqr.omega, self.N
        r0, r1 = float(ref[0]), float(ref[1])
        tau = h * np.arange(N + 1)
        if om > 0.0:
            c, s = np.cos(om * tau), np.sin(om * tau)
            r, rd = r0 * c + r1 / om * s, -r0 * om * s + r1 * c
            rdd = -om * om * r
        else:
            r, rd, rdd = np.full(N + 1, r0), np.zeros(N + 1), np.zeros(N + 1)
        rows = np.vstack([r, rd, rdd])
        E_s, c_s, e_u, c_u = self._reference_map
        Sr = E_s @ rows + c_s[:, None]
        Ur = e_u @ rows + c_u
        return Sr, Ur[:N]

    def running_cost(self, states: np.ndarray, refs: np.ndarray, u: np.ndarray,
                     dt: float) -> float:
        """The closed loop's cost: ``dt sum (e^T Q e + R (u - u_r)^2)`` over a run's samples
        (``states`` (n, nx), ``refs`` (n, 3) reference rows, ``u`` (n,) the applied
        inputs), the integral the MPC's stage cost sums by rectangles; the pole's error
        wrapped."""
        E_s, c_s, e_u, c_u = self._reference_map
        refs = np.asarray(refs, dtype=float)
        e = np.asarray(states, dtype=float) - (refs @ E_s.T + c_s)
        pole = e[:, self.model.pole]
        e[:, self.model.pole] = [wrap_angle(a) for a in pole]
        du = np.asarray(u, dtype=float) - (refs @ e_u + c_u)
        return float(dt * (np.einsum("ij,jk,ik->", e, self.Q, e) + self.R * du @ du))

    def solve(self, state: np.ndarray, ref: np.ndarray) -> tuple[float, bool, float]:
        """``(u, success, wall seconds)`` of one sample's solve from ``state``."""
        if self.rti is not None:
            return self._solve_rti(state, ref)
        m, N, nx = self.model, self.N, self.nx
        s0 = np.asarray(state, dtype=float).copy()
        # the pole's angle nearest the reference: a turned-over pole is not 2 pi off
        s0[m.pole] = float(ref[0]) + wrap_angle(s0[m.pole] - float(ref[0]))
        Sr, Ur = self.references(ref)
        self._u_ref = float(Ur[0])
        ns, nS = self.ns, nx * (N + 1)
        if self.w0 is None:
            w0 = np.concatenate([np.tile(s0, N + 1), np.clip(Ur, self.u_lo, self.u_hi),
                                 np.zeros(N * ns)])
        else:
            # shift the last plan by one period; repeat its last node
            Sp = self.w0[:nS].reshape(N + 1, nx)
            Up = self.w0[nS:nS + N]
            Ep = self.w0[nS + N:].reshape(N, ns)
            w0 = np.concatenate([np.vstack([s0, Sp[2:], Sp[-1:]]).ravel(),
                                 np.concatenate([Up[1:], Up[-1:]]),
                                 np.vstack([Ep[1:], Ep[-1:]]).ravel()])
        p = np.concatenate([s0, Sr.T.ravel(), Ur])
        started = time.perf_counter()
        # a signal during the solve: CasADi catches it and prints a warning through Python's
        # stderr; the loop honours the stop at the next sample and says so in its own line
        with contextlib.redirect_stderr(io.StringIO()):
            sol = self.solver(x0=w0, p=p, lbx=self.lbx, ubx=self.ubx, lbg=self.lbg,
                              ubg=self.ubg)
        wall = time.perf_counter() - started
        stats = self.solver.stats()
        ok = bool(stats.get("success", False))
        self.diag[3] = float(stats.get("iter_count", 0))
        if ok:
            w = np.asarray(sol["x"]).ravel()
            self.w0 = w
            self.plan_states = w[:nS].reshape(N + 1, nx).T.copy()
            self.plan_inputs = w[nS:nS + N].copy()
            self.plan_slacks = w[nS + N:].reshape(N, ns).T.copy()
            self._plan_age = 0
            return float(self.plan_inputs[0]), True, wall
        return math.nan, False, wall

    def _solve_rti(self, state: np.ndarray, ref: np.ndarray) -> tuple[float, bool, float]:
        """One sample of the rti or sqp scheme (:mod:`.mpc_rti`); the wall time is the
        whole sample's, references and shift included."""
        started = time.perf_counter()
        m, N, nx, nz, rti = self.model, self.N, self.nx, self.nz, self.rti
        s0 = np.array(state, dtype=float)
        s0[m.pole] = float(ref[0]) + wrap_angle(s0[m.pole] - float(ref[0]))
        Sr, Ur = self.references(ref)
        self._u_ref = float(Ur[0])
        zr = np.concatenate([np.vstack([Sr[:, :N], Ur[None, :], np.zeros((self.ns, N))]
                                       ).T.ravel(), Sr[:, N]])
        if self.z is None:
            # cold: the state held, the feedforward input, no slack; iterate as the sqp
            # scheme does
            z = np.concatenate([np.tile(np.append(s0, np.zeros(nz - nx)), N), s0])
            z[nx:N * nz:nz] = np.clip(Ur, self.u_lo, self.u_hi)
            iterations = self.s.sqp_iterations
        else:
            z = rti.shifted(self.z, nz)
            iterations = self.s.sqp_iterations if self.s.scheme == "sqp" else 1
        try:
            z, steps = rti.iterate(z, s0, zr, iterations, self.s.tolerance)
        except RuntimeError:
            self.diag[3] = 0.0
            self.z = None
            rti.reset()
            return math.nan, False, time.perf_counter() - started
        self.diag[3] = float(steps)
        self.z = z
        body = z[:N * nz].reshape(N, nz)
        self.plan_states = np.vstack([body[:, :nx], z[None, N * nz:]]).T
        self.plan_inputs = body[:, nx].copy()
        self.plan_slacks = body[:, nx + 1:].T.copy()
        self._plan_age = 0
        return float(self.plan_inputs[0]), True, time.perf_counter() - started

    def act(self, state: np.ndarray, ref: np.ndarray) -> float:
        cpu_started = time.thread_time()
        u, ok, wall = self.solve(state, ref)
        cpu = time.thread_time() - cpu_started
        if not ok:
            self.failures += 1
            self._plan_age += 1
            if self._plan_age < self.N:     # the previous plan's input for now
                u = float(self.plan_inputs[self._plan_age])
            else:
                u = min(self.u_hi, max(self.u_lo, self.lqr.act(state, ref)))
        if wall > self.s.period:
            self.overruns += 1
        if cpu > self.s.period:
            self.cpu_overruns += 1
        d = self.diag
        d[0], d[1], d[2] = 1e3 * wall, self.failures, self.overruns
        d[4] = self._u_ref
        d[5], d[6] = 1e3 * cpu, self.cpu_overruns
        return u

    def step(self, obs: Observation, dt: float) -> float:
        return self.act(obs.state, obs.ref)

    def parameters(self) -> dict[str, np.ndarray]:
        return {}


#: what the mpc kind shows each sample (its panels in a recording)
DIAGNOSTICS = diagnostics(
    ("solve_ms", 1, {"panel": "solver", "unit": "ms",
                     "description": "wall time of this sample's NLP solve "
                                    "(rti, sqp: of the whole sample)"}),
    ("solve_failures", 1, {"panel": "counters",
                           "description": "solves that did not succeed, so far"}),
    ("solve_overruns", 1, {"panel": "counters",
                           "description": "solves longer than the period, so far"}),
    ("iterations", 1, {"panel": "solver",
                       "description": "IPOPT iterations (rti, sqp: SQP steps)"}),
    ("u_ref", 1, {"panel": "control", "description": "feedforward u_r"}),
    # the CPU time this thread spent on the sample: on a loaded machine the wall
    # time also counts waits for a core, which no solver can shorten
    ("solve_cpu_ms", 1, {"panel": "solver", "unit": "ms",
                         "description": "this thread's CPU time in the sample's solve"}),
    ("solve_cpu_overruns", 1, {"panel": "counters",
                               "description": "solves whose CPU time exceeded the "
                                              "period, so far"}))


@dataclass(frozen=True)
class MPCDesign:
    """What the mpc kind designs once on the nominal machine (:func:`design`): the OCP's
    weights, bounds and rows and its compiled solvers; :class:`MPCController` runs over it."""

    model: FullModel
    settings: MPCSettings
    lqr: "FullStateLQR"
    Q: np.ndarray
    R: float
    order: int
    #: (C, D, b, S) of (M3) and the soft rows' names (:func:`ocp_constraints`)
    rows: tuple
    soft_names: tuple[str, ...]
    #: the QP solver the rti and sqp schemes use (``solver``, "auto" resolved)
    qp_solver: str
    #: IPOPT on the NLP (scheme ipopt), else None
    nlp_solver: Any
    #: the rti and sqp schemes' SQP (:mod:`.mpc_rti`), else None
    rti: RealTimeSQP | None
    lbx: np.ndarray
    ubx: np.ndarray
    lbg: np.ndarray
    ubg: np.ndarray
    state_lo: np.ndarray
    state_hi: np.ndarray
    u_lo: float
    u_hi: float
    #: (E_s, c_s, e_u, c_u) of :func:`linear_reference_map`
    reference_map: tuple


def design(model: FullModel, settings: MPCSettings, lqr: "FullStateLQR", Q: np.ndarray,
           R: float, order: int, constraints: "ConstraintSet | None" = None) -> MPCDesign:
    """The mpc kind's :class:`MPCDesign` on ``model`` (the nominal machine's): (M2)'s bounds
    and (M3)'s rows (:func:`ocp_constraints`), the NLP or the SQP over ``F``, the RK4 map
    of one period (the hold the plant sees), and the LQR's terminal cost and references."""
    Q, R = np.asarray(Q, dtype=float), float(R)
    N, nx = settings.horizon, model.size
    lo_s, hi_s, u_lo, u_hi, rows, soft_names = ocp_constraints(
        model, constraints if settings.constraints else None, settings.margin)
    b, ns = rows[2], rows[3].shape[1]
    qp_solver = _qp_solver(settings, ns, soft_names)
    F = model.rk4_map(settings.period, settings.substeps, name="F")
    nlp_solver = rti = None
    if settings.scheme == "ipopt":
        nlp_solver = _ipopt_solver(F, settings, Q, R, np.asarray(lqr.P, dtype=float), rows, nx)
    else:
        rti = _sqp_solver(F, settings, Q, R, np.asarray(lqr.P, dtype=float), rows,
                          (lo_s, hi_s, u_lo, u_hi), qp_solver, nx)
    return MPCDesign(
        model=model, settings=settings, lqr=lqr, Q=Q, R=R, order=order, rows=rows,
        soft_names=soft_names, qp_solver=qp_solver, nlp_solver=nlp_solver, rti=rti,
        # bounds on the decision vector (the first state's are moot: s_0 = s(t))
        lbx=np.concatenate([np.tile(lo_s, N + 1), np.full(N, u_lo), np.zeros(N * ns)]),
        ubx=np.concatenate([np.tile(hi_s, N + 1), np.full(N, u_hi), np.full(N * ns, _FREE)]),
        lbg=np.concatenate([np.zeros(nx * (N + 1)), np.full(N * len(b), -np.inf)]),
        ubg=np.concatenate([np.zeros(nx * (N + 1)), np.tile(b, N)]),
        state_lo=lo_s, state_hi=hi_s, u_lo=u_lo, u_hi=u_hi,
        reference_map=linear_reference_map(lqr, nx))


def _qp_solver(settings: MPCSettings, ns: int, soft_names: tuple[str, ...]) -> str:
    """``solver`` with "auto" resolved: hpipm when the OCP has soft rows, else qrqp."""
    if settings.solver == "auto":
        return "hpipm" if ns else "qrqp"
    if settings.solver == "qrqp" and ns and settings.scheme != "ipopt":
        # measured: with (M3)'s rows active qrqp (CasADi 3.8.2) stalls at its iteration
        # limit or reports success on answers metres outside them
        raise ScenarioError(f"controllers.mpc.solver: qrqp cannot take the task's soft "
                            f"constraints ({', '.join(soft_names)}: rows with slacks "
                            f"in the OCP); allowed: auto, hpipm, daqp, osqp, or "
                            f"controllers.mpc.constraints = false")
    return settings.solver


def _ipopt_solver(F: Any, settings: MPCSettings, Q: np.ndarray, R: float, P: np.ndarray,
                  rows: tuple, nx: int) -> Any:
    """IPOPT on the whole NLP: multiple shooting over ``F``, (M1)'s cost and (M3)'s rows."""
    import casadi

    N, h, rho = settings.horizon, settings.period, settings.slack_weight
    C, D, _, sel = rows
    ns = sel.shape[1]
    S = casadi.SX.sym("S", nx, N + 1)
    U = casadi.SX.sym("U", 1, N)
    E = casadi.SX.sym("E", ns, N)
    s0 = casadi.SX.sym("s0", nx)
    Sr = casadi.SX.sym("Sr", nx, N + 1)
    Ur = casadi.SX.sym("Ur", 1, N)
    Qm = casadi.DM(Q)
    cost, g = 0, [S[:, 0] - s0]
    stage_rows = []
    for k in range(N):
        e = S[:, k] - Sr[:, k]
        # h x the stage: a rectangle sum of the LQR's integral cost, so P is its tail
        cost += h * (casadi.mtimes([e.T, Qm, e]) + R * (U[0, k] - Ur[0, k]) ** 2)
        g.append(S[:, k + 1] - F(S[:, k], U[0, k]))
        if ns:
            # (M3) and its exact penalty (M1)
            cost += rho * casadi.sum1(E[:, k]) + _SLACK_QUADRATIC * casadi.sumsqr(E[:, k])
            stage_rows.append(casadi.mtimes(casadi.DM(C), S[:, k]) + casadi.DM(D) * U[0, k]
                              - casadi.mtimes(casadi.DM(sel), E[:, k]))
    eN = S[:, N] - Sr[:, N]
    cost += casadi.mtimes([eN.T, casadi.DM(P), eN])
    # decision vector: [S (column by column), U, E (column by column)]; the constraints:
    # the shooting equalities, then (M3)'s rows stage by stage
    w = casadi.vertcat(casadi.reshape(S, -1, 1), casadi.reshape(U, -1, 1),
                       casadi.reshape(E, -1, 1))
    p = casadi.vertcat(s0, casadi.reshape(Sr, -1, 1), casadi.reshape(Ur, -1, 1))
    nlp = {"x": w, "p": p, "f": cost, "g": casadi.vertcat(*g, *stage_rows)}
    opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
            "ipopt.max_iter": settings.max_iter, "ipopt.tol": settings.tolerance}
    return casadi.nlpsol("mpc", "ipopt", nlp, opts)


def _sqp_solver(F: Any, settings: MPCSettings, Q: np.ndarray, R: float, P: np.ndarray,
                rows: tuple, bounds: tuple, qp_solver: str, nx: int) -> RealTimeSQP:
    """The rti and sqp schemes' SQP (:class:`RealTimeSQP`): the same cost's Hessian stage
    by stage over ``(x_k, u_k, e_k)``, then ``x_N``, the bounds with no bound as infinite."""
    C, D, b, sel = rows
    lo_s, hi_s, u_lo, u_hi = bounds
    N, h, ns = settings.horizon, settings.period, sel.shape[1]
    nz = nx + 1 + ns
    stage = np.zeros((nz, nz))
    stage[:nx, :nx], stage[nx, nx] = 2.0 * h * Q, 2.0 * h * R
    stage[nx + 1:, nx + 1:] = 2.0 * _SLACK_QUADRATIC * np.eye(ns)
    inf_lo = np.where(lo_s <= -_FREE, -np.inf, lo_s)
    inf_hi = np.where(hi_s >= _FREE, np.inf, hi_s)
    ulo = u_lo if u_lo > -_FREE else -np.inf
    uhi = u_hi if u_hi < _FREE else np.inf
    z_lo = np.concatenate([np.tile(np.concatenate([inf_lo, [ulo], np.zeros(ns)]), N), inf_lo])
    z_hi = np.concatenate([np.tile(np.concatenate([inf_hi, [uhi], np.full(ns, np.inf)]), N),
                           inf_hi])
    G = np.hstack([C, D[:, None], -sel])
    return RealTimeSQP(F, nx, N, stage, 2.0 * P, z_lo, z_hi, qp_solver, settings.compiled,
                       stage_rows=G, stage_bound=b,
                       stage_gradient=np.concatenate([np.zeros(nx + 1),
                                                      np.full(ns, settings.slack_weight)]),
                       nz=nz)


def linear_reference_map(lqr: "FullStateLQR", nx: int
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """``(E_s, c_s, e_u, c_u)``: the LQR's ``reference_state`` is affine in the
    reference row, ``s_r = E_s row + c_s``, ``u_r = e_u . row + c_u``; read off it once
    so that the horizon's references are two matrix products per sample."""
    s_c, u_c = lqr.reference_state(np.zeros(3))
    E_s, e_u = np.empty((nx, 3)), np.empty(3)
    for i in range(3):
        row = np.zeros(3)
        row[i] = 1.0
        s_i, u_i = lqr.reference_state(row)
        E_s[:, i], e_u[i] = s_i - s_c, u_i - u_c
    return E_s, np.asarray(s_c, dtype=float), e_u, float(u_c)


def _model_bounds(model: FullModel, margin: float) -> tuple[np.ndarray, np.ndarray, float, float]:
    """``(state lo, state hi, u_lo, u_hi)`` of the model: its positions' ranges less
    ``margin`` and the input's range, :data:`_FREE` where there is none."""
    nx = model.size
    lo_s, hi_s = np.full(nx, -_FREE), np.full(nx, _FREE)
    for j in range(model.dof):
        lo, hi = model.q_lo[j], model.q_hi[j]
        if math.isfinite(lo):
            lo_s[j] = lo + margin
        if math.isfinite(hi):
            hi_s[j] = hi - margin
    u_lo = model.u_lo if math.isfinite(model.u_lo) else -_FREE
    u_hi = model.u_hi if math.isfinite(model.u_hi) else _FREE
    return lo_s, hi_s, u_lo, u_hi


def _state_columns(model: FullModel, cs: "ConstraintSet") -> list[int]:
    """Where each of the model's states sits among the constraint set's columns, by name:
    the plant's full state (then u) is the model's, but nothing here relies on the order
    being the same (ScenarioError when the names differ)."""
    if tuple(cs.names[:-1]) != tuple(model.state_names):
        missing = set(model.state_names) - set(cs.names[:-1])
        if missing or len(cs.names) - 1 != model.size:
            raise ScenarioError(f"controllers.mpc: the constraints' states "
                                f"({', '.join(cs.names[:-1])}) are not the model's "
                                f"({', '.join(model.state_names)})")
    return [cs.names.index(n) for n in model.state_names]


def ocp_constraints(model: FullModel, cs: "ConstraintSet | None", margin: float) -> tuple:
    """``(state lo, state hi, u_lo, u_hi, (C, D, b, S), soft_names)``: the bounds of (M2)
    and the input, the rows of (M3) (S: each row's slack, one per constraint) and the
    constraints (M3) keeps, in slack order, from the model's bounds and the constraint
    set ``cs`` (None: the model's bounds only); every box keeps ``margin`` (also the
    predictive safety filter's, :mod:`.mpsc`)."""
    nx = model.size
    lo_s, hi_s, u_lo, u_hi = _model_bounds(model, margin)
    C, D, b, owner, names = [], [], [], [], []
    if cs is not None:
        col = _state_columns(model, cs)
        for c in cs:
            for a_row, b_row in zip(c.A, c.b):
                a_s, a_u = a_row[col], float(a_row[-1])
                nonzero = np.flatnonzero(a_s)
                if a_u != 0.0 and nonzero.size == 0:
                    # a box on the input: the input's bound (always feasible)
                    if a_u > 0.0:
                        u_hi = min(u_hi, b_row / a_u)
                    else:
                        u_lo = max(u_lo, b_row / a_u)
                    continue
                box = a_u == 0.0 and nonzero.size == 1
                j = int(nonzero[0]) if box else -1
                # a box keeps the margin, as the rail does (in the state's unit: m or
                # rad, m/s or rad/s): the OCP holds it at the period's nodes on the
                # model, the machine moves between them and differs from the model
                room = b_row - (abs(a_s[j]) * margin if box else 0.0)
                if box and c.hard and j < model.dof:
                    # a position's hard box: a bound, as the rail (the margin is the
                    # room a measured state needs); a velocity's is a slack row below:
                    # a measured speed at its bound would make the bound infeasible
                    if a_s[j] > 0.0:
                        hi_s[j] = min(hi_s[j], room / a_s[j])
                    else:
                        lo_s[j] = max(lo_s[j], room / a_s[j])
                    continue
                if c.name not in names:
                    names.append(c.name)
                C.append(a_s)
                D.append(a_u)
                b.append(room)
                owner.append(names.index(c.name))
    sel = np.zeros((len(owner), len(names)))
    sel[np.arange(len(owner)), owner] = 1.0
    rows = (np.array(C, dtype=float).reshape(-1, nx), np.array(D, dtype=float),
            np.array(b, dtype=float), sel)
    return lo_s, hi_s, u_lo, u_hi, rows, tuple(names)


def build(scenario: "Scenario", machine: "Plant | None" = None) -> MPCController:
    from tspend.controllers.full_model import full_model_and_constraints
    from tspend.controllers.lqr import LQRSettings, build_full

    from tspend.runtime.extras import missing_extra

    problem = missing_extra("casadi", "controller 'mpc'")
    if problem:
        raise ScenarioError(problem)
    s: MPCSettings = settings_for(scenario, MPCSettings)
    model, constraints = full_model_and_constraints(scenario, machine)
    dt = scenario.run.dt
    if abs(s.period / dt - round(s.period / dt)) > 1e-9 * max(1.0, s.period / dt):
        raise ScenarioError(f"{scenario.path}: controllers.mpc.period: must be a whole multiple "
                            f"of run.dt = {dt:g} s, got {s.period:g}")
    lqr = build_full(scenario, settings_for(scenario, LQRSettings), machine)
    if s.state_weights is not None:
        if len(s.state_weights) != model.size:
            raise ScenarioError(f"{scenario.path}: controllers.mpc.state_weights: needs "
                                f"{model.size} entries ({', '.join(model.state_names)}), "
                                f"got {len(s.state_weights)}")
        Q = np.diag(s.state_weights)
    else:
        Q = lqr.Q
    R = s.R if s.R is not None else lqr.R
    return MPCController(design(model, s, lqr, Q, R, order=len(scenario.plant.x0),
                                constraints=constraints))
