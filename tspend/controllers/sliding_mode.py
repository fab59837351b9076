"""``sliding_mode``: sliding-mode control with a nominal model and a boundary layer.

Following Slotine and Li, *Applied Nonlinear Control*, 1991, sections 7.1-7.2 (and
Utkin, *Sliding Modes in Control and Optimization*, 1992), on the surface

    s = c^T e = c_1 e_1 + .. + c_{n-1} e_{n-1} + e_n,        e = x - r,  c_n = 1,

with the nominal model ``f_hat(x) = a^T (x - x*)``, ``b_hat = b0`` (the linearisation at
the operating point, :mod:`.plant_model`; ``nominal = "none"`` drops ``f_hat``):

    u = u* + (r^(n) - f_hat(x) - sum_{i<n} c_i e_{i+1} - k sat(s / phi)) / b_hat.

Then ``s' = Delta - k sat(s / phi)`` with ``Delta`` the model error and the disturbance
(in units of ``x_n'``).  While ``|Delta| < k`` the surface is reached in finite time,
``|s| <= phi`` from then on (the boundary layer), and inside it ``s`` settles at about
``phi Delta / k``; on the surface ``e`` decays as ``c`` dictates.  ``sat`` replaces
``sign`` so that ``u`` does not chatter at the sample rate (Slotine and Li, 7.2).

Defaults (:class:`SlidingModeSettings`):

* ``c``: Slotine's ``s = (d/dt + surface_pole)^(n-1) e``, ``surface_pole = 5 rad/s``,
  five times the references' frequency;
* ``k`` by plant domain (``PlantModel.switching_gain``, the domain says why), a margin
  over ``|Delta|`` on the paper's operating regions:
  Example 1 ``2`` (disturbance 0.1 plus the input gain's variation away from the
  origin), Duffing ``20`` (``12 cos t`` and ``x1^3`` with ``|x1| <= 1.5`` are outside the
  linear model: about 15.5), the cart-pole ``0.5 rad/s^2`` (the disturbance is ``0.05 /
  41 ~ 1.2e-3`` and the linearisation's error ~ 2.6 theta^3/6 is smaller still; 0.5
  gives a fast reaching phase from ``theta(0) = pi/30``), the third-order plant ``2``;
* ``phi = k / 50``: the layer's linear gain ``k / phi = 50 s^-1`` is fast against the
  references and slow against the 1 ms sample (``dt k / phi = 0.05 << 2``), so the
  discrete loop stays inside the layer without chattering;
* ``b0 = df/du`` at the operating point.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numba import njit

from tspend.controllers.base import (CompiledController, Controller, Observation, diag_width,
                                     diagnostics)
from tspend.plants.domain import VIEW_MODEL
from tspend.runtime.jit import JIT
import tspend.runtime.xp as xp
from tspend.runtime.law import array_law
from tspend.controllers.pd import gains_from_poles
from tspend.controllers.plant_model import plant_model
from tspend.controllers.settings import POLE_CAP, KindSettings, finite_or, setting, settings_for

if TYPE_CHECKING:
    from tspend.plants.base import Plant
    from tspend.config import Scenario

#: phi = k / LAYER_RATE when phi is not given
LAYER_RATE = 50.0


@dataclass(frozen=True)
class SlidingModeSettings(KindSettings):
    """``[controllers.sliding_mode]``."""

    #: what ``tspend tune`` searches (controllers.settings.Search: low, high, scale[, form])
    SEARCH = {"surface_pole": (0.2, POLE_CAP, "log"), "k": (0.01, 100.0, "log"),
              "phi": (1e-4, 10.0, "log")}

    c: tuple[float, ...] | None = setting(
        None, "c_1 .. c_{n-1} of s = c^T e, c_n = 1 (default: (d/dt + surface_pole)^(n-1))",
        kind="vector", length="n-1", low=0.0, strict=True)
    surface_pole: float = setting(5.0, "rad/s; the surface's pole when c is not given",
                                  low=0.0, strict=True)
    k: float | None = setting(None, "switching gain in units of x_n' (default by plant)",
                              low=0.0, strict=True)
    phi: float | None = setting(None, "boundary layer half-width on s (default k / 50)",
                                low=0.0, strict=True)
    b0: float | None = setting(None, "nominal input gain (default df/du at the operating point)")
    nominal: str = setting("linear", "nominal f_hat: the linearisation, or none (f_hat = 0)",
                           kind="choice", choices=("linear", "none"))

    def check(self, n: int):
        if self.b0 is not None and self.b0 == 0.0:
            return "b0", "must not be 0"
        return None


@array_law
def sat(z: float) -> float:
    return xp.where(-1.0 <= z, xp.where(z <= 1.0, z, 1.0), -1.0)


class SlidingLaw(NamedTuple):
    """The law's numbers, as compiled code reads them (:func:`sliding_law`)."""

    c: np.ndarray      # (n,) c_1 .. c_n, c_n = 1
    k: float
    phi: float
    a: np.ndarray      # (n,) the nominal model's df/dx
    b0: float
    x_op: np.ndarray   # (n,)
    u_op: float


@array_law
def sliding_law(law: SlidingLaw, state, scratch, t: float, full: np.ndarray, x: np.ndarray,
                ref: np.ndarray, dt: float, diag: np.ndarray) -> tuple:
    """``(u, state)``, ``u = u* + (r^(n) - f_hat(x) - sum_{i<n} c_i e_{i+1} - k sat(s /
    phi)) / b_hat`` (module docstring), its parts into ``diag``; the one implementation,
    for numba and JAX (:mod:`tspend.runtime.law`)."""
    n = law.c.size
    s = 0.0
    f_hat = 0.0
    shift = 0.0
    for j in range(n):
        e_j = x[j] - ref[j]
        s += law.c[j] * e_j
        f_hat += law.a[j] * (x[j] - law.x_op[j])
        if j > 0:
            shift += law.c[j - 1] * e_j
    u_eq = law.u_op + (ref[n] - f_hat - shift) / law.b0
    u_sw = -law.k * sat(s / law.phi) / law.b0
    diag = xp.put(diag, 0, s)
    diag = xp.put(diag, 1, s / law.phi)
    diag = xp.put(diag, 2, u_eq)
    diag = xp.put(diag, 3, u_sw)
    return u_eq + u_sw, state


@njit(**JIT)
def sliding_step(law: SlidingLaw, state, scratch, t: float, full: np.ndarray, x: np.ndarray,
                 ref: np.ndarray, dt: float, diag: np.ndarray) -> float:
    """:func:`sliding_law` behind the compiled controllers' common signature."""
    return sliding_law(law, state, scratch, t, full, x, ref, dt, diag)[0]


class SlidingModeController(Controller):
    """The ``sliding_mode`` kind (a :class:`~tspend.controllers.base.Controller`)."""

    kind = "sliding_mode"
    Settings = SlidingModeSettings

    @classmethod
    def from_scenario(cls, scenario: "Scenario", machine: "Plant | None" = None) -> Controller:
        return build(scenario, machine)
    needs = (VIEW_MODEL,)
    guarantees = ("reaches the boundary layer in finite time while the model error stays "
                  "below the switching gain")

    def __init__(self, c: np.ndarray, k: float, phi: float, a: np.ndarray, b0: float,
                 x_op: np.ndarray, u_op: float) -> None:
        self.c = np.append(np.asarray(c, dtype=float), 1.0)   # c_n = 1
        self.order = self.c.size
        self.k, self.phi, self.b0 = float(k), float(phi), float(b0)
        self.a = np.asarray(a, dtype=float)
        self.x_op, self.u_op = np.asarray(x_op, dtype=float), float(u_op)
        self.diagnostics = diagnostics(
            ("s", 1, {"panel": "sliding", "description": "sliding variable c^T e"}),
            ("s_over_phi", 1, {"panel": "sliding",
                               "description": "s / phi: inside the boundary layer when |.| <= 1"}),
            ("u_eq", 1, {"panel": "control", "description": "equivalent control of the nominal model"}),
            ("u_sw", 1, {"panel": "control", "chattering": True,
                         "description": "switching part -k sat(s / phi) / b0"}))
        self.diag = np.zeros(diag_width(self.diagnostics))
        self.law = SlidingLaw(self.c.copy(), self.k, self.phi, self.a.copy(), self.b0,
                              self.x_op.copy(), self.u_op)

    def reset(self, rng: np.random.Generator) -> None:
        """Nothing is adapted and nothing is drawn."""

    def step(self, obs: Observation, dt: float) -> float:
        # the compiled law from Python too: one dispatch instead of the law interpreted
        return sliding_step(self.law, None, None, obs.t, obs.state, obs.x, obs.ref, dt,
                            self.diag)

    def compiled(self) -> CompiledController:
        """The same law in the compiled loops (:mod:`tspend.loop.fastloop`)."""
        return CompiledController(sliding_step, self.law, None, None, sliding_law)

    def parameters(self) -> dict[str, np.ndarray]:
        return {}


def build(scenario: "Scenario", machine: "Plant | None" = None) -> SlidingModeController:
    st: SlidingModeSettings = settings_for(scenario, SlidingModeSettings)
    model = plant_model(scenario, machine)
    n = model.order
    a, b = model.linearisation()
    c = np.asarray(st.c) if st.c is not None else gains_from_poles(n - 1, st.surface_pole)
    k = finite_or(st.k, model.switching_gain)
    phi = finite_or(st.phi, k / LAYER_RATE)
    if st.nominal == "none":
        a = np.zeros(n)
    return SlidingModeController(c, k, phi, a, finite_or(st.b0, b), np.asarray(model.x_op),
                                 model.u_op)
