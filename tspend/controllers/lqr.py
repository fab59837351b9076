"""``lqr``: linear-quadratic regulator on the plant linearised at its operating point.

The linearisation (:meth:`.plant_model.PlantModel.state_space`, numerical Jacobians of
the plant's own ``f``) is ``x' = A (x - x*) + B (u - u*)`` with ``A`` the chain of
integrators whose last row is ``a = df/dx`` and ``B = b e_n``, ``b = df/du``.  The gain
minimises ``int (e^T Q e + R v^2) dt`` on that model (Anderson and Moore, *Optimal
Control: Linear Quadratic Methods*, 1990, ch. 2-3):

    A^T P + P A - P B R^-1 B^T P + Q = 0,        K = R^-1 B^T P

(``P`` from ``scipy.linalg.solve_continuous_are``).  Tracking uses the linear model's
feedforward, so that on the linear model ``e' = (A - B K) e`` exactly:

    u = u* + (r^(n) - a^T (r - x*)) / b - K e,      r = [r .. r^(n-1)],  e = x - r.

``V = e^T P e`` is recorded: it is the cost-to-go of the linear design and a Lyapunov
function of ``A - B K``.

**Full-state design** (``design = "full"``, the default on a plant with a full state:
the cart-pole's ``s = [x_c, theta, x_c', theta']``, :mod:`.full_model`).  ``A, B`` are the
whole machine's linearisation at the upright (:func:`design_model`: the domain's exact
Jacobian, what :func:`tspend.linearize` gives for the analytic twin of the nominal
machine), ``K`` from ``control.lqr`` (python-control,
the ``control`` extra), and the feedback acts on every state, so the cart is held too
(the paper's 2-state view leaves the cart free: it drifts 42.8 m in 20 s).  With one
input, a pole angle ``r(t)`` fixes the cart's motion: on the linear model
``theta'' = a_th s + b_th u`` and ``x_c'' = a_x s + b_x u``; eliminating ``u`` gives
``x_c'' = kappa_0 r + (b_x / b_th) r''`` with ``kappa_0 = c - b_x a / b_th``
(``c = dx_c''/dtheta``, ``a = dtheta''/dtheta``).  The feedforward is the steady-state
map of the reference's harmonic model (Francis' regulator equations for an exosystem of
frequency ``omega``, ``r'' = -omega^2 r``): the reference state and input

    s_r = [kappa r, r, kappa r', r'],   kappa = b_x / b_th - kappa_0 / omega^2,
    u_r = (r'' - a_th^T s_r) / b_th,    u = u_r - K (s - s_r)   (angle errors wrapped)

make ``e' = (A - B K) e`` exactly on the linear model for a sine of frequency ``omega``
(the scenario's sine reference gives it; ``reference_omega`` overrides).  For
``omega = 0`` (a constant or unknown reference) the ``1/omega^2`` term is dropped: no
pole angle other than the upright can be held with the cart at rest, so a constant
reference is met only on average (the Nbar of the pole angle is infinite).

Full-state defaults: ``Q = diag(1, 100, 1, 10)`` (the actuated joint's position and
velocity, the pole's angle and rate), ``R = b_th^2``: prices the pole's angular
acceleration the input produces, as the view design prices ``b u``.  On the paper's
machine the poles are ``-4.77, -2.76, -0.77 +/- 0.38j``; the cart swings +/- 1.4 m
around the rail's centre tracking ``(pi/30) sin t``.

Defaults (:class:`LQRSettings`): ``Q = diag(10^n, .., 100, 10)`` weighs each error
derivative ten times less than the one before (``diag(100, 10)`` for n = 2); ``R = 1 /
b^2`` prices the acceleration ``b u`` the input produces rather than ``u`` itself, so
the design does not depend on the input's units (newtons on the cart-pole, where ``b ~
1/41``, or Example 2's unit gain).  On a double integrator these give closed-loop poles
``-2.7 +/- 1.4j``, about three times the references' 1 rad/s.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from tspend.runtime.errors import ScenarioError
from numba import njit

from tspend.controllers.base import (CompiledController, Controller, Observation, diag_width,
    diagnostics)
from tspend.plants.domain import VIEW_MODEL
import tspend.runtime.xp as xp
from tspend.controllers.full_model import wrap_angle
from tspend.runtime.law import array_law
from tspend.runtime.jit import JIT
from tspend.controllers.plant_model import plant_model
from tspend.controllers.settings import KindSettings, setting, settings_for

if TYPE_CHECKING:
    from tspend.plants.base import Plant
    from tspend.config import Scenario
    from tspend.controllers.full_model import FullModel

__all__ = ["LQRSettings", "LQRController", "FullStateLQR", "build", "lqr_gain", "lqr_full_gain"]


#: the designs: on the whole machine's state, or on the paper's view (the tracked output
#: and its derivatives)
DESIGNS = ("full", "view")


@dataclass(frozen=True)
class LQRSettings(KindSettings):
    """``[controllers.lqr]``."""

    #: what ``tspend tune`` searches: only Q/R matters, so R against the default Q
    SEARCH = {"R": (1e-6, 1e12, "log")}

    Q: tuple[tuple[float, ...], ...] | None = setting(
        None, "view design: state weight on e, n x n SPD (default diag(10^n, .., 100, 10))",
        kind="matrix")
    R: float | None = setting(None, "input weight (default: view 1 / b^2, b = df/du at the "
                                    "operating point; full (dtheta''/du)^2)", low=0.0, strict=True)
    design: str | None = setting(None, "full: the whole machine's state; view: the paper's "
                                       "n-state error model (default full on a plant with a "
                                       "full state, else view)", kind="choice", choices=DESIGNS)
    state_weights: tuple[float, ...] | None = setting(
        None, "full design: diagonal of Q on the full state, in the plant's state order "
              "(default 1, 100, 1, 10 for the cart-pole)", kind="list", low=0.0)
    reference_omega: float | None = setting(
        None, "rad/s: frequency of the harmonic model behind the full design's feedforward "
              "(default the scenario's sine reference's omega, else 0)", low=0.0)


def default_Q(n: int) -> np.ndarray:
    return np.diag([10.0 ** (n - i) for i in range(n)])


def lqr_gain(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: float) -> tuple[np.ndarray, np.ndarray]:
    """``(K, P)``: the Riccati solution ``P`` and ``K = R^-1 B^T P`` (1 x n)."""
    from scipy.linalg import solve_continuous_are

    P = solve_continuous_are(A, B, Q, np.array([[R]]))
    return (B.T @ P) / R, P


def lqr_full_gain(A: np.ndarray, B: np.ndarray, Q: np.ndarray,
                  R: float) -> tuple[np.ndarray, np.ndarray]:
    """``(K, P)`` by python-control's ``control.lqr`` (a core dependency)."""
    from tspend.runtime.extras import missing_extra

    problem = missing_extra("control", "controllers.lqr")
    if problem:
        raise ScenarioError(problem)
    import control

    K, P, _ = control.lqr(A, B, Q, np.array([[R]]))
    return np.asarray(K, dtype=float), np.asarray(P, dtype=float)


class ViewLQRLaw(NamedTuple):
    """The view design's numbers, as compiled code reads them (:func:`view_lqr_law`)."""

    K: np.ndarray      # (n,)
    P: np.ndarray      # (n, n)
    a: np.ndarray      # (n,) the last row of A
    b: float
    x_op: np.ndarray   # (n,)
    u_op: float
    e: np.ndarray      # (n,) scratch: the error


@array_law
def view_lqr_law(law: ViewLQRLaw, state, scratch, t: float, full: np.ndarray, x: np.ndarray,
                 ref: np.ndarray, dt: float, diag: np.ndarray) -> tuple:
    """``(u, state)``, ``u = u* + (r^(n) - a^T (r - x*)) / b - K e`` (module docstring),
    diagnostics into ``diag``; the one implementation, for numba and JAX
    (:mod:`tspend.runtime.law`)."""
    e = law.e
    n = e.size
    ar = 0.0
    u_fb = 0.0
    for j in range(n):
        ar += law.a[j] * (ref[j] - law.x_op[j])
        e = xp.put(e, j, x[j] - ref[j])
        u_fb -= law.K[j] * e[j]
    u_ff = law.u_op + (ref[n] - ar) / law.b
    V = 0.0
    for i in range(n):
        for j in range(n):
            V += e[i] * law.P[i, j] * e[j]
    diag = xp.put(diag, 0, u_ff)
    diag = xp.put(diag, 1, u_fb)
    diag = xp.put(diag, 2, V)
    return u_ff + u_fb, state


@njit(**JIT)
def view_lqr_step(law: ViewLQRLaw, state, scratch, t: float, full: np.ndarray, x: np.ndarray,
                  ref: np.ndarray, dt: float, diag: np.ndarray) -> float:
    """:func:`view_lqr_law` behind the compiled controllers' common signature."""
    return view_lqr_law(law, state, scratch, t, full, x, ref, dt, diag)[0]


@dataclass(frozen=True)
class LQRDesign:
    """An LQR design's numbers, made once: the linear model ``(A, B)``, the weights, the
    gain ``K`` (one row) and the cost ``P``."""

    A: np.ndarray
    B: np.ndarray
    Q: np.ndarray
    R: float
    K: np.ndarray
    P: np.ndarray


@dataclass(frozen=True)
class ViewLQRDesign(LQRDesign):
    """The view design (:func:`design_view`) and its law's record."""

    law: ViewLQRLaw


def design_view(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: float, x_op: np.ndarray,
                u_op: float) -> ViewLQRDesign:
    """The view design (module docstring) on the chain ``(A, B)`` at the operating point
    ``(x_op, u_op)``: pure, python-control style."""
    K, P = lqr_gain(A, B, Q, float(R))
    law = ViewLQRLaw(K[0].copy(), np.ascontiguousarray(P), A[-1].copy(), float(B[-1, 0]),
                     np.array(x_op, dtype=float), float(u_op), np.zeros(A.shape[0]))
    return ViewLQRDesign(A, B, Q, float(R), K[0], P, law)


class LQRController(Controller):
    """The ``lqr`` kind (a :class:`~tspend.controllers.base.Controller`)."""

    kind = "lqr"
    Settings = LQRSettings

    @classmethod
    def from_scenario(cls, scenario: "Scenario", machine: "Plant | None" = None) -> Controller:
        return build(scenario, machine)
    needs = (VIEW_MODEL,)
    guarantees = ("local exponential stability at the upright on the linearisation: of the whole "
                  "machine with a full state (exact sine tracking on the linear model), else of "
                  "the view's error")

    def __init__(self, design: "ViewLQRDesign") -> None:
        self.design = design
        self.A, self.B, self.Q, self.R = design.A, design.B, design.Q, design.R
        self.K, self.P, self.law = design.K, design.P, design.law
        self.a, self.b = design.law.a, design.law.b
        self.x_op, self.u_op = design.law.x_op, design.law.u_op
        self.order = design.A.shape[0]
        self.diagnostics = diagnostics(
            ("u_ff", 1, {"panel": "control",
                         "description": "feedforward u* + (r^(n) - a^T (r - x*)) / b"}),
            ("u_fb", 1, {"panel": "control", "description": "feedback -K e"}),
            ("V", 1, {"panel": "lyapunov", "log": True,
                      "description": "cost-to-go e^T P e of the linear design"}))
        self.diag = np.zeros(diag_width(self.diagnostics))

    def closed_loop(self) -> np.ndarray:
        """``A - B K``, Hurwitz by construction."""
        return self.A - self.B @ self.K[None, :]

    def reset(self, rng: np.random.Generator) -> None:
        """Nothing is adapted and nothing is drawn."""

    def step(self, obs: Observation, dt: float) -> float:
        # the compiled law from Python too: one dispatch instead of the law interpreted
        return view_lqr_step(self.law, None, None, obs.t, obs.state, obs.x, obs.ref, dt,
                             self.diag)

    def compiled(self) -> CompiledController:
        """The same law in the compiled loops (:mod:`tspend.loop.fastloop`)."""
        return CompiledController(view_lqr_step, self.law, None, None, view_lqr_law)

    def parameters(self) -> dict[str, np.ndarray]:
        return {}


class FullLQRLaw(NamedTuple):
    """The full-state law's numbers, as compiled code reads them (:func:`full_lqr_law`)."""

    K: np.ndarray          # (N,)
    P: np.ndarray          # (N, N)
    a_pole: np.ndarray     # (N,) the pole's acceleration row of A
    b_pole: float
    kappa: float
    pole: int
    actuated: int
    dof: int
    wraps: np.ndarray      # (N,) bool: angles whose error wraps
    s_r: np.ndarray        # (N,) scratch: the reference state
    e: np.ndarray          # (N,) scratch: the error


@array_law
def full_lqr_law(law: FullLQRLaw, full: np.ndarray, ref: np.ndarray, diag: np.ndarray) -> float:
    """``u = u_r - K (s - s_r)`` (module docstring), diagnostics into ``diag``; the one
    implementation, for numba and JAX (:mod:`tspend.runtime.law`)."""
    s_r, e = law.s_r, law.e
    r, rd, rdd = ref[0], ref[1], ref[2]
    for j in range(s_r.size):
        s_r = xp.put(s_r, j, 0.0)
    s_r = xp.put(s_r, law.pole, r)
    s_r = xp.put(s_r, law.dof + law.pole, rd)
    s_r = xp.put(s_r, law.actuated, law.kappa * r)
    s_r = xp.put(s_r, law.dof + law.actuated, law.kappa * rd)
    acc = 0.0
    for j in range(s_r.size):
        acc += law.a_pole[j] * s_r[j]
    u_ff = (rdd - acc) / law.b_pole
    u_fb = 0.0
    for j in range(e.size):
        d = full[j] - s_r[j]
        e = xp.put(e, j, xp.where(law.wraps[j] & (abs(d) > math.pi), wrap_angle(d), d))
        u_fb -= law.K[j] * e[j]
    V = 0.0
    for i in range(e.size):
        for j in range(e.size):
            V += e[i] * law.P[i, j] * e[j]
    diag = xp.put(diag, 0, u_ff)
    diag = xp.put(diag, 1, u_fb)
    diag = xp.put(diag, 2, V)
    diag = xp.put(diag, 3, s_r[law.actuated])
    return u_ff + u_fb


@array_law
def full_lqr_control(law: FullLQRLaw, state, scratch, t: float, full: np.ndarray,
                     x: np.ndarray, ref: np.ndarray, dt: float, diag: np.ndarray) -> tuple:
    """``(u, state)`` of :func:`full_lqr_law`, in the laws' common signature."""
    return full_lqr_law(law, full, ref, diag), state


@njit(**JIT)
def full_lqr_step(law: FullLQRLaw, state, scratch, t: float, full: np.ndarray, x: np.ndarray,
                  ref: np.ndarray, dt: float, diag: np.ndarray) -> float:
    """:func:`full_lqr_law` behind the compiled controllers' common signature."""
    return full_lqr_law(law, full, ref, diag)


@dataclass(frozen=True)
class FullLQRDesign(LQRDesign):
    """The full-state design (:func:`design_full`), the reference's frequency behind
    kappa, and its law's record."""

    omega: float
    law: FullLQRLaw


def design_full(model: "FullModel", A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: float,
                omega: float) -> FullLQRDesign:
    """The full-state design (module docstring) on the machine's linearisation ``(A, B)``
    at the upright: the gain by python-control, the pole's feedforward row and the
    actuated joint's reference gain kappa.  Pure; ScenarioError when the input does not
    reach the pole."""
    A, B = np.asarray(A, dtype=float), np.asarray(B, dtype=float)
    Q, R = np.asarray(Q, dtype=float), float(R)
    K, P = lqr_full_gain(A, B, Q, R)
    dof, pole, act = model.dof, model.pole, model.actuated
    #: the pole's acceleration row, and the actuated joint's (see the docstring)
    a_pole, b_pole = A[dof + pole].copy(), float(B[dof + pole, 0])
    if b_pole == 0.0:
        raise ScenarioError("controllers.lqr: the input does not reach the pole's "
                            "acceleration at the upright; no feedforward exists")
    b_act = float(B[dof + act, 0])
    kappa0 = float(A[dof + act, pole]) - b_act * float(A[dof + pole, pole]) / b_pole
    omega = float(omega)
    kappa = b_act / b_pole - (kappa0 / omega ** 2 if omega > 0.0 else 0.0)
    N = model.size
    law = FullLQRLaw(K[0].copy(), np.ascontiguousarray(P), a_pole, b_pole, float(kappa), pole,
                     act, dof, np.array(model.angles, dtype=np.bool_), np.zeros(N), np.zeros(N))
    return FullLQRDesign(A, B, Q, R, K[0], P, omega, law)


class FullStateLQR(Controller):
    """The ``lqr`` kind's full-state design (module docstring): ``u = u_r - K (s - s_r)``."""

    kind = "lqr"

    def __init__(self, model: "FullModel", design: "FullLQRDesign", order: int) -> None:
        self.model, self.design, self.order = model, design, order
        self.A, self.B, self.Q, self.R = design.A, design.B, design.Q, design.R
        self.K, self.P, self.law = design.K, design.P, design.law
        self.a_pole, self.b_pole = design.law.a_pole, design.law.b_pole
        self.kappa, self.omega = design.law.kappa, design.omega
        self.diagnostics = diagnostics(
            ("u_ff", 1, {"panel": "control",
                         "description": "feedforward u_r = (r'' - a_th^T s_r) / b_th"}),
            ("u_fb", 1, {"panel": "control", "description": "feedback -K (s - s_r)"}),
            ("V", 1, {"panel": "lyapunov", "log": True,
                      "description": "cost-to-go (s - s_r)^T P (s - s_r) of the linear design"}),
            ("x_ref", 1, {"panel": "state", "unit": "m",
                          "description": "the actuated joint's reference kappa r"}))
        self.diag = np.zeros(diag_width(self.diagnostics))

    def closed_loop(self) -> np.ndarray:
        return self.A - self.B @ self.K[None, :]

    def reference_state(self, ref: np.ndarray) -> tuple[np.ndarray, float]:
        """``(s_r, u_r)`` for the reference row ``[r, r', r'']``."""
        m = self.model
        r, rd, rdd = float(ref[0]), float(ref[1]), float(ref[2])
        s_r = np.zeros(m.size)
        s_r[m.pole], s_r[m.dof + m.pole] = r, rd
        s_r[m.actuated], s_r[m.dof + m.actuated] = self.kappa * r, self.kappa * rd
        return s_r, (rdd - float(self.a_pole @ s_r)) / self.b_pole

    def reset(self, rng: np.random.Generator) -> None:
        """Nothing is adapted and nothing is drawn."""

    def act(self, state: np.ndarray, ref: np.ndarray) -> float:
        """u for the full ``state`` and the pole's reference row ``ref``."""
        return full_lqr_law(self.law, np.asarray(state, dtype=float), ref, self.diag)

    def compiled(self) -> CompiledController:
        """The same law in the compiled loops (:mod:`tspend.loop.fastloop`)."""
        return CompiledController(full_lqr_step, self.law, None, None, full_lqr_control)

    def step(self, obs: Observation, dt: float) -> float:
        # the compiled law from Python too: one dispatch instead of the law interpreted
        return full_lqr_step(self.law, None, None, obs.t, obs.state, obs.x, obs.ref, dt,
                             self.diag)

    def parameters(self) -> dict[str, np.ndarray]:
        return {}


def default_state_weights(model: "FullModel") -> np.ndarray:
    """``diag(Q)``: 1 on the actuated joint's position and velocity, 100 on each pole's
    angle, 10 on its rate; 1 on any other joint."""
    w = np.ones(model.size)
    for pole in model.upright:
        w[pole], w[model.dof + pole] = 100.0, 10.0
    return w


def reference_omega_of(scenario: "Scenario") -> float:
    """The scenario's sine reference's frequency (0 for any other reference)."""
    from tspend.config.signals import Sine

    ref = scenario.reference
    return float(ref.omega) if isinstance(ref, Sine) else 0.0


def design_model(scenario: "Scenario", machine: "Plant") -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` of the full design: the domain's exact Jacobian at the upright
    (``Domain.linearisation``), the function :func:`tspend.linearize` uses on an analytic
    plant, applied to the nominal machine the model-based kinds assume (the cart-pole's
    leaves out the friction a rig adds: its slope at rest is no linear model of it)."""
    from tspend.plants.registry import domain_of

    AB = domain_of(scenario.plant.kind).linearisation(scenario, machine)
    if AB is None:  # pragma: no cover - every full-state domain has one
        raise ScenarioError(f"{scenario.path}: plant '{scenario.plant.kind}' has no full-state "
                            f"linearisation")
    return AB


def unstabilisable(A: np.ndarray, B: np.ndarray, names: tuple[str, ...] = ()) -> str:
    """Why no feedback of the state can stabilise ``x' = A x + B u`` ("" = it can): an
    eigenvalue with Re >= 0 whose mode u cannot move (the Popov-Belevitch-Hautus test,
    ``rank [A - lambda I, B] < n``, by the smallest singular value)."""
    n = A.shape[0]
    scale = max(1.0, float(np.abs(A).max()), float(np.abs(B).max()))
    for lam in np.linalg.eigvals(A):
        if lam.real < -1e-9 * scale:
            continue
        sv = np.linalg.svd(np.hstack([A - lam * np.eye(n), B]), compute_uv=False)
        if sv[-1] <= 1e-9 * scale:
            _, _, vh = np.linalg.svd((A - lam * np.eye(n)).conj().T)
            left = np.abs(vh[-1])
            part = [names[i] for i in np.argsort(-left)[:3] if left[i] > 1e-6] if names else []
            return (f"the machine cannot be stabilised from u at the upright: its mode with "
                    f"eigenvalue {lam.real:.4g}{lam.imag:+.4g}j (unstable) is uncontrollable"
                    + (f" (it involves {', '.join(part)})" if part else ""))
    return ""


def build_full(scenario: "Scenario", s: LQRSettings, machine: "Plant") -> FullStateLQR:
    from tspend.controllers.full_model import full_model

    model = full_model(scenario, machine)
    where = f"{scenario.path}: controllers.lqr"
    if s.state_weights is not None:
        if len(s.state_weights) != model.size:
            raise ScenarioError(f"{where}.state_weights: needs {model.size} entries "
                                f"({', '.join(model.state_names)}), got {len(s.state_weights)}")
        w = np.asarray(s.state_weights, dtype=float)
    else:
        w = default_state_weights(model)
    A, B = design_model(scenario, machine)
    why = unstabilisable(A, B, model.state_names)
    if why:
        raise ScenarioError(f"{where}: {why}")
    b_pole = float(B[model.dof + model.pole, 0])
    R = s.R if s.R is not None else b_pole ** 2
    omega = s.reference_omega if s.reference_omega is not None else reference_omega_of(scenario)
    try:
        design = design_full(model, A, B, np.diag(w), R, omega)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise ScenarioError(f"{where}.state_weights: no stabilising LQR gain ({exc})") from None
    return FullStateLQR(model, design, order=len(scenario.plant.x0))


def build(scenario: "Scenario", machine: "Plant | None" = None) -> "LQRController | FullStateLQR":
    from tspend.controllers.full_model import has_full_state

    s: LQRSettings = settings_for(scenario, LQRSettings)
    design = s.design or ("full" if has_full_state(scenario) else "view")
    if design == "full":
        if not has_full_state(scenario):
            raise ScenarioError(f"{scenario.path}: controllers.lqr.design: 'full' needs a "
                                f"plant with a full state (the cart-pole, the Furuta pendulum); "
                                f"plant '{scenario.plant.kind}' has only the view: use 'view'")
        return build_full(scenario, s, machine)
    model = plant_model(scenario, machine)
    A, B = model.state_space()
    b = float(B[-1, 0])
    if b == 0.0:
        raise ScenarioError(f"{scenario.path}: controllers.lqr: df/du = 0 at the operating "
                            f"point of plant '{model.name}'; LQR cannot act")
    Q = np.asarray(s.Q) if s.Q is not None else default_Q(model.order)
    R = s.R if s.R is not None else 1.0 / b**2
    return LQRController(design_view(A, B, Q, R, np.asarray(model.x_op), model.u_op))
