"""``pd``: error feedback with a nominal input gain (a PD controller for n = 2).

    u = (r^(n) - k^T e) / b0,        e = x - r,  k = [k_1 .. k_n]

(Astrom and Murray, *Feedback Systems*, 2nd ed., 2021, ch. 3 and 11: PD action on the
tracking error plus feedforward of the reference acceleration.)  On the chain of
integrators ``x_n' = b0 u`` this gives ``e^(n) + k_n e^(n-1) + .. + k_1 e = 0``; on the
real plant, everything in ``f`` besides ``b0 u`` (gravity, Duffing's cubic and forcing,
Example 1's nonlinear gain) is left to the feedback to reject, so the error stays
roughly ``|f - b0 u| / k_1``.

Defaults (:class:`PDSettings`): ``k`` are the coefficients of ``(s + bandwidth)^n``
(critically damped, all poles at ``-bandwidth``); ``bandwidth = 10 rad/s`` is ten times
the paper's references' frequency (1 rad/s) and, at the 1 ms sample time, a hundredth of
the sample rate, so the hold costs nothing noticeable.  ``b0`` defaults to ``df/du`` at
the operating point, from the plant's own equations (:mod:`.plant_model`).
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numba import njit

from tspend.controllers.base import (CompiledController, Controller, Observation, diag_width,
                                     diagnostics)
from tspend.plants.domain import VIEW_MODEL
from tspend.runtime.jit import JIT
import tspend.runtime.xp as xp
from tspend.runtime.law import array_law
from tspend.controllers.plant_model import plant_model
from tspend.controllers.settings import POLE_CAP, KindSettings, finite_or, setting, settings_for

if TYPE_CHECKING:
    from tspend.plants.base import Plant
    from tspend.config import Scenario


@dataclass(frozen=True)
class PDSettings(KindSettings):
    """``[controllers.pd]``."""

    #: what ``tspend tune`` searches (controllers.settings.Search: low, high, scale[, form])
    SEARCH = {"bandwidth": (0.2, POLE_CAP, "log")}

    gains: tuple[float, ...] | None = setting(
        None, "k_1 .. k_n on e_1 .. e_n (default: coefficients of (s + bandwidth)^n)",
        kind="vector", length="n", low=0.0, strict=True)
    bandwidth: float = setting(10.0, "rad/s; all closed-loop poles at -bandwidth when gains "
                                     "are not given", low=0.0, strict=True)
    b0: float | None = setting(None, "nominal input gain (default: df/du at the operating "
                                     "point, from the plant's equations)")

    def check(self, n: int):
        if self.b0 is not None and self.b0 == 0.0:
            return "b0", "must not be 0 (u = (r^(n) - k^T e) / b0)"
        return None


def gains_from_poles(n: int, pole: float) -> np.ndarray:
    """``k_1 .. k_n`` with ``s^n + k_n s^(n-1) + .. + k_1 = (s + pole)^n``."""
    return np.array([comb(n, i) * pole ** (n - i) for i in range(n)], dtype=float)


class PDLaw(NamedTuple):
    """The law's numbers, as compiled code reads them."""

    k: np.ndarray      # (n,) gains k_1 .. k_n
    b0: float


@array_law
def pd_law(law: PDLaw, state, scratch, t: float, full: np.ndarray, x: np.ndarray,
           ref: np.ndarray, dt: float, diag: np.ndarray) -> tuple:
    """``(u, state)``, ``u = (r^(n) - k^T e) / b0`` (module docstring), its parts into
    ``diag``; the one implementation, for numba and JAX (:mod:`tspend.runtime.law`)."""
    n = law.k.size
    ke = 0.0
    for j in range(n):
        ke += law.k[j] * (x[j] - ref[j])
    u_ff = ref[n] / law.b0
    u_fb = -ke / law.b0
    diag = xp.put(diag, 0, u_ff)
    diag = xp.put(diag, 1, u_fb)
    return u_ff + u_fb, state


@njit(**JIT)
def pd_step(law: PDLaw, state, scratch, t: float, full: np.ndarray, x: np.ndarray,
            ref: np.ndarray, dt: float, diag: np.ndarray) -> float:
    """:func:`pd_law` behind the compiled controllers' common signature."""
    return pd_law(law, state, scratch, t, full, x, ref, dt, diag)[0]


class PDController(Controller):
    """The ``pd`` kind (a :class:`~tspend.controllers.base.Controller`)."""

    kind = "pd"
    Settings = PDSettings

    @classmethod
    def from_scenario(cls, scenario: "Scenario", machine: "Plant | None" = None) -> Controller:
        return build(scenario, machine)
    needs = (VIEW_MODEL,)
    guarantees = ("exponential stability of the view's error where df/du stays near its "
                  "nominal b0 (the linearisation's margins); nothing beyond the view")

    def __init__(self, gains: np.ndarray, b0: float) -> None:
        self.k = np.asarray(gains, dtype=float)
        self.order = self.k.size
        self.b0 = float(b0)
        self.diagnostics = diagnostics(
            ("u_ff", 1, {"panel": "control", "description": "feedforward r^(n) / b0"}),
            ("u_fb", 1, {"panel": "control", "description": "feedback -k^T e / b0"}))
        self.diag = np.zeros(diag_width(self.diagnostics))
        self.law = PDLaw(self.k.copy(), self.b0)

    def reset(self, rng: np.random.Generator) -> None:
        """Nothing is adapted and nothing is drawn."""

    def step(self, obs: Observation, dt: float) -> float:
        # the compiled law from Python too: one dispatch instead of the law interpreted
        return pd_step(self.law, None, None, obs.t, obs.state, obs.x, obs.ref, dt, self.diag)

    def compiled(self) -> CompiledController:
        """The same law in the compiled loops (:mod:`tspend.loop.fastloop`)."""
        return CompiledController(pd_step, self.law, None, None, pd_law)

    def parameters(self) -> dict[str, np.ndarray]:
        return {}


def build(scenario: "Scenario", machine: "Plant | None" = None) -> PDController:
    s: PDSettings = settings_for(scenario, PDSettings)
    model = plant_model(scenario, machine)
    gains = np.asarray(s.gains) if s.gains else gains_from_poles(model.order, s.bandwidth)
    b0 = finite_or(s.b0, model.linearisation()[1])
    return PDController(gains, b0)
