"""``feedback_linearization``: the oracle, which knows the true plant.

It solves, every sample, for the ``u`` that gives the plant the acceleration of the
target error dynamics (18) (Isidori, *Nonlinear Control Systems*, 3rd ed., 1995, ch. 4;
Slotine and Li, *Applied Nonlinear Control*, 1991, section 6.1):

    f(t, x, u) = v,     v = r^(n) - lambda^T e,     e = x - r,

with ``f`` the plant's own equations (:mod:`.plant_model`, ``d_d = 0``: the oracle knows
the plant, not the disturbance).  Then ``e' = Lambda e + b_e d_d``: without a
disturbance the error decays as ``s^n + lambda_n s^(n-1) + .. + lambda_1`` says, up to
what holding ``u`` over a sample costs.  No adaptive controller should beat it there;
with the disturbance it shows what model knowledge alone buys.

* ``f`` affine in ``u`` (Duffing, the cart-pole): the closed form
  ``u = (v - f(t, x, 0)) / (f(t, x, 1) - f(t, x, 0))``, exact for an affine ``f``.
* otherwise (Example 1, the third-order plant): Newton's method from the previous
  sample's ``u``, ``u <- u - (f(u) - v) / (df/du)(u)``, with the step halved while the
  residual does not shrink (or ``e^u`` overflows), until ``|f - v| <= tol (1 + |v|)``.
  Example 1's ``u + e^u - 1`` is increasing and convex, so the solution is unique.

The plant's time enters through Duffing's forcing ``12 cos t``: the controller keeps its
own clock, ``t = k dt`` at its k-th sample, which is the runner's sample time.

Defaults (:class:`FeedbackLinearizationSettings`): ``lambda`` is the scenario's
``[controller] lambda``, so the oracle aims at the same error dynamics (18) as the
paper's controller and the comparison is like for like.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numba import njit
from numba.extending import register_jitable

from tspend.controllers.paper.control_law import is_hurwitz
from tspend.controllers.base import (CompiledController, Controller, Observation, diag_width,
                                     diagnostics)
from tspend.plants.domain import VIEW_MODEL
from tspend.controllers.plant_model import PlantModel, plant_model
from tspend.plants.domain import central_df_du, view_accel
from tspend.runtime.jit import JIT
import tspend.runtime.xp as xp
from tspend.runtime.law import array_law, mark_law
from tspend.controllers.settings import POLE_CAP, KindSettings, setting, settings_for

if TYPE_CHECKING:
    from tspend.plants.base import Plant
    from tspend.config import Scenario


@dataclass(frozen=True)
class FeedbackLinearizationSettings(KindSettings):
    """``[controllers.feedback_linearization]``."""

    #: what ``tspend tune`` searches: lambda as (s + p)^n, so it stays Hurwitz
    SEARCH = {"lambda": (0.2, POLE_CAP, "log", "poles")}

    lam: tuple[float, ...] | None = setting(
        None, "lambda_1 .. lambda_n of the target error dynamics (default: the scenario's "
              "[controller] lambda)", kind="vector", length="n", name="lambda")
    tol: float = setting(1e-12, "Newton stops at |f - v| <= tol (1 + |v|)", low=0.0,
                         strict=True)
    max_iter: int = setting(50, "Newton iterations per sample at most", kind="integer", low=1)

    def check(self, n: int):
        if self.lam is not None and not is_hurwitz(np.asarray(self.lam)):
            return "lambda", f"s^n + lambda_n s^(n-1) + .. + lambda_1 must be Hurwitz; {list(self.lam)} is not"
        return None


class NewtonFailed(ArithmeticError):
    """No u found with f(x, u) = v (the runner stops the run as diverged)."""


@register_jitable
def _f_or_inf(model: Any, t: float, x: np.ndarray, u: float) -> float:
    try:
        return view_accel(model, t, x, u, 0.0)
    except Exception:  # e^u overflows in Python's math; compiled code gives inf itself
        return math.inf


@mark_law
@register_jitable
def newton_u(model: Any, affine: bool, t: float, x: np.ndarray, v: float, u0: float,
             tol: float, max_iter: int) -> tuple[float, int, float, bool]:
    """``(u, iterations, residual, found)`` with ``f(t, x, u) = v`` (module docstring);
    ``model`` is a :class:`~tspend.plants.domain.PlantModel` or its compiled view model.
    The one implementation: plain Python in the generic loop, compiled in the compiled
    ones."""
    if affine:
        f0 = view_accel(model, t, x, 0.0, 0.0)
        u = (v - f0) / (view_accel(model, t, x, 1.0, 0.0) - f0)
        return u, 0, view_accel(model, t, x, u, 0.0) - v, True
    u = u0
    res = view_accel(model, t, x, u, 0.0) - v
    scale = tol * (1.0 + abs(v))
    for it in range(1, max_iter + 1):
        if abs(res) <= scale:
            return u, it - 1, res, True
        slope = central_df_du(model, t, x, u)
        if slope == 0.0 or not math.isfinite(slope):
            break
        step = res / slope
        shrunk = False
        trial = res
        for _ in range(60):  # backtracking: halve until the residual shrinks
            trial = _f_or_inf(model, t, x, u - step) - v
            if abs(trial) < abs(res):
                shrunk = True
                break
            step *= 0.5
        if not shrunk:
            break
        u, res = u - step, trial
    return u, max_iter, res, abs(res) <= scale


def solve_for_u(model: PlantModel, t: float, x: np.ndarray, v: float, u0: float,
                tol: float, max_iter: int) -> tuple[float, int, float]:
    """``(u, iterations, residual)`` with ``f(t, x, u) = v`` (:func:`newton_u`); raises
    :class:`NewtonFailed` when there is none."""
    u, its, res, found = newton_u(model, model.affine_in_u, t, x, v, u0, tol, max_iter)
    if not found:
        raise NewtonFailed(f"feedback_linearization: no u with f(x, u) = {v:.6g} at x = {x} "
                           f"(residual {res:.3g})")
    return u, its, res


class OracleLaw(NamedTuple):
    """The oracle's numbers, as compiled code reads them (:func:`oracle_law`)."""

    model: Any             # the compiled view model (PlantModel.compiled), or the PlantModel
    affine: bool
    lam: np.ndarray        # (n,)
    tol: float
    max_iter: int


@array_law
def oracle_law(law: OracleLaw, state: np.ndarray, scratch, t: float, full: np.ndarray,
               x: np.ndarray, ref: np.ndarray, dt: float, diag: np.ndarray) -> tuple:
    """``(u, state)`` of one sample (module docstring); ``state = [k, u_prev]``: the
    controller's own clock (``t = k dt``) and Newton's starting point.  The one
    implementation, for numba and JAX (:mod:`tspend.runtime.law`; JAX traces the closed
    form of an ``affine`` model only: Newton's loop branches on data)."""
    n = law.lam.size
    t_own = state[0] * dt
    state = xp.add(state, 0, 1.0)
    lam_e = 0.0
    for j in range(n):
        lam_e += law.lam[j] * (x[j] - ref[j])
    v = ref[n] - lam_e
    u, its, res, found = newton_u(law.model, law.affine, t_own, x, v, state[1], law.tol,
                                  law.max_iter)
    u = xp.where(found, u, math.nan)
    diag = xp.put(diag, 0, v)
    diag = xp.put(diag, 2, xp.where(found, its, law.max_iter))
    diag = xp.put(diag, 3, xp.where(found, res, math.nan))
    finite = math.isfinite(u)
    diag = xp.put(diag, 1, xp.where(finite, central_df_du(law.model, t_own, x, u), math.nan))
    state = xp.put(state, 1, xp.where(finite, u, state[1]))
    return u, state


@njit(**JIT)
def oracle_step(law: OracleLaw, state: np.ndarray, scratch, t: float, full: np.ndarray,
                x: np.ndarray, ref: np.ndarray, dt: float, diag: np.ndarray) -> float:
    """:func:`oracle_law` behind the compiled controllers' common signature."""
    return oracle_law(law, state, scratch, t, full, x, ref, dt, diag)[0]


class FeedbackLinearizationController(Controller):
    """The ``feedback_linearization`` kind (a :class:`~tspend.controllers.base.Controller`)."""

    kind = "feedback_linearization"
    Settings = FeedbackLinearizationSettings

    @classmethod
    def from_scenario(cls, scenario: "Scenario", machine: "Plant | None" = None) -> Controller:
        return build(scenario, machine)
    needs = (VIEW_MODEL,)
    guarantees = ("exact linear error dynamics where the view's model is exact and "
                  "df/du != 0 (the oracle)")

    def __init__(self, model: PlantModel, lam: np.ndarray, tol: float = 1e-12,
                 max_iter: int = 50) -> None:
        self.model = model
        self.order = model.order
        self.lam = np.asarray(lam, dtype=float)
        self.tol, self.max_iter = tol, max_iter
        #: [k, u_prev]: the sample count (the clock) and Newton's starting point
        self.state = np.array([0.0, model.u_op])
        view = model.compiled if model.compiled is not None else model
        self.law = OracleLaw(view, bool(model.affine_in_u), self.lam.copy(), float(tol),
                             int(max_iter))
        self.diagnostics = diagnostics(
            ("v", 1, {"panel": "control", "description": "commanded x_n' = r^(n) - lambda^T e"}),
            ("df_du", 1, {"panel": "model", "description": "true df/du at the sample"}),
            ("newton_iterations", 1, {"panel": "model",
                                      "description": "Newton iterations (0: closed form)"}),
            ("residual", 1, {"panel": "model", "description": "f(t, x, u) - v"}))
        self.diag = np.zeros(diag_width(self.diagnostics))

    @property
    def k(self) -> int:
        """Samples taken since the reset."""
        return int(self.state[0])

    @property
    def u_prev(self) -> float:
        return float(self.state[1])

    def reset(self, rng: np.random.Generator) -> None:
        """Clock and Newton's starting point back to the start; nothing is drawn."""
        self.state[0] = 0.0
        self.state[1] = self.model.u_op

    def step(self, obs: Observation, dt: float) -> float:
        if self.model.compiled is not None:   # the compiled law from Python too
            return oracle_step(self.law, self.state, None, obs.t, obs.state, obs.x, obs.ref,
                               dt, self.diag)
        return oracle_law.py_func(self.law, self.state, None, obs.t, obs.state, obs.x, obs.ref,
                                  dt, self.diag)[0]

    def compiled(self) -> CompiledController | None:
        """The same law in the compiled loops (:mod:`tspend.loop.fastloop`), when the
        plant's domain offers its model to compiled code (``PlantModel.compiled``)."""
        if self.model.compiled is None:
            return None
        # JAX traces the closed form only (Newton's loop branches on data)
        return CompiledController(oracle_step, self.law, self.state, None,
                                  oracle_law if self.law.affine else None)

    def parameters(self) -> dict[str, np.ndarray]:
        return {}


def build(scenario: "Scenario", machine: "Plant | None" = None) -> FeedbackLinearizationController:
    s: FeedbackLinearizationSettings = settings_for(scenario, FeedbackLinearizationSettings)
    lam = np.asarray(s.lam if s.lam is not None else scenario.controller.lam)
    return FeedbackLinearizationController(plant_model(scenario, machine), lam, s.tol, s.max_iter)
