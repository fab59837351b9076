"""What the full-state controller kinds (``lqr`` with ``design = "full"``, ``mpc``,
``swingup``) know of a plant: its whole state, its equations, its bounds.

A :class:`FullModel` describes an underactuated mechanical domain with positions ``q``
and velocities ``q'`` (the full state ``s = [q, q']``, named as the plant names it:
cart-pole ``("slider", "hinge", "slider_dot", "hinge_dot")``), one input ``u`` and
``q'' = accel(s, u)`` taken from the domain's own equations (written once, in the
domain's module; here only called).  The equations are built twice from that one
source: over ``math`` for numbers and over CasADi for symbols
(:func:`tspend.plants.cartpole_physics.accelerations_factory`), so the MPC's model is the
simulated one, not a copy.

Derived, each documented as such:

* (the linearisation at the upright is the domain's own exact Jacobian,
  :meth:`tspend.plants.domain.Domain.linearisation`, as :func:`tspend.linearize` gives it);
* the input's affine map ``q'' = q''(s, 0) + u dq''/du`` (the domains' inputs are
  forces or voltages entering linearly: checked at build time);
* the pendulum's energy about its pivot (swing-up):
  ``E = 1/2 J_p theta'^2 + m g l (cos theta - 1)``, 0 at the upright at rest.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any, Callable

import numpy as np
from numba.extending import register_jitable

from tspend.errors import ScenarioError

if TYPE_CHECKING:
    from tspend.config import Scenario

__all__ = ["FullModel", "full_model", "has_full_state", "wrap_angle",
           "FULL_STATE_DOMAINS"]

#: the domains whose full-state model this module builds
FULL_STATE_DOMAINS = ("cartpole", "furuta")


@register_jitable
def wrap_angle(a: float) -> float:
    """``a`` wrapped to (-pi, pi]: the error of an angle that may have turned over."""
    return a - 2.0 * math.pi * math.ceil((a - math.pi) / (2.0 * math.pi))


@dataclass(frozen=True)
class FullModel:
    """A domain's full-state model (module docstring).

    ``accel_factory(sin, cos, tanh)`` returns ``accel(s, u) -> q''`` (a tuple of length
    ``len(q)``) over those math functions; ``angles`` marks the states that wrap;
    ``pole`` is the index of the pendulum's angle in ``s`` (upright 0, hanging pi),
    ``actuated`` the index of the driven coordinate (cart, arm); ``q_lo``/``q_hi`` bound
    the positions (+/-inf: free; a finite rail or joint range otherwise); ``u_lo``/``u_hi``
    bound the input (the actuator's range).
    """

    domain: str
    state_names: tuple[str, ...]
    accel_factory: Callable[..., Callable[[Any, Any], tuple]]
    pole: int
    actuated: int
    angles: tuple[bool, ...]
    u_lo: float = -math.inf
    u_hi: float = math.inf
    q_lo: tuple[float, ...] = ()
    q_hi: tuple[float, ...] = ()
    #: pendulum inertia about its pivot and m g l (energy, swing-up)
    pole_inertia: float = 0.0
    mgl: float = 0.0
    parameters: dict = field(default_factory=dict)
    #: whether the equations can be built over CasADi (MPC)
    symbolic_ok: bool = True

    @property
    def size(self) -> int:
        return len(self.state_names)

    @property
    def dof(self) -> int:
        return self.size // 2

    @cached_property
    def numeric(self) -> Callable[[np.ndarray, float], tuple]:
        """``q''(s, u)`` over ``math`` (numbers)."""
        return self.accel_factory(math.sin, math.cos, math.tanh)

    def rhs(self, s: np.ndarray, u: float) -> np.ndarray:
        """``s' = [q', q''(s, u)]``."""
        qdd = self.numeric(s, u)
        return np.concatenate([np.asarray(s[self.dof:], dtype=float), np.asarray(qdd, dtype=float)])

    def symbolic(self) -> Callable[[Any, Any], Any]:
        """``s' = f(s, u)`` as CasADi expressions of an ``SX``/``MX`` state and input."""
        import casadi

        accel = self.accel_factory(casadi.sin, casadi.cos, casadi.tanh)

        def f(s, u):
            qdd = accel(s, u)
            return casadi.vertcat(s[self.dof:], *qdd)

        return f

    def input_map(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(q''(s, 0), dq''/du)``: the accelerations are affine in ``u``."""
        f = self.numeric
        a0 = np.asarray(f(s, 0.0), dtype=float)
        return a0, np.asarray(f(s, 1.0), dtype=float) - a0

    def energy(self, s: np.ndarray) -> float:
        """The pendulum's energy about its pivot, 0 upright at rest (-2 m g l hanging)."""
        w = s[self.dof + self.pole]
        return 0.5 * self.pole_inertia * w * w + self.mgl * (math.cos(s[self.pole]) - 1.0)

    def error(self, s: np.ndarray, s_ref: np.ndarray) -> np.ndarray:
        """``s - s_ref`` with the angles' errors wrapped to (-pi, pi]."""
        e = np.asarray(s, dtype=float) - s_ref
        for i, wraps in enumerate(self.angles):
            if wraps:
                e[i] = wrap_angle(e[i])
        return e


def _cartpole(machine: Any, names: tuple[str, ...], u_lo: float, u_hi: float,
              q_lo: tuple[float, ...], q_hi: tuple[float, ...], params: dict) -> FullModel:
    from tspend.plants.cartpole_physics import accelerations_factory

    def factory(sin, cos, tanh):
        accel = accelerations_factory(sin, cos, tanh)

        def q_dd(s, u):
            # s = [slider, hinge, slider_dot, hinge_dot]; the domain's order is
            # (theta'', x''); no disturbance in a controller's model
            thdd, xdd = accel(machine, s[1], s[3], s[2], u, 0.0)
            return xdd, thdd

        return q_dd

    return FullModel(domain="cartpole", state_names=names, accel_factory=factory, pole=1,
                     actuated=0, angles=(False, True, False, False), u_lo=u_lo, u_hi=u_hi,
                     q_lo=q_lo, q_hi=q_hi,
                     pole_inertia=machine.J, mgl=machine.m * machine.g * machine.l,
                     parameters=params)


def _furuta(machine: Any, names: tuple[str, ...], u_lo: float, u_hi: float,
            q_lo: tuple[float, ...], q_hi: tuple[float, ...], params: dict) -> FullModel:
    from tspend.plants.furuta_physics import machine_accelerations

    def factory(sin, cos, tanh):
        if sin is not math.sin:
            # tspend/plants/furuta_physics.py is written over math only (yet): no second
            # symbolic copy of its equations here
            raise ScenarioError("the Furuta domain's equations are not yet built over "
                                "CasADi: mpc cannot run on it")

        def q_dd(s, u):
            return machine_accelerations(machine, np.asarray(s, dtype=float), float(u), 0.0)

        return q_dd

    # the pendulum's energy about its pivot: m22 and V = v_c cos al (+ v_s sin al, ~0)
    return FullModel(domain="furuta", state_names=names, accel_factory=factory, pole=1,
                     actuated=0, angles=(True, True, False, False), u_lo=u_lo, u_hi=u_hi,
                     q_lo=q_lo, q_hi=q_hi, pole_inertia=machine.m22, mgl=machine.v_c,
                     parameters=params, symbolic_ok=False)


def full_model(scenario: "Scenario") -> FullModel:
    """The full-state model of the scenario's plant (the cart-pole, the Furuta pendulum),
    with the actuator's range, the rail and the joints' ranges as bounds."""
    from dataclasses import asdict

    from tspend.plants import registry

    kind = scenario.plant.kind
    domain = registry.domain_of(kind)
    if domain.name not in FULL_STATE_DOMAINS:
        raise ScenarioError(f"{scenario.path}: plant '{kind}' has no full state to design on "
                            f"(full-state kinds need a mechanical domain: "
                            f"{', '.join(FULL_STATE_DOMAINS)})")
    plant = registry.build(scenario)
    params = domain.params_of_scenario(scenario)  # type: ignore[attr-defined]
    u_lo, u_hi = (plant.inputs[0].lo, plant.inputs[0].hi) if plant.inputs else (-math.inf, math.inf)
    effects = scenario.effects
    if effects.saturation > 0.0:
        u_lo, u_hi = max(u_lo, -effects.saturation), min(u_hi, effects.saturation)
    names = plant.state_names
    dof = len(names) // 2
    q_lo, q_hi = [-math.inf] * dof, [math.inf] * dof
    for j in plant.joints:
        if j.name in names[:dof] and j.range is not None:
            q_lo[names.index(j.name)], q_hi[names.index(j.name)] = j.range
    if domain.name == "cartpole":
        if effects.rail > 0.0:
            q_lo[0], q_hi[0] = -effects.rail, effects.rail
        return _cartpole(params.machine(), names, u_lo, u_hi, tuple(q_lo), tuple(q_hi),
                         asdict(params))
    return _furuta(params.machine(), names, u_lo, u_hi, tuple(q_lo), tuple(q_hi),
                   asdict(params))


def has_full_state(scenario: "Scenario") -> bool:
    """Whether the scenario's plant has a full-state model here."""
    from tspend.plants.registry import domain_of

    return domain_of(scenario.plant.kind).name in FULL_STATE_DOMAINS
