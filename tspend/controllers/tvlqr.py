"""``tvlqr``: follows a planned swing-up with time-varying LQR, then balances with LQR.

The plan (:mod:`.trajectory`: states ``s*_k`` and inputs ``u*_k`` on the run's step
``dt``, from the start to the upright) is read from a file written by ``tspend plan``
(``plan``), or made from the first observed state at the run's first sample when no file
is named (the time it took is the ``plan_s`` diagnostic and is printed by ``tspend
plan``).  About the plan, the deviation ``e_k = s_k - s*_k`` (angles wrapped) obeys to
first order ``e_{k+1} = A_k e_k + B_k (u_k - u*_k)``, with ``A_k, B_k`` the zero-order-hold
discretisation over ``dt`` of the domain's CasADi model's Jacobians at ``(s*_k, u*_k)``:

    [A_k B_k; 0 1] = expm([A_c B_c; 0 0] dt)                                   (V1)

(Franklin, Powell and Workman, *Digital Control of Dynamic Systems*, 3rd ed., 1998,
sec. 4.3.3).  The gains come from the discrete Riccati recursion backwards along the
plan (Anderson and Moore, *Optimal Control: Linear Quadratic Methods*, 1990, sec. 2.4;
Tedrake, *Underactuated Robotics*, ch. "Trajectory optimisation", TVLQR):

    K_k = (R dt + B_k^T P_{k+1} B_k)^-1 B_k^T P_{k+1} A_k
    P_k = Q dt + A_k^T P_{k+1} (A_k - B_k K_k)                                 (V2)

from ``P_n`` = the discrete algebraic Riccati solution at the upright (the cost-to-go of
the LQR that takes over).  ``Q`` and ``R`` are the full-state LQR's (:mod:`.lqr`,
``[controllers.lqr]``).  Each sample: ``u = u*_k - K_k e_k`` clipped to the actuator's
range while the plan lasts; after its end, the full-state LQR of :mod:`.lqr`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numba import njit

import tspend.runtime.xp as xp
from tspend.controllers.base import (CompiledController, Controller, Observation, diag_width,
                                     diagnostics)
from tspend.controllers.lqr import FullLQRLaw, full_lqr_law
from tspend.controllers.swingup import clipped
from tspend.plants.domain import wrap_angle
from tspend.runtime.jit import JIT
from tspend.runtime.law import array_law
from tspend.controllers.settings import KindSettings, setting, settings_for
from tspend.controllers.trajectory import Plan, PlanFailed, plan_swingup, read_plan
from tspend.runtime.errors import ScenarioError
from tspend.plants.domain import FULL_STATE, SYMBOLIC

if TYPE_CHECKING:
    from tspend.plants.base import Plant
    from tspend.config import Scenario
    from tspend.controllers.full_model import FullModel
    from tspend.controllers.lqr import FullStateLQR

__all__ = ["TVLQRSettings", "TVLQRController", "build", "tvlqr_gains", "plan_of"]

#: modes recorded in the ``mode`` diagnostic
FOLLOW, BALANCE = 0.0, 1.0


@dataclass(frozen=True)
class TVLQRSettings(KindSettings):
    """``[controllers.tvlqr]``: the plan to follow, or how to make one (``tspend plan``
    reads the same table)."""

    #: what tspend tune searches: the plan's length (a shorter one asks more of the input)
    SEARCH = {"horizon": (1.0, 6.0, "log")}

    plan: str = setting("", "the plan file (Parquet from 'tspend plan'; relative: to the "
                            "working directory, the scenario's directory, then the project); "
                            "empty: plan from the first observed state", kind="string")
    horizon: float = setting(2.0, "s: the plan's length T, from the start to the upright "
                                   "(rounded to whole intervals)",
                             low=0.0, strict=True)
    interval: float = setting(0.02, "s: the shooting interval h (u held over it), a whole "
                                    "multiple of run.dt", low=0.0, strict=True)
    step: float = setting(0.01, "s: the RK4 step of the planner's model inside an interval "
                                "(run.dt makes the plan MuJoCo's RK4 to round-off, slower)",
                          low=0.0, strict=True)
    margin: float = setting(0.05, "kept from every position bound (m or rad)", low=0.0)
    max_iter: int = setting(1000, "IPOPT's iteration limit", kind="integer", low=1)
    tolerance: float = setting(1e-8, "IPOPT's tol", low=0.0, strict=True)


def find_plan(path: str, scenario: "Scenario") -> Path:
    """The plan file ``path`` names, looked for like a scenario's MJCF."""
    from tspend.shipped import find_named_file

    return find_named_file(path, scenario, "controllers.tvlqr.plan")


def tvlqr_gains(model: "FullModel", plan: Plan, Q: np.ndarray, R: float,
                P_end: np.ndarray) -> np.ndarray:
    """``K_k`` (n, nx) for every row of the plan but the last, by (V1)-(V2)."""
    import casadi

    nx, n, dt = model.size, plan.t.size - 1, plan.dt
    f = model.symbolic()
    s, u = casadi.SX.sym("s", nx), casadi.SX.sym("u")
    rhs = f(s, u)
    jac = casadi.Function("plan_jacobians", [s, u], [casadi.jacobian(rhs, s), casadi.jacobian(rhs, u)])
    Ac, Bc = jac.map(n)(plan.states[:n].T, plan.u[:n][None, :])
    Ac, Bc = np.asarray(Ac).reshape(nx, n, nx), np.asarray(Bc).reshape(nx, n)
    K = np.empty((n, nx))
    P = np.asarray(P_end, dtype=float)
    Qd, Rd = Q * dt, R * dt
    M = np.zeros((n, nx + 1, nx + 1))
    M[:, :nx, :nx], M[:, :nx, nx] = Ac.transpose(1, 0, 2), Bc.T
    E = expm_stack(M * dt)
    for k in range(n - 1, -1, -1):
        A, B = E[k, :nx, :nx], E[k, :nx, nx:]
        BP = B.T @ P
        Kk = np.linalg.solve(Rd + BP @ B, BP @ A)
        P = Qd + A.T @ P @ (A - B @ Kk)
        P = 0.5 * (P + P.T)
        K[k] = Kk[0]
    return K


def expm_stack(M: np.ndarray) -> np.ndarray:
    """``expm`` of each matrix of the stack ``M`` (k, m, m): scaling and squaring with a
    Taylor polynomial of degree 14 (Moler and Van Loan, "Nineteen dubious ways...", SIAM
    Review 45, 2003, method 3), batched: scipy's ``expm`` one matrix at a time costs
    milliseconds each on a loaded machine, the plan has thousands."""
    norm = float(np.abs(M).sum(axis=2).max()) if M.size else 0.0
    squarings = max(0, int(math.ceil(math.log2(norm / 0.25)))) if norm > 0.25 else 0
    X = M / 2.0 ** squarings
    E = np.broadcast_to(np.eye(M.shape[1]), M.shape).copy()
    term = E.copy()
    for j in range(1, 15):   # ||X|| <= 1/4: the remainder is below 1/4^15 / 15! ~ 1e-21
        term = term @ X / j
        E += term
    for _ in range(squarings):
        E = E @ E
    return E


def discrete_terminal(model: "FullModel", lqr: "FullStateLQR", dt: float) -> np.ndarray:
    """``P_n``: the discrete Riccati solution at the upright with the LQR's weights."""
    from scipy.linalg import solve_discrete_are

    nx = model.size
    M = np.zeros((1, nx + 1, nx + 1))
    M[0, :nx, :nx], M[0, :nx, nx:] = lqr.A, lqr.B
    E = expm_stack(M * dt)[0]
    return solve_discrete_are(E[:nx, :nx], E[:nx, nx:], lqr.Q * dt, np.array([[lqr.R * dt]]))


class TVLQRLaw(NamedTuple):
    """A plan's numbers as compiled code reads them (:func:`tvlqr_law`)."""

    states: np.ndarray      # (n + 1, nx) s*_k
    u: np.ndarray           # (n + 1,) u*_k
    K: np.ndarray           # (n, nx) K_k of (V2)
    angles: np.ndarray      # (nx,) bool: errors wrapped to (-pi, pi]
    dt: float
    u_lo: float
    u_hi: float
    lqr: FullLQRLaw         # the LQR after the plan
    lqr_diag: np.ndarray    # its own diagnostics (not recorded)
    e: np.ndarray           # (nx,) scratch: the error


@array_law
def tvlqr_law(law: TVLQRLaw, clock: np.ndarray, scratch, t: float, full: np.ndarray,
              x: np.ndarray, ref: np.ndarray, dt: float, diag: np.ndarray) -> tuple:
    """``(u, clock)``: ``u = u*_k - K_k e_k`` while the plan lasts, the LQR after it, clipped
    to the input's range (module docstring); ``clock = [t0, started]``, the plan's start
    (the first sample's time).  The one implementation, for numba and JAX
    (:mod:`tspend.runtime.law`)."""
    t0 = xp.where(clock[1] > 0.0, clock[0], t)
    clock = xp.put(clock, 0, t0)
    clock = xp.put(clock, 1, 1.0)
    n = law.K.shape[0]
    k = xp.rounded_index((t - t0) / law.dt)
    follow = k < n
    row = xp.where(follow, k, n)        # the plan's last row after it
    gain_row = xp.where(follow, k, n - 1)
    e = law.e
    u_fb = 0.0
    norm2 = 0.0
    for j in range(e.size):
        d = full[j] - law.states[row, j]
        e = xp.put(e, j, xp.where(law.angles[j], wrap_angle(d), d))
        u_fb += law.K[gain_row, j] * e[j]
        norm2 += e[j] * e[j]
    u_plan = law.u[row]
    u_lqr = full_lqr_law(law.lqr, full, ref, law.lqr_diag)
    diag = xp.put(diag, 0, xp.where(follow, FOLLOW, BALANCE))
    diag = xp.put(diag, 1, xp.where(follow, u_plan, 0.0))
    diag = xp.put(diag, 2, math.sqrt(norm2))
    u = xp.where(follow, u_plan - u_fb, u_lqr)
    return clipped(u, law.u_lo, law.u_hi), clock


@njit(**JIT)
def tvlqr_step(law: TVLQRLaw, clock: np.ndarray, scratch, t: float, full: np.ndarray,
               x: np.ndarray, ref: np.ndarray, dt: float, diag: np.ndarray) -> float:
    """:func:`tvlqr_law` behind the compiled controllers' common signature."""
    return tvlqr_law(law, clock, scratch, t, full, x, ref, dt, diag)[0]


@dataclass(frozen=True)
class TVLQRDesign:
    """The kind's design (:func:`design`): the model, settings and LQR it follows a plan
    with, the run's step, the terminal cost ``P_n`` and, when a plan is given, its law."""

    model: "FullModel"
    settings: TVLQRSettings
    lqr: "FullStateLQR"
    dt: float
    P_end: np.ndarray
    where: str
    units: tuple[tuple[str, ...], str, str]
    law: TVLQRLaw | None


def plan_law(model: "FullModel", lqr: "FullStateLQR", plan: Plan, P_end: np.ndarray,
             dt: float, where: str) -> TVLQRLaw:
    """The law's numbers of following ``plan``: its gains by (V1)-(V2).  Pure;
    ScenarioError when the plan is not of this plant or this step."""
    if tuple(plan.state_names) != tuple(model.state_names):
        raise ScenarioError(f"{where}.plan: its states {', '.join(plan.state_names)} are "
                            f"not the plant's {', '.join(model.state_names)}")
    if abs(plan.dt - dt) > 1e-12 * max(1.0, dt):
        raise ScenarioError(f"{where}.plan: made on a step of {plan.dt:g} s, the run's "
                            f"is run.dt = {dt:g} s")
    K = tvlqr_gains(model, plan, lqr.Q, lqr.R, P_end)
    return TVLQRLaw(np.ascontiguousarray(plan.states, dtype=float),
                    np.ascontiguousarray(plan.u, dtype=float), K,
                    np.array(model.angles[:model.size], dtype=bool), float(dt),
                    float(model.u_lo), float(model.u_hi), lqr.law, np.zeros_like(lqr.diag),
                    np.zeros(model.size))


def design(model: "FullModel", settings: TVLQRSettings, lqr: "FullStateLQR", dt: float,
           plan: Plan | None, where: str,
           units: tuple[tuple[str, ...], str, str]) -> TVLQRDesign:
    """The kind's design (:class:`TVLQRDesign`): pure; a plan made at the first sample
    gets its law then (:meth:`TVLQRController.act`)."""
    P_end = discrete_terminal(model, lqr, float(dt))
    law = plan_law(model, lqr, plan, P_end, float(dt), where) if plan is not None else None
    return TVLQRDesign(model, settings, lqr, float(dt), P_end, where, units, law)


class TVLQRController(Controller):
    """The ``tvlqr`` kind (module docstring)."""

    kind = "tvlqr"
    Settings = TVLQRSettings

    @classmethod
    def from_scenario(cls, scenario: "Scenario", machine: "Plant | None" = None) -> Controller:
        return build(scenario, machine)
    needs = (FULL_STATE, SYMBOLIC)
    guarantees = ("a plan within the actuator's and positions' ranges (checked by IPOPT on the "
                  "planner's model); local tracking of it on the linearisation about it; "
                  "LQR's local guarantee after it; the input clipped to its range")

    def __init__(self, design: TVLQRDesign, order: int) -> None:
        self.design, self.order = design, order
        self.model, self.s, self.lqr, self.dt = design.model, design.settings, design.lqr, design.dt
        self.where, self.units, self.P_end = design.where, design.units, design.P_end
        self.diagnostics = diagnostics(
            ("mode", 1, {"panel": "mode", "description": "0 following the plan, 1 LQR"}),
            ("u_plan", 1, {"panel": "control", "description": "the plan's input u*_k"}),
            ("plan_error", 1, {"panel": "state", "description":
                               "|s - s*_k|, angles wrapped (the plan's last row after it)"}),
            ("plan_s", 1, {"panel": "solver", "unit": "s",
                           "description": "wall time of the plan made at the first sample "
                                          "(0: read from a file)"}))
        self.diag = np.zeros(diag_width(self.diagnostics))
        #: [t0, started]: the plan's start, the first sample's time
        self.clock = np.zeros(2)
        self.law = design.law
        self.reset(None)

    @property
    def K(self) -> np.ndarray:
        """The plan's gains ``K_k`` (none before a plan)."""
        return self.law.K if self.law is not None else np.zeros((0, self.model.size))

    def make_plan(self, s0: np.ndarray) -> Plan:
        """A plan from ``s0`` with this kind's settings (:func:`.trajectory.plan_swingup`)."""
        s = self.s
        return plan_swingup(self.model, s0, s.horizon, s.interval, self.dt, step=s.step,
                            margin=s.margin, max_iter=s.max_iter, tolerance=s.tolerance,
                            where=self.where, units=self.units)

    def reset(self, rng: np.random.Generator | None) -> None:
        self.clock[:] = 0.0
        self.law = self.design.law
        self.diag[:] = 0.0

    def act(self, t: float, state: np.ndarray, ref: np.ndarray) -> float:
        state = np.asarray(state, dtype=float)
        if self.law is None:     # the plan made at the first sample
            started = time.perf_counter()
            try:
                plan = self.make_plan(state)
            except PlanFailed as exc:
                raise RuntimeError(str(exc)) from None
            self.law = plan_law(self.model, self.lqr, plan, self.P_end, self.dt, self.where)
            self.diag[3] = time.perf_counter() - started
        return tvlqr_step(self.law, self.clock, None, t, state, state, ref, self.dt, self.diag)

    def step(self, obs: Observation, dt: float) -> float:
        return self.act(obs.t, obs.state, obs.ref)

    def compiled(self) -> CompiledController | None:
        """The law in the compiled loops when the plan is given (one made at the first
        sample runs here, in Python, IPOPT first)."""
        if self.design.law is None:
            return None
        return CompiledController(tvlqr_step, self.design.law, self.clock, None, tvlqr_law)


def plan_of(scenario: "Scenario", machine: "Plant") -> tuple["FullModel", TVLQRSettings, tuple]:
    """The model, the settings and the units a plan of ``scenario`` is made with, on the
    nominal ``machine`` (:func:`tspend.loop.simulation.nominal_machine`)."""
    from tspend.controllers.full_model import full_model

    from tspend.runtime.extras import missing_extra

    problem = missing_extra("casadi", "planning")
    if problem:
        raise ScenarioError(problem)
    s: TVLQRSettings = settings_for(scenario, TVLQRSettings)
    model = full_model(scenario, machine)
    inp = machine.inputs[0] if machine.inputs else None
    units = (tuple(machine.state_units), inp.name if inp else "u", inp.unit if inp else "")
    return model, s, units


def build(scenario: "Scenario", machine: "Plant | None" = None) -> TVLQRController:
    from tspend.controllers.lqr import LQRSettings, build_full

    model, s, units = plan_of(scenario, machine)
    where = f"{scenario.path or scenario.name}: controllers.tvlqr"
    lqr = build_full(scenario, settings_for(scenario, LQRSettings), machine)
    plan = read_plan(find_plan(s.plan, scenario), f"{where}.plan") if s.plan.strip() else None
    if plan is None:   # the settings checked now, not at the first sample
        from tspend.controllers.trajectory import check_plan_input

        check_plan_input(model, np.zeros(model.size), s.horizon, s.interval, scenario.run.dt,
                         s.margin, where, s.step)
    return TVLQRController(design(model, s, lqr, scenario.run.dt, plan, where, units),
                           len(scenario.plant.x0))
