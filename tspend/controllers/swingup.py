"""``swingup``: energy-based swing-up (Astrom and Furuta, 2000) caught by full-state LQR.

The pendulum's energy about its pivot, 0 upright at rest and ``-2 m g l`` hanging
(:meth:`.full_model.FullModel.energy`),

    E = 1/2 J theta'^2 + m g l (cos theta - 1),

changes only through the driven joint: ``E' = J theta' (theta'' - theta''|_{a=0})``, so
on the cart-pole ``E' = m l cos(theta) theta' a`` with ``a`` the cart's acceleration
(Astrom and Furuta, "Swinging up a pendulum by energy control", Automatica 36, 2000,
eq. 4).  Their law drives ``E`` to the upright's ``E_0 = 0``:

    a = sat_{a_max}( k_E (E_0 - E) sign(theta' cos theta) )            (A-F 2000, eq. 6)

Here ``sign(theta' cos theta)`` is computed from the model as the sign of ``dE'/du``
(``J theta' dtheta''/du``, the domain's own equations), so the same law serves a reversed
hinge or another domain, and a pendulum at rest (``theta' = 0``) is kicked with
``sign = +1``.  ``a`` becomes a force through the model's affine input map
(``u = (a - a_0(s)) / (da/du)``).  The cart is centred by ``-k_x x - k_v x'`` added to
``a`` only where it does not take energy out (``sign(dE'/da) a_c >= 0``), so the
energy rises monotonically until the catch (tests/test_swingup.py); near the rail's
end a braking acceleration overrides everything (the rail is respected first), and the
force is clipped to the actuator's range.

**Catch** (with hysteresis): once the wrapped pole angle ``|theta| < catch_angle``, the
full-state LQR of :mod:`.lqr` (design on the upright) takes over; it hands back only when
``|theta| > release_angle`` (> catch_angle), so the switch cannot chatter on the edge.
Angles wrap: the upright is 0, hanging is pi, and every angle error is wrapped to
(-pi, pi].
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from tspend.controllers.base import Controller, Observation, diag_width, diagnostics
from tspend.controllers.full_model import FullModel, wrap_angle
from tspend.controllers.settings import KindSettings, setting, settings_for
from tspend.errors import ScenarioError

if TYPE_CHECKING:
    from tspend.config import Scenario
    from tspend.controllers.lqr import FullStateLQR

__all__ = ["SwingUpSettings", "SwingUpController", "build"]

#: modes recorded in the ``mode`` diagnostic
SWING, CATCH = 0.0, 1.0


@dataclass(frozen=True)
class SwingUpSettings(KindSettings):
    """``[controllers.swingup]``."""

    #: what tspend tune searches: the energy pumping gain and the acceleration bound
    SEARCH = {"energy_gain": (0.05, 20.0, "log"), "accel_max": (0.5, 20.0, "log")}

    energy_gain: float = setting(1.0, "k_E, (unit of a)/(J s^2): a = k_E (E_0 - E) sign(...)",
                                 low=0.0, strict=True)
    accel_max: float = setting(4.0, "a_max, the driven joint's acceleration bound while "
                                    "swinging (m/s^2 on the cart-pole)", low=0.0, strict=True)
    catch_angle: float = setting(0.4, "rad from upright: LQR takes over inside", low=0.0,
                                 strict=True)
    release_angle: float = setting(0.8, "rad from upright: swing-up resumes outside (must "
                                        "exceed catch_angle)", low=0.0, strict=True)
    centring: tuple[float, ...] = setting((0.5, 1.0), "k_x (1/s^2), k_v (1/s): cart-centring "
                                                      "acceleration -k_x x - k_v x'",
                                          kind="list", low=0.0)
    rail_margin: float = setting(0.5, "brake when the stopping distance reaches the rail's "
                                      "end minus this (m)", low=0.0)

    def check(self, n: int):
        if self.release_angle <= self.catch_angle:
            return "release_angle", (f"must exceed catch_angle {self.catch_angle:g} "
                                     f"(hysteresis), got {self.release_angle:g}")
        if len(self.centring) != 2:
            return "centring", f"needs 2 entries [k_x, k_v], got {len(self.centring)}"
        return None


class SwingUpController(Controller):
    """The ``swingup`` kind (module docstring)."""

    kind = "swingup"

    def __init__(self, model: FullModel, settings: SwingUpSettings, catch: "FullStateLQR",
                 order: int) -> None:
        self.model, self.s, self.lqr = model, settings, catch
        self.order = order
        self.mode = SWING
        self.diagnostics = diagnostics(
            ("energy", 1, {"panel": "energy", "unit": "J",
                           "description": "E = 1/2 J theta'^2 + m g l (cos theta - 1)"}),
            ("mode", 1, {"panel": "mode", "description": "0 swinging up, 1 caught (LQR)"}),
            ("theta_wrapped", 1, {"panel": "state", "unit": "rad",
                                  "description": "pole angle wrapped to (-pi, pi]"}),
            # an acceleration of the driven joint, not a part of u: a view of its own
            ("a_cmd", 1, {"panel": "commanded_acceleration",
                          "unit": "rad/s²" if model.angles[model.actuated] else "m/s²",
                          "description": "commanded acceleration of the driven joint while "
                                         "swinging"}))
        self.diag = np.zeros(diag_width(self.diagnostics))

    def reset(self, rng: np.random.Generator) -> None:
        self.mode = SWING

    def swing(self, state: np.ndarray) -> tuple[float, float]:
        """``(u, a)``: the energy law's force and the acceleration it asks for."""
        m, s = self.model, self.s
        dof, act = m.dof, m.actuated
        a0, du = m.input_map(state)
        # dE'/du = J theta' dtheta''/du, and da/du = du[act] > 0 on the domains here:
        # the sign of dE'/da, i.e. A-F's sign(theta' cos theta)
        slope = m.pole_inertia * state[dof + m.pole] * du[m.pole] * math.copysign(1.0, du[act])
        sign = 1.0 if slope >= 0.0 else -1.0
        energy = m.energy(state)
        a = min(s.accel_max, max(-s.accel_max, s.energy_gain * (0.0 - energy) * sign))
        x, v = state[act], state[dof + act]
        k_x, k_v = s.centring
        a_c = -k_x * x - k_v * v
        if a_c * sign >= 0.0:   # centring that also pumps energy in
            a += a_c
        lim = m.q_hi[act]
        if math.isfinite(lim):
            # stopping distance at full braking; brake before the rail's end
            stop = x + v * abs(v) / (2.0 * s.accel_max)
            if abs(stop) > lim - s.rail_margin:
                # heading out: brake at full; at rest near the end: centre only
                a = -math.copysign(s.accel_max, v) if x * v > 0.0 else a_c
        u = (a - a0[act]) / du[act]
        return min(m.u_hi, max(m.u_lo, u)), a

    def act(self, state: np.ndarray, ref: np.ndarray) -> float:
        m, s = self.model, self.s
        theta = wrap_angle(float(state[m.pole]))
        if self.mode == SWING and abs(theta) < s.catch_angle:
            self.mode = CATCH
        elif self.mode == CATCH and abs(theta) > s.release_angle:
            self.mode = SWING
        if self.mode == CATCH:
            u = min(m.u_hi, max(m.u_lo, self.lqr.act(state, ref)))
            a = 0.0
        else:
            u, a = self.swing(state)
        d = self.diag
        d[0], d[1], d[2], d[3] = m.energy(state), self.mode, theta, a
        return u

    def step(self, obs: Observation, dt: float) -> float:
        return self.act(obs.state, obs.ref)

    def parameters(self) -> dict[str, np.ndarray]:
        return {}


def build(scenario: "Scenario") -> SwingUpController:
    from tspend.controllers.full_model import full_model
    from tspend.controllers.full_model import has_full_state
    from tspend.controllers.lqr import LQRSettings, build_full

    if not has_full_state(scenario):
        raise ScenarioError(f"{scenario.path}: controller 'swingup' needs a pendulum with a "
                            f"full state (the cart-pole, the Furuta pendulum); plant "
                            f"'{scenario.plant.kind}' has none")
    s: SwingUpSettings = settings_for(scenario, SwingUpSettings)
    lqr_settings: LQRSettings = settings_for(scenario, LQRSettings)
    model = full_model(scenario)
    return SwingUpController(model, s, build_full(scenario, lqr_settings),
                             order=len(scenario.plant.x0))
