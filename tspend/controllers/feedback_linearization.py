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
from typing import TYPE_CHECKING

import numpy as np

from tspend.controllers.paper.control_law import is_hurwitz
from tspend.controllers.base import Controller, Observation, diag_width, diagnostics
from tspend.plants.domain import VIEW_MODEL
from tspend.controllers.plant_model import PlantModel, plant_model
from tspend.controllers.settings import KindSettings, setting, settings_for

if TYPE_CHECKING:
    from tspend.config import Scenario


@dataclass(frozen=True)
class FeedbackLinearizationSettings(KindSettings):
    """``[controllers.feedback_linearization]``."""

    #: what ``tspend tune`` searches: lambda as (s + p)^n, so it stays Hurwitz
    SEARCH = {"lambda": (0.2, 50.0, "log", "poles")}

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


def solve_for_u(model: PlantModel, t: float, x: np.ndarray, v: float, u0: float,
                tol: float, max_iter: int) -> tuple[float, int, float]:
    """``(u, iterations, residual)`` with ``f(t, x, u) = v``."""
    if model.affine_in_u:
        f0 = model.f(t, x, 0.0)
        u = (v - f0) / (model.f(t, x, 1.0) - f0)
        return u, 0, model.f(t, x, u) - v
    u = u0
    res = model.f(t, x, u) - v
    scale = tol * (1.0 + abs(v))
    for it in range(1, max_iter + 1):
        if abs(res) <= scale:
            return u, it - 1, res
        slope = model.df_du(t, x, u)
        if slope == 0.0 or not math.isfinite(slope):
            break
        step = res / slope
        for _ in range(60):  # backtracking: halve until the residual shrinks
            try:
                trial = model.f(t, x, u - step) - v
            except OverflowError:
                trial = math.inf
            if abs(trial) < abs(res):
                break
            step *= 0.5
        else:
            break
        u, res = u - step, trial
    if abs(res) <= scale:
        return u, max_iter, res
    raise NewtonFailed(f"feedback_linearization: no u with f(x, u) = {v:.6g} at x = {x} "
                       f"(residual {res:.3g})")


class FeedbackLinearizationController(Controller):
    """The ``feedback_linearization`` kind (a :class:`~tspend.controllers.base.Controller`)."""

    kind = "feedback_linearization"
    needs = (VIEW_MODEL,)
    guarantees = ("exact linear error dynamics where the view's model is exact and "
                  "df/du != 0 (the oracle)")

    def __init__(self, model: PlantModel, lam: np.ndarray, tol: float = 1e-12,
                 max_iter: int = 50) -> None:
        self.model = model
        self.order = model.order
        self.lam = np.asarray(lam, dtype=float)
        self.tol, self.max_iter = tol, max_iter
        self.k = 0
        self.u_prev = model.u_op
        self.diagnostics = diagnostics(
            ("v", 1, {"panel": "control", "description": "commanded x_n' = r^(n) - lambda^T e"}),
            ("df_du", 1, {"panel": "model", "description": "true df/du at the sample"}),
            ("newton_iterations", 1, {"panel": "model",
                                      "description": "Newton iterations (0: closed form)"}),
            ("residual", 1, {"panel": "model", "description": "f(t, x, u) - v"}))
        self.diag = np.zeros(diag_width(self.diagnostics))

    def reset(self, rng: np.random.Generator) -> None:
        """Clock and Newton's starting point back to the start; nothing is drawn."""
        self.k = 0
        self.u_prev = self.model.u_op

    def step(self, obs: Observation, dt: float) -> float:
        x, ref = obs.x, obs.ref
        n = self.order
        t = self.k * dt
        self.k += 1
        e = x - ref[:n]
        v = ref[n] - float(self.lam @ e)
        try:
            u, its, res = solve_for_u(self.model, t, x, v, self.u_prev, self.tol, self.max_iter)
        except NewtonFailed:
            u, its, res = math.nan, self.max_iter, math.nan
        d = self.diag
        d[0], d[2], d[3] = v, its, res
        d[1] = self.model.df_du(t, x, u) if math.isfinite(u) else math.nan
        self.u_prev = u if math.isfinite(u) else self.u_prev
        return u

    def parameters(self) -> dict[str, np.ndarray]:
        return {}


def build(scenario: "Scenario") -> FeedbackLinearizationController:
    s: FeedbackLinearizationSettings = settings_for(scenario, FeedbackLinearizationSettings)
    lam = np.asarray(s.lam if s.lam is not None else scenario.controller.lam)
    return FeedbackLinearizationController(plant_model(scenario), lam, s.tol, s.max_iter)
