"""``wang_indirect``: L.-X. Wang's indirect adaptive fuzzy controller, the classic baseline.

Source: L.-X. Wang, "Stable adaptive fuzzy control of nonlinear systems", IEEE Trans.
Fuzzy Systems 1(2), 146-155, 1993 (the indirect scheme with its supervisory control),
also chapter "indirect adaptive fuzzy control" of L.-X. Wang, *Adaptive Fuzzy Systems
and Control: Design and Stability Analysis*, Prentice Hall, 1994.  Wang writes the error
as ``y_m - y``; tspend's ``e = x - r`` is its negative, so the laws below carry the
opposite sign to the printed ones and are otherwise the same.

The plant is taken as affine, ``x_n' = f(x) + g(x) u + d``; ``f`` and ``g`` are unknown
and approximated by fuzzy systems on a fixed grid of Gaussian sets
(:mod:`.gaussian_basis`): ``f_hat = theta_f^T xi(x)``, ``g_hat = theta_g^T xi(x)``.

* Certainty-equivalence control, then the optional supervisory term:

      u_c = (-f_hat + r^(n) - lambda^T e) / g_hat,       e = x - r,
      u_s = -I* sgn(e_Delta) (|f_hat| + f^U + |g_hat u_c| + g^U |u_c|) / g_L,
      u   = u_c + u_s,

  with ``I* = 1`` when ``V_e = 1/2 e^T P e > V_bar`` (else 0) and the designer's bounds
  ``|f| <= f^U``, ``0 < g_L <= g <= g^U``.
* Error dynamics: ``e' = Lambda e + b [(f - f_hat) + (g - g_hat) u_c + g u_s + d]``.
  ``P`` solves ``Lambda^T P + P Lambda = -Q`` (the Gamma of Lemma 1,
  :func:`tspend.controllers.paper.control_law.lyapunov_gamma`) and ``e_Delta = e^T P b``.
* With ``V = 1/2 e^T P e + |theta_f* - theta_f|^2 / (2 gamma_f)
  + |theta_g* - theta_g|^2 / (2 gamma_g)``, the laws

      theta_f' = gamma_f e_Delta xi(x),      theta_g' = gamma_g e_Delta xi(x) u_c

  cancel the parameter terms of ``V'``, leaving ``V' = -1/2 e^T Q e + e_Delta (g u_s +
  w + d)`` with ``w`` the best approximation error; the supervisory term makes the
  bracket non-positive whenever ``V_e > V_bar``.
* Projection (Wang's, in discrete form): every ``theta_g,l`` is kept ``>= g_min`` (so
  ``g_hat >= g_min`` and ``u_c`` is defined), and optionally ``|theta_f| <= M_f``,
  ``|theta_g| <= M_g`` by scaling back onto the ball.

The laws are integrated by forward Euler at the sample time, like the paper controller's.

Defaults (:class:`WangSettings`) reuse what the scenario already says about the plant:
``lambda`` and ``Q`` are the scenario's ``[controller]`` ones (same target dynamics and
Lyapunov matrix as the paper controller); the grid is the scenario's state sets
(``[controller.sets] states``, 5 x 5 = 25 rules in the paper's examples); ``g_min`` is
the scenario's ``b_min`` (Assumption 5's bound, chosen per example from df/du);
``theta_g`` starts at ``b0 = df/du`` at the operating point and ``theta_f`` at 0 (Wang
starts from whatever linguistic knowledge there is; this is the linearisation's);
``gamma_f = 50`` and ``gamma_g = gamma_f b0^2``, scaled by ``b0^2`` so that ``f_hat`` and
``g_hat u_c`` adapt at the same relative rate whatever the input's units.  ``gamma_f``
came from a sweep over 10, 50 and 300 on the paper cases: 50 cuts the error 2-6x
against 10 on every case with ``u`` still smooth; 300 helps Example 1 and the
cart-pole further (their scenarios set it) but makes Duffing's ``u`` chatter (TV 2e3/s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numba import njit

from tspend.config import SetSpec
from tspend.controllers.paper.control_law import is_hurwitz, lyapunov_gamma
from tspend.runtime.errors import ScenarioError
from tspend.controllers.base import (CompiledController, Controller, Observation, diag_width,
                                     diagnostics)
from tspend.plants.domain import VIEW_MODEL
import tspend.runtime.xp as xp
from tspend.runtime.law import array_law
from tspend.controllers.gaussian_basis import GaussianGrid, GaussianTable, basis_into, gaussian_grid
from tspend.runtime.jit import JIT
from tspend.controllers.plant_model import plant_model
from tspend.controllers.settings import POLE_CAP, KindSettings, finite_or, setting, settings_for

if TYPE_CHECKING:
    from tspend.plants.base import Plant
    from tspend.config import Scenario


@dataclass(frozen=True)
class WangSettings(KindSettings):
    """``[controllers.wang_indirect]``."""

    #: what ``tspend tune`` searches: lambda as (s + p)^n (Hurwitz), the f rate
    SEARCH = {"lambda": (0.2, POLE_CAP, "log", "poles"), "gamma_f": (1.0, 1e4, "log")}

    lam: tuple[float, ...] | None = setting(
        None, "lambda_1 .. lambda_n (default: the scenario's [controller] lambda)",
        kind="vector", length="n", name="lambda")
    Q: tuple[tuple[float, ...], ...] | None = setting(
        None, "Q of Lambda^T P + P Lambda = -Q (default: the scenario's [controller] Q)",
        kind="matrix")
    sets: tuple[SetSpec, ...] | None = setting(
        None, "Gaussian grid, one {terms, lo, hi} per state (default: [controller.sets] states)",
        kind="sets")
    gamma_f: float = setting(50.0, "adaptation rate of theta_f", low=0.0, strict=True)
    gamma_g: float | None = setting(None, "adaptation rate of theta_g (default gamma_f b0^2)",
                                    low=0.0)
    g_init: float | None = setting(None, "initial theta_g (default b0 = df/du at the "
                                         "operating point)", low=0.0, strict=True)
    g_min: float | None = setting(None, "projection bound theta_g >= g_min (default: the "
                                        "scenario's b_min)", low=0.0, strict=True)
    f_radius: float = setting(0.0, "projection |theta_f| <= f_radius (0: off)", low=0.0)
    g_radius: float = setting(0.0, "projection |theta_g| <= g_radius (0: off)", low=0.0)
    supervisory: bool = setting(False, "add Wang's supervisory control u_s", kind="bool")
    f_upper: float = setting(0.0, "f^U: bound on |f| for u_s", low=0.0)
    g_upper: float = setting(0.0, "g^U: upper bound on g for u_s", low=0.0)
    g_lower: float | None = setting(None, "g_L: lower bound on g for u_s (default g_min)",
                                    low=0.0, strict=True)
    V_bar: float = setting(0.0, "u_s acts while 1/2 e^T P e > V_bar", low=0.0)

    def check(self, n: int):
        if self.lam is not None and not is_hurwitz(np.asarray(self.lam)):
            return "lambda", f"s^n + lambda_n s^(n-1) + .. + lambda_1 must be Hurwitz; {list(self.lam)} is not"
        if self.g_init is not None and self.g_min is not None and self.g_init < self.g_min:
            return "g_init", f"must be >= g_min ({self.g_min:g}), got {self.g_init:g}"
        return None


@dataclass(frozen=True)
class Supervisor:
    """Wang's supervisory control: bounds f^U, g^U, g_L and the threshold V_bar."""

    f_upper: float
    g_upper: float
    g_lower: float
    V_bar: float


class WangLaw(NamedTuple):
    """The scheme's fixed numbers, as compiled code reads them (:func:`wang_law`)."""

    grid: GaussianTable
    lam: np.ndarray        # (n,)
    P: np.ndarray          # (n, n)
    gamma_f: float
    gamma_g: float
    g_min: float
    f_radius: float        # 0: off
    g_radius: float        # 0: off
    supervised: bool
    f_upper: float
    g_upper: float
    g_lower: float
    V_bar: float


class WangState(NamedTuple):
    """What adapts: the consequents of ``f_hat`` and ``g_hat``."""

    theta_f: np.ndarray    # (rules,)
    theta_g: np.ndarray    # (rules,)


class WangScratch(NamedTuple):
    e: np.ndarray          # (n,)
    mu: np.ndarray         # (sets,)
    xi: np.ndarray         # (rules,)


@array_law
def supervisory(law: WangLaw, e_delta: float, V: float, f_hat: float, g_hat: float,
                u_c: float) -> float:
    """Wang's ``u_s`` (module docstring): 0 when off, when ``V_e <= V_bar`` or ``e_Delta = 0``."""
    if not law.supervised:
        return 0.0
    size = (abs(f_hat) + law.f_upper + abs(g_hat * u_c) + law.g_upper * abs(u_c)) / law.g_lower
    return xp.where((V <= law.V_bar) | (e_delta == 0.0), 0.0, -math.copysign(size, e_delta))


@array_law
def _scale_onto_ball(theta: np.ndarray, radius: float) -> tuple:
    norm = 0.0
    for l in range(theta.size):
        norm += theta[l] * theta[l]
    norm = math.sqrt(norm)
    scale = radius / norm
    for l in range(theta.size):
        theta = xp.put(theta, l, xp.where(norm > radius, theta[l] * scale, theta[l]))
    return (theta,)


@array_law
def law_coefficients(law: WangLaw, e_delta: float, u_c: float) -> tuple[float, float]:
    """The laws are ``theta_f' = a_f xi(x)`` and ``theta_g' = a_g xi(x)``: ``(a_f, a_g)``
    with ``a_f = gamma_f e_Delta``, ``a_g = gamma_g e_Delta u_c``."""
    return law.gamma_f * e_delta, law.gamma_g * e_delta * u_c


@array_law
def _at_least(theta: np.ndarray, low: float, when: bool) -> tuple:
    """``theta_l = max(theta_l, low)`` where ``when``; returns ``(theta,)``."""
    for l in range(theta.size):
        theta = xp.put(theta, l, xp.where(when & (low > theta[l]), low, theta[l]))
    return (theta,)


@array_law
def project(law: WangLaw, state: WangState, when: bool = True) -> WangState:
    """Wang's projection, where ``when``: ``theta_g >= g_min``, then the balls
    ``|theta| <= radius`` (those that are on), then the lower bound again (the ball must
    not undo it); the state after it."""
    theta_f = state.theta_f
    theta_g, = _at_least(state.theta_g, law.g_min, when)
    if law.f_radius > 0.0:
        theta_f, = _scale_onto_ball(theta_f, law.f_radius)
    if law.g_radius > 0.0:
        theta_g, = _scale_onto_ball(theta_g, law.g_radius)
        theta_g, = _at_least(theta_g, law.g_min, when)
    return WangState(theta_f, theta_g)


@array_law
def wang_law(law: WangLaw, state: WangState, scratch: WangScratch, t: float,
             full: np.ndarray, x: np.ndarray, ref: np.ndarray, dt: float,
             diag: np.ndarray) -> tuple:
    """``(u, state)``: one sample of the scheme (module docstring), ``u = u_c + u_s``,
    diagnostics into ``diag``, the laws integrated by forward Euler over ``dt`` and
    projected.  The one implementation, for numba and JAX (:mod:`tspend.runtime.law`)."""
    e = scratch.e
    theta_f, theta_g = state.theta_f, state.theta_g
    n = e.size
    for j in range(n):
        e = xp.put(e, j, x[j] - ref[j])
    e_delta = 0.0    # e^T P b = P[n-1] . e
    lam_e = 0.0
    V = 0.0
    for i in range(n):
        e_delta += law.P[n - 1, i] * e[i]
        lam_e += law.lam[i] * e[i]
        for j in range(n):
            V += e[i] * law.P[i, j] * e[j]
    V *= 0.5
    xi, = basis_into(law.grid, x, scratch.mu, scratch.xi)
    f_hat = 0.0
    g_hat = 0.0
    norm_f = 0.0
    min_g = math.inf
    for l in range(xi.size):
        f_hat += theta_f[l] * xi[l]
        g_hat += theta_g[l] * xi[l]
        norm_f += theta_f[l] * theta_f[l]
        min_g = xp.where(theta_g[l] < min_g, theta_g[l], min_g)
    u_c = (-f_hat + ref[n] - lam_e) / g_hat
    u_s = supervisory(law, e_delta, V, f_hat, g_hat, u_c)
    diag = xp.put(diag, 0, u_c)
    diag = xp.put(diag, 1, u_s)
    diag = xp.put(diag, 2, f_hat)
    diag = xp.put(diag, 3, g_hat)
    diag = xp.put(diag, 4, e_delta)
    diag = xp.put(diag, 5, V)
    diag = xp.put(diag, 6, math.sqrt(norm_f))
    diag = xp.put(diag, 7, min_g)
    a_f, a_g = law_coefficients(law, e_delta, u_c)
    step_f, step_g = dt * a_f, dt * a_g
    for l in range(xi.size):
        theta_f = xp.add(theta_f, l, step_f * xi[l])
        theta_g = xp.add(theta_g, l, step_g * xi[l])
    # xi > 0: only a_g < 0 (or a ball) can leave the set
    when = (a_g < 0.0) | (law.f_radius > 0.0) | (law.g_radius > 0.0)
    return u_c + u_s, project(law, WangState(theta_f, theta_g), when)


@njit(**JIT)
def wang_step(law: WangLaw, state: WangState, scratch: WangScratch, t: float,
              full: np.ndarray, x: np.ndarray, ref: np.ndarray, dt: float,
              diag: np.ndarray) -> float:
    """:func:`wang_law` behind the compiled controllers' common signature."""
    return wang_law(law, state, scratch, t, full, x, ref, dt, diag)[0]


class WangIndirectController(Controller):
    """The ``wang_indirect`` kind (a :class:`~tspend.controllers.base.Controller`)."""

    kind = "wang_indirect"
    Settings = WangSettings

    @classmethod
    def from_scenario(cls, scenario: "Scenario", machine: "Plant | None" = None) -> Controller:
        return build(scenario, machine)
    needs = (VIEW_MODEL,)
    guarantees = ("bounded tracking error (Lyapunov, with the supervisor) under the fuzzy "
                  "approximation's assumptions")

    def __init__(self, grid: GaussianGrid, lam: np.ndarray, Q: np.ndarray, P: np.ndarray,
                 gamma_f: float, gamma_g: float, g_init: float, g_min: float,
                 f_radius: float = 0.0, g_radius: float = 0.0,
                 supervisor: Supervisor | None = None) -> None:
        """Stores the design :func:`build` made (``P`` solves the Lyapunov equation of
        ``lam`` and ``Q``)."""
        self.grid = grid
        self.lam = np.asarray(lam, dtype=float)
        self.order = n = self.lam.size
        self.Q, self.P = np.asarray(Q, dtype=float), np.asarray(P, dtype=float)
        self.gamma_f, self.gamma_g = float(gamma_f), float(gamma_g)
        self.g_init, self.g_min = float(g_init), float(g_min)
        self.f_radius, self.g_radius = float(f_radius), float(g_radius)
        self.supervisor = supervisor
        h = grid.rules
        self.theta_f = np.zeros(h)
        self.theta_g = np.full(h, self.g_init)
        sv = supervisor or Supervisor(0.0, 0.0, 1.0, 0.0)
        self.law = WangLaw(grid.table(), self.lam.copy(), np.ascontiguousarray(self.P),
                           self.gamma_f, self.gamma_g, self.g_min, self.f_radius,
                           self.g_radius, supervisor is not None, float(sv.f_upper),
                           float(sv.g_upper), float(sv.g_lower), float(sv.V_bar))
        self.state = WangState(self.theta_f, self.theta_g)
        self.scratch = WangScratch(np.zeros(n), np.zeros(grid.flat_centres.size), np.zeros(h))
        self.diagnostics = diagnostics(
            ("u_c", 1, {"panel": "control", "description": "certainty-equivalence control"}),
            ("u_s", 1, {"panel": "control", "chattering": True,
                        "description": "supervisory control (0 when off or V_e <= V_bar)"}),
            ("f_hat", 1, {"panel": "estimates", "description": "theta_f^T xi(x)"}),
            ("g_hat", 1, {"panel": "estimates", "description": "theta_g^T xi(x) (>= g_min)"}),
            ("e_delta", 1, {"panel": "error", "description": "e^T P b"}),
            ("V", 1, {"panel": "lyapunov", "log": True, "description": "V_e = 1/2 e^T P e"}),
            ("norm_theta_f", 1, {"panel": "norms", "log": True, "description": "|theta_f|"}),
            ("min_theta_g", 1, {"panel": "norms",
                                "description": "min_l theta_g,l (>= g_min under projection)"}))
        self.diag = np.zeros(diag_width(self.diagnostics))

    def reset(self, rng: np.random.Generator) -> None:
        """theta_f = 0, theta_g = g_init: a deterministic start (nothing is drawn)."""
        self.theta_f[:] = 0.0
        self.theta_g[:] = self.g_init

    def rates(self, e_delta: float, xi: np.ndarray, u_c: float) -> tuple[np.ndarray, np.ndarray]:
        """``(theta_f', theta_g')`` before projection."""
        a_f, a_g = law_coefficients(self.law, e_delta, u_c)
        return a_f * xi, a_g * xi

    def step(self, obs: Observation, dt: float) -> float:
        # the compiled law from Python too (interpreted, its loops cost ~15x)
        return wang_step(self.law, self.state, self.scratch, obs.t, obs.state, obs.x, obs.ref,
                         dt, self.diag)

    def compiled(self) -> CompiledController:
        """The same scheme in the compiled loops (:mod:`tspend.loop.fastloop`); adapting
        there adapts ``theta_f``, ``theta_g`` here."""
        return CompiledController(wang_step, self.law, self.state, self.scratch, wang_law)

    def parameters(self) -> dict[str, np.ndarray]:
        return {"theta_f": self.theta_f.copy(), "theta_g": self.theta_g.copy()}


def build(scenario: "Scenario", machine: "Plant | None" = None) -> WangIndirectController:
    s: WangSettings = settings_for(scenario, WangSettings)
    cfg = scenario.controller
    model = plant_model(scenario, machine)
    b0 = model.linearisation()[1]
    if b0 <= 0.0:
        raise ScenarioError(f"{scenario.path}: controllers.wang_indirect: g_hat is kept > 0, "
                            f"but df/du = {b0:g} at the operating point of '{model.name}'")
    lam = np.asarray(s.lam if s.lam is not None else cfg.lam)
    Q = np.asarray(s.Q if s.Q is not None else cfg.Q)
    grid = gaussian_grid(s.sets if s.sets is not None else cfg.state_sets)
    g_min = finite_or(s.g_min, cfg.b_min)
    g_init = max(finite_or(s.g_init, b0), g_min)
    supervisor = None
    if s.supervisory:
        supervisor = Supervisor(s.f_upper, s.g_upper, finite_or(s.g_lower, g_min), s.V_bar)
    return WangIndirectController(
        grid, lam, Q, lyapunov_gamma(np.asarray(lam, dtype=float), np.asarray(Q, dtype=float)),
        s.gamma_f, finite_or(s.gamma_g, s.gamma_f * b0**2), g_init, g_min,
        s.f_radius, s.g_radius, supervisor)
