"""``swingup``: energy-based swing-up (Astrom and Furuta, 2000) caught by full-state LQR.

The pendulum's energy about its pivot, 0 upright at rest and ``-2 m g l`` hanging, is
the domain's (:class:`~tspend.plants.domain.FullModel`'s ``energy``:
:class:`tspend.plants.articulated.domain.DerivedFull`), ``E = 1/2 J theta'^2 + V(theta)``.
It changes only through the driven joint (and the pendulum's own damping):
``E' = J theta' (theta'' - theta''|_{a=0})``, so on the cart-pole ``E' = m l cos(theta)
theta' a`` with ``a`` the cart's acceleration (Astrom and Furuta, "Swinging up a
pendulum by energy control", Automatica 36, 2000, eq. 4), on the Furuta pendulum the
same with the arm's angular acceleration.  Their law drives ``E`` to the upright's
``E_0 = 0``:

    a = sat_{a_max}( k_E (E_0 - E) sign(theta' cos theta) )            (A-F 2000, eq. 6)

Here ``sign(theta' cos theta)`` is computed from the model as the sign of ``dE'/du``
(``J theta' dtheta''/du``, the domain's own equations), so the same law serves every
domain with a full-state model and a reversed hinge, and a pendulum at rest
(``theta' = 0``) is kicked with ``sign = +1``.  ``a`` (the driven joint's acceleration:
m/s^2 on the cart-pole, rad/s^2 on the Furuta's arm) becomes the input through the
model's affine input map (``u = (a - a_0(s)) / (da/du)``).  The driven joint is centred
by ``-k_x q - k_v q'`` added to ``a`` only where it does not take energy out
(``sign(dE'/da) a_c >= 0``), so the energy rises monotonically until the catch (up to
the pendulum's damping; tests/test_full_state_control.py, tests/test_furuta_swingup.py);
near the end of the driven joint's range (the cart-pole's rail, a joint's range, a
``task.state_bounds`` entry) a braking acceleration overrides everything (the range is
respected first), and the input is clipped to the actuator's range (newtons, volts).

**Catch** (with hysteresis): once the wrapped pole angle ``|theta| < catch_angle``, the
full-state LQR of :mod:`.lqr` (design on the upright) takes over; it hands back only when
``|theta| > release_angle`` (> catch_angle), so the switch cannot chatter on the edge.
Angles wrap: the upright is 0, hanging is pi, and every angle error is wrapped to
(-pi, pi].
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numba import njit
from numba.extending import register_jitable

from tspend.controllers.base import (CompiledController, Controller, Observation, diag_width,
                                     diagnostics)
from tspend.plants.articulated.domain import derived_full_accel, derived_pole_energy
from tspend.plants.domain import FULL_STATE, PUMPED_ENERGY, FullModel, wrap_angle
from tspend.controllers.lqr import FullLQRLaw, full_lqr_law
from tspend.runtime.jit import JIT
import tspend.runtime.xp as xp
from tspend.runtime.law import array_law, mark_law
from tspend.controllers.settings import KindSettings, setting, settings_for

if TYPE_CHECKING:
    from tspend.plants.base import Plant
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
                                    "swinging (m/s^2 for a cart, rad/s^2 for an arm)",
                               low=0.0, strict=True)
    catch_angle: float = setting(0.4, "rad from upright: LQR takes over inside", low=0.0,
                                 strict=True)
    release_angle: float = setting(0.8, "rad from upright: swing-up resumes outside (must "
                                        "exceed catch_angle)", low=0.0, strict=True)
    centring: tuple[float, ...] = setting((0.5, 1.0), "k_x (1/s^2), k_v (1/s): the driven "
                                                      "joint's centring acceleration "
                                                      "-k_x q - k_v q'",
                                          kind="list", low=0.0)
    range_margin: float = setting(0.5, "brake when the driven joint's stopping distance "
                                       "reaches the end of its range minus this (m or rad)",
                                  low=0.0)

    def check(self, n: int):
        if self.release_angle <= self.catch_angle:
            return "release_angle", (f"must exceed catch_angle {self.catch_angle:g} "
                                     f"(hysteresis), got {self.release_angle:g}")
        if len(self.centring) != 2:
            return "centring", f"needs 2 entries [k_x, k_v], got {len(self.centring)}"
        return None


class SwingLaw(NamedTuple):
    """The swing-up's numbers and its catching LQR, as compiled code reads them."""

    machine: Any            # the derived machine (FullModel.machine: DerivedFull)
    pole: int
    actuated: int
    dof: int
    u_lo: float
    u_hi: float
    bounded: bool           # whether the driven joint's range is finite
    limit: float            # the driven joint's range, symmetric (inf: free)
    energy_gain: float
    accel_max: float
    catch_angle: float
    release_angle: float
    k_x: float
    k_v: float
    range_margin: float
    lqr: FullLQRLaw
    lqr_diag: np.ndarray    # the catching LQR's own diagnostics (not recorded)


@array_law
def clipped(v: float, lo: float, hi: float) -> float:
    """``min(hi, max(lo, v))`` with Python's (and numba's) choice, NaN included."""
    above = xp.where(v > lo, v, lo)
    return xp.where(above < hi, above, hi)


@mark_law
@register_jitable
def swing(law: SwingLaw, state: np.ndarray) -> tuple[float, float]:
    """``(u, a)``: the energy law's force and the acceleration it asks for (module
    docstring)."""
    dof, act, pole = law.dof, law.actuated, law.pole
    a0 = derived_full_accel(law.machine, state, 0.0)
    a1 = derived_full_accel(law.machine, state, 1.0)
    du_act, du_pole = a1[act] - a0[act], a1[pole] - a0[pole]
    # dE'/du = J theta' dtheta''/du (J > 0), times the sign of da/du: the sign of
    # dE'/da, i.e. A-F's sign(theta' cos theta)
    slope = state[dof + pole] * du_pole * math.copysign(1.0, du_act)
    sign = xp.where(slope >= 0.0, 1.0, -1.0)
    energy = derived_pole_energy(law.machine, state)
    a = clipped(law.energy_gain * (0.0 - energy) * sign, -law.accel_max, law.accel_max)
    x, v = state[act], state[dof + act]
    a_c = -law.k_x * x - law.k_v * v
    a = xp.where(a_c * sign >= 0.0, a + a_c, a)   # centring that also pumps energy in
    if law.bounded:
        # stopping distance at full braking; brake before the range's end: heading out,
        # brake at full; at rest near the end, centre only
        stop = x + v * abs(v) / (2.0 * law.accel_max)
        brake = xp.where(x * v > 0.0, -math.copysign(law.accel_max, v), a_c)
        a = xp.where(abs(stop) > law.limit - law.range_margin, brake, a)
    u = (a - a0[act]) / du_act
    return clipped(u, law.u_lo, law.u_hi), a


@array_law
def swingup_law(law: SwingLaw, mode: np.ndarray, scratch, t: float, full: np.ndarray,
                x: np.ndarray, ref: np.ndarray, dt: float, diag: np.ndarray) -> tuple:
    """``(u, mode)`` of one sample: switch between swinging and catching (hysteresis),
    then that mode's u; ``mode[0]`` is :data:`SWING` or :data:`CATCH`.  Both modes' u
    are computed and one chosen by data (``xp.where``).  The one implementation, for
    numba and JAX (:mod:`tspend.runtime.law`)."""
    theta = wrap_angle(full[law.pole])
    now = mode[0]
    now = xp.where((now == SWING) & (abs(theta) < law.catch_angle), CATCH,
                   xp.where((now == CATCH) & (abs(theta) > law.release_angle), SWING, now))
    mode = xp.put(mode, 0, now)
    u_catch = clipped(full_lqr_law(law.lqr, full, ref, law.lqr_diag), law.u_lo, law.u_hi)
    u_swing, a_swing = swing(law, full)
    caught = now == CATCH
    a = xp.where(caught, 0.0, a_swing)
    diag = xp.put(diag, 0, derived_pole_energy(law.machine, full))
    diag = xp.put(diag, 1, now)
    diag = xp.put(diag, 2, theta)
    diag = xp.put(diag, 3, a)
    return xp.where(caught, u_catch, u_swing), mode


@njit(**JIT)
def swingup_step(law: SwingLaw, mode: np.ndarray, scratch, t: float, full: np.ndarray,
                 x: np.ndarray, ref: np.ndarray, dt: float, diag: np.ndarray) -> float:
    """:func:`swingup_law` behind the compiled controllers' common signature."""
    return swingup_law(law, mode, scratch, t, full, x, ref, dt, diag)[0]


@dataclass(frozen=True)
class SwingUpDesign:
    """The swing-up's design (:func:`design`): the full-state model it pumps, its
    settings, the catching LQR and the law's numbers."""

    model: FullModel
    settings: SwingUpSettings
    catch: "FullStateLQR"
    law: SwingLaw


def design(model: FullModel, settings: SwingUpSettings, catch: "FullStateLQR") -> SwingUpDesign:
    """The law's numbers of the swing-up on ``model`` (its bounds, its derived machine)
    with ``settings``, caught by ``catch``: pure."""
    k_x, k_v = settings.centring
    limit = min(model.q_hi[model.actuated], -model.q_lo[model.actuated])
    law = SwingLaw(model.machine, model.pole, model.actuated, model.dof, float(model.u_lo),
                   float(model.u_hi), math.isfinite(limit), float(limit),
                   settings.energy_gain, settings.accel_max, settings.catch_angle,
                   settings.release_angle, float(k_x), float(k_v), settings.range_margin,
                   catch.law, catch.diag)
    return SwingUpDesign(model, settings, catch, law)


class SwingUpController(Controller):
    """The ``swingup`` kind (module docstring)."""

    kind = "swingup"
    Settings = SwingUpSettings

    @classmethod
    def from_scenario(cls, scenario: "Scenario", machine: "Plant | None" = None) -> Controller:
        return build(scenario, machine)
    needs = (FULL_STATE, PUMPED_ENERGY)
    guarantees = ("the energy the input adds is never negative until the catch (A-F 2000); "
                  "the driven joint's range respected by braking, the input clipped to its "
                  "range; LQR's local guarantee once caught (hysteresis)")

    def __init__(self, design: SwingUpDesign, order: int) -> None:
        self.design, self.order = design, order
        self.model, self.s, self.lqr, self.law = (design.model, design.settings, design.catch,
                                                  design.law)
        model = design.model
        #: [SWING or CATCH]
        self.modes = np.array([SWING])
        self.diagnostics = diagnostics(
            ("energy", 1, {"panel": "energy", "unit": "J",
                           "description": "the pendulum's energy about its pivot, 0 upright"}),
            ("mode", 1, {"panel": "mode", "description": "0 swinging up, 1 caught (LQR)"}),
            ("theta_wrapped", 1, {"panel": "state", "unit": "rad",
                                  "description": "pole angle wrapped to (-pi, pi]"}),
            # an acceleration of the driven joint, not a part of u: a view of its own
            ("a_cmd", 1, {"panel": "commanded_acceleration",
                          "unit": "rad/s²" if model.angles[model.actuated] else "m/s²",
                          "description": "commanded acceleration of the driven joint while "
                                         "swinging"}))
        self.diag = np.zeros(diag_width(self.diagnostics))

    @property
    def mode(self) -> float:
        return float(self.modes[0])

    def reset(self, rng: np.random.Generator) -> None:
        self.modes[0] = SWING

    def swing(self, state: np.ndarray) -> tuple[float, float]:
        """``(u, a)``: the energy law's force and the acceleration it asks for."""
        return swing(self.law, np.asarray(state, dtype=float))

    def act(self, state: np.ndarray, ref: np.ndarray) -> float:
        state = np.asarray(state, dtype=float)
        return swingup_law.py_func(self.law, self.modes, None, 0.0, state, state, ref, 0.0,
                                   self.diag)[0]

    def step(self, obs: Observation, dt: float) -> float:
        if self.model.machine is not None:   # the compiled law from Python too
            return swingup_step(self.law, self.modes, None, obs.t, obs.state, obs.x, obs.ref,
                                dt, self.diag)
        return self.act(obs.state, obs.ref)

    def compiled(self) -> CompiledController | None:
        """The same law in the compiled loops (:mod:`tspend.loop.fastloop`)."""
        if self.model.machine is None:
            return None
        return CompiledController(swingup_step, self.law, self.modes, None, swingup_law)

    def parameters(self) -> dict[str, np.ndarray]:
        return {}


def build(scenario: "Scenario", machine: "Plant | None" = None) -> SwingUpController:
    from tspend.controllers.full_model import full_model
    from tspend.controllers.lqr import LQRSettings, build_full

    s: SwingUpSettings = settings_for(scenario, SwingUpSettings)
    lqr_settings: LQRSettings = settings_for(scenario, LQRSettings)
    model = full_model(scenario, machine)
    return SwingUpController(design(model, s, build_full(scenario, lqr_settings, machine)),
                             order=len(scenario.plant.x0))
