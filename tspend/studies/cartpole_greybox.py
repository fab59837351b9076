"""The grey-box cart-pole: the hand-written equations (C1)-(C2) of a cart-pole
(docs/paper-notes.md section 7, docs/third-party-models.md for the general geometry),
the model ``tspend identify`` fits to a cart-pole's record, and the test oracle of the
equations derived from every MuJoCo cart-pole (tests/test_cartpole_derived.py).  No plant
runs on them: a cart-pole is an articulated machine (:mod:`tspend.plants.articulated`).

Coordinates: cart position ``x`` along the rail (the slide joint's axis ``s``), pole
angle ``q`` (the hinge's own coordinate, axis ``a``).  The paper's angle is
``theta = sigma q`` (``sigma = theta_sign``: +1 when ``q > 0`` leans the pole toward -x,
the paper's convention).  The pole (mass ``m``, inertia ``J`` about the hinge axis,
centre of mass ``c`` anywhere in its frame, at distance ``l`` from the axis) turns
about ``a``, which may point anywhere not parallel to ``s``.  Its centre of mass then
moves along the rail by ``X(q)`` and up (against gravity) by ``H(q)``:

    X(q) = -l k_r sin(sigma q + phi_r),      H(q) = l k_g cos(sigma q + phi_g)

``k_r`` is the part of the pole's rotation plane the rail sees (1 when ``a`` is
perpendicular to ``s``), ``k_g`` the part gravity sees (1 for a horizontal axis),
``phi_r``, ``phi_g`` the lean of the centre of mass off the pole's line (0 for a pole
whose COM is on the line through the pivot).  With ``Mt = M + m`` (``M`` all the slider
carries besides the pole, with the slide's armature; ``J`` with the hinge's), the
Lagrangian ``T = 1/2 Mt x'^2 + m X'(q) x' q' + 1/2 J q'^2``, ``V = m g H(q) - Mt g_s x``
(``g_s``: gravity along the rail) gives

    Mt x''      + m X'(q) q'' = Q_x + Mt g_s + m X(q) q'^2                         (C1)
    m X'(q) x'' + J q''       = Q_q - m g H'(q)                                    (C2)

with ``Q_x = F(u, x, x') - b_x x' - F_x dry(x') - k_x (x - x_ref)`` (the actuator's
force, viscous and dry friction, a spring at the cart) and ``Q_q = tau - b_q q' - F_q
dry(q') - k_q (q - q_ref)``.  For the paper's machine (``k = 1``, ``phi = 0``, uniform
rod ``J = 4/3 m l^2``, no friction, ``tau = -d_d m l / (M + m)``) this is exactly
Example 3's ODE

    theta'' = (m l w^2 sin cos - (M+m) g sin - u cos + d_d) / (m l cos^2 - 4/3 l (M+m)).

The actuator is MuJoCo's (``mjTRN_JOINT`` on the slide, no activation dynamics):

    F = clip(gear clip((g0 + g1 L + g2 V) clip(u, ctrl) + b0 + b1 L + b2 V, force), joint)

with ``L = gear x``, ``V = gear x'`` (a motor: ``g0 = 1``, the rest 0; a velocity
actuator: ``g0 = kv``, ``b2 = -kv``; a position actuator: ``g0 = kp``, ``b1 = -kp``,
``b2 = -kv``), clipped by ``ctrlrange``, ``forcerange`` and the joint's
``actuatorfrcrange`` where each is set.

Dry friction is smooth here, ``F tanh(v / v_s)``, so an RK4 step stays well defined; MuJoCo's
``frictionloss`` is a soft constraint instead, so on dry friction the two backends agree
in kind, not to rounding (the cross-check names it as a departure).

Its numbers are :class:`tspend.plants.mjcf.CartPoleParams`, read from a compiled model
(:meth:`tspend.plants.mjcf.ModelFacts.params`); :func:`machine_of` resolves them for
compiled code.
"""

from __future__ import annotations

import math
from dataclasses import fields
from typing import NamedTuple

import numpy as np
from numba.extending import register_jitable

from tspend.plants.articulated.domain import DRY_FRICTION_SLIP
from tspend.plants.mjcf import CartPoleParams

__all__ = ["CartPoleMachine", "accelerations",
           "accelerations_factory", "actuator_force", "actuator_force_range", "clip",
           "gain_sign", "inverse_dynamics", "machine_accelerations", "machine_of", "machine_rhs",
           "pole_energy", "rhs"]

INF = math.inf


def machine_of(p: CartPoleParams) -> "CartPoleMachine":
    """``p`` as compiled code reads it (``J`` the inertia about the pivot, the hinge torque
    per unit d_d resolved)."""
    values = {f.name: float(getattr(p, f.name)) for f in fields(p)}
    values["J"] = p.pole_inertia_pivot
    return CartPoleMachine(disturbance_torque=p.disturbance_torque, **values)


class CartPoleMachine(NamedTuple):
    """:class:`~tspend.plants.mjcf.CartPoleParams` with ``J`` the inertia about the pivot and the hinge torque
    per unit d_d resolved: a structure numba can pass by value."""

    M: float
    m: float
    l: float
    g: float
    J: float
    cart_damping: float
    hinge_damping: float
    cart_friction: float
    hinge_friction: float
    gear: float
    theta_sign: float
    rail_coupling: float
    rail_phase: float
    gravity_coupling: float
    gravity_phase: float
    rail_gravity: float
    cart_stiffness: float
    cart_spring_ref: float
    hinge_stiffness: float
    hinge_spring_ref: float
    gain: float
    gain_length: float
    gain_velocity: float
    bias: float
    bias_length: float
    bias_velocity: float
    ctrl_min: float
    ctrl_max: float
    force_min: float
    force_max: float
    joint_force_min: float
    joint_force_max: float
    disturbance_torque: float

    def rhs_into(self, t: float, s: np.ndarray, u: float, d: float, sdot: np.ndarray) -> None:
        machine_rhs(self, t, s, u, d, sdot)


@register_jitable
def clip(v: float, lo: float, hi: float) -> float:
    """``v`` clipped to ``[lo, hi]`` (+/-inf: that side open), as MuJoCo clips ctrl and
    the actuator's force."""
    return min(max(v, lo), hi)


def accelerations_factory(sin, cos, tanh, clip=clip):
    """``(accelerations, force)``: ``(q'', x'')`` of (C1)-(C2) and the actuator's force
    ``F(u, x, x')``, built over the math functions ``(sin, cos, tanh)`` and the clip
    ``clip(v, lo, hi)``.

    The equations are written once, here: ``math``'s functions and :func:`clip` give
    :func:`machine_accelerations` and :func:`machine_force` (plain Python, and inlined
    by numba into compiled loops); CasADi's ``(casadi.sin, casadi.cos, casadi.tanh)``
    with a clip over ``casadi.fmin``/``casadi.fmax`` give the same expressions, the
    whole general geometry and actuator included, symbolically for nonlinear MPC
    (:meth:`tspend.plants.cartpole.CartPoleDomain.full_model`,
    :mod:`tspend.controllers.mpc`).  The parameters ``p`` are numbers in both cases (the
    branch on a friction force is on a number; ``clip`` is called only on the ranges
    that are set).
    """

    @register_jitable
    def dry(force, v):
        return force * tanh(v / DRY_FRICTION_SLIP) if force > 0.0 else 0.0

    @register_jitable
    def bounded(v, lo, hi):
        # the ranges are numbers: an open one adds no term to a symbolic expression
        if lo > -INF or hi < INF:
            return clip(v, lo, hi)
        return v

    @register_jitable
    def force_of(p, cart_pos, cart_vel, u):
        length, speed = p.gear * cart_pos, p.gear * cart_vel
        uc = bounded(u, p.ctrl_min, p.ctrl_max)
        force = ((p.gain + p.gain_length * length + p.gain_velocity * speed) * uc
                 + p.bias + p.bias_length * length + p.bias_velocity * speed)
        return bounded(p.gear * bounded(force, p.force_min, p.force_max),
                       p.joint_force_min, p.joint_force_max)

    def accelerations_of(p, q, w, cart_pos, cart_vel, u, d):
        sg = p.theta_sign
        ar, ag = sg * q + p.rail_phase, sg * q + p.gravity_phase
        lr, lg = p.m * p.l * p.rail_coupling, p.m * p.l * p.gravity_coupling
        mm = p.M + p.m
        q_x = (force_of(p, cart_pos, cart_vel, u) - p.cart_damping * cart_vel
               - dry(p.cart_friction, cart_vel) - p.cart_stiffness * (cart_pos - p.cart_spring_ref))
        q_q = (p.disturbance_torque * d - p.hinge_damping * w - dry(p.hinge_friction, w)
               - p.hinge_stiffness * (q - p.hinge_spring_ref))
        b = -sg * lr * cos(ar)                               # m X'(q)
        rhs_x = q_x + mm * p.rail_gravity - lr * sin(ar) * w * w
        rhs_q = q_q + sg * lg * p.g * sin(ag)                # - m g H'(q)
        det = mm * p.J - b * b
        return (mm * rhs_q - b * rhs_x) / det, (p.J * rhs_x - b * rhs_q) / det

    return accelerations_of, force_of


_numeric, _force = accelerations_factory(math.sin, math.cos, math.tanh)

#: ``(q'', x'')`` of (C1)-(C2) in the model's angle convention, as
#: ``machine_accelerations(p: CartPoleMachine, q, w, cart_pos, cart_vel, u, d)``: plain
#: Python when called from Python; compiled inline when called from numba code (the
#: compiled closed loop, :mod:`tspend.loop.fastloop`)
machine_accelerations = register_jitable(_numeric)
#: the actuator's force at the cart, ``F(u, x, x')`` of the module docstring
machine_force = register_jitable(_force)


def _as_machine(p: CartPoleParams | CartPoleMachine) -> CartPoleMachine:
    return p if isinstance(p, CartPoleMachine) else machine_of(p)


def accelerations(p: CartPoleParams | CartPoleMachine, theta: float, w: float,
                  cart_vel: float, u: float, d: float, cart_pos: float = 0.0
                  ) -> tuple[float, float]:
    """``(q'', x'')`` of (C1)-(C2), evaluated in Python (pass a :class:`CartPoleMachine`
    when calling often: resolving the parameters each call costs more than the math)."""
    return machine_accelerations(_as_machine(p), theta, w, cart_pos, cart_vel, u, d)


def actuator_force(p: CartPoleParams | CartPoleMachine, u: float, cart_pos: float = 0.0,
                   cart_vel: float = 0.0) -> float:
    """The force the actuator applies at the cart, N (ranges applied)."""
    return machine_force(_as_machine(p), cart_pos, cart_vel, u)


def actuator_force_range(p: CartPoleParams | CartPoleMachine, u_lo: float = -INF,
                         u_hi: float = INF) -> tuple[float, float]:
    """The least and the largest force the actuator puts on the cart at rest (x = 0,
    x' = 0) for u in ``[u_lo, u_hi]`` and its own ranges (+/-inf: unbounded)."""
    machine = _as_machine(p)
    lo, hi = max(u_lo, machine.ctrl_min), min(u_hi, machine.ctrl_max)
    huge = 1e300   # an unbounded u: the force ranges, if any, bound the force
    ends = [actuator_force(machine, v) for v in (max(lo, -huge), min(hi, huge))]
    ends = [math.copysign(INF, f) if abs(f) >= 1e250 else f for f in ends]
    return min(ends), max(ends)


def inverse_dynamics(p: CartPoleParams | CartPoleMachine, q: float, w: float, q_dd: float,
                     cart_vel: float, d: float) -> tuple[float, float]:
    """``(F, x'')``: the actuator force and the cart acceleration that give the pole
    ``q'' = q_dd`` at ``(q, q')`` with the cart moving at ``cart_vel`` ((C2) solved for x'',
    then (C1) for F; the cart's spring is left out: the cart's position is free).
    ``F`` is +/-inf where the rail cannot move the pole (``X'(q) = 0``)."""
    m = _as_machine(p)
    sg = m.theta_sign
    ar, ag = sg * q + m.rail_phase, sg * q + m.gravity_phase
    lr, lg = m.m * m.l * m.rail_coupling, m.m * m.l * m.gravity_coupling
    mm = m.M + m.m
    b = -sg * lr * math.cos(ar)
    q_q = (m.disturbance_torque * d - m.hinge_damping * w
           - (m.hinge_friction * math.tanh(w / DRY_FRICTION_SLIP) if m.hinge_friction > 0 else 0.0)
           - m.hinge_stiffness * (q - m.hinge_spring_ref))
    rhs_q = q_q + sg * lg * m.g * math.sin(ag)
    if b == 0.0:
        return math.copysign(INF, rhs_q - m.J * q_dd), math.nan
    x_dd = (rhs_q - m.J * q_dd) / b
    dry = m.cart_friction * math.tanh(cart_vel / DRY_FRICTION_SLIP) if m.cart_friction > 0 else 0.0
    force = (mm * x_dd + b * q_dd - mm * m.rail_gravity + lr * math.sin(ar) * w * w
             + m.cart_damping * cart_vel + dry)
    return force, x_dd


def gain_sign(p: CartPoleParams) -> float:
    """Sign of d(q'')/du at the upright, at rest: Assumption 5's sign (0: u cannot
    move the pole, a hinge parallel to the rail)."""
    diff = (accelerations(p, 0.0, 0.0, 0.0, 1e-3, 0.0)[0]
            - accelerations(p, 0.0, 0.0, 0.0, 0.0, 0.0)[0])
    return 0.0 if diff == 0.0 else math.copysign(1.0, diff)


@register_jitable
def pole_energy(p: CartPoleMachine, q: float, w: float) -> float:
    """The pole's energy about its hinge, J, 0 upright at rest (the centre of mass at its
    highest), ``-2 m g l k_g`` hanging: ``E = 1/2 J q'^2 + m g (H(q) - l k_g)`` with
    ``H`` of the module docstring (the paper's pole: ``1/2 J theta'^2 + m g l (cos theta
    - 1)``).

    By (C2) its rate is ``E' = q' (Q_q - m X'(q) x'')``: the cart's acceleration is the
    only way in besides the hinge's own torques (Astrom and Furuta, 2000, eq. 4;
    swing-up, :mod:`tspend.controllers.swingup`).
    """
    lg = p.m * p.l * p.gravity_coupling
    return 0.5 * p.J * w * w + lg * p.g * (math.cos(p.theta_sign * q + p.gravity_phase) - 1.0)


def rhs(p: CartPoleParams | CartPoleMachine, s: np.ndarray, u: float, d: float) -> np.ndarray:
    """Derivative of ``[q, q', x, x']``."""
    thdd, xdd = accelerations(p, s[0], s[1], s[3], u, d, s[2])
    return np.array([s[1], thdd, s[3], xdd])


@register_jitable
def machine_rhs(p: CartPoleMachine, t: float, s: np.ndarray, u: float, d: float,
                sdot: np.ndarray) -> None:
    """:func:`rhs` into ``sdot``, for :func:`tspend.plants.analytic.rk4_step`."""
    thdd, xdd = machine_accelerations(p, s[0], s[1], s[2], s[3], u, d)
    sdot[0] = s[1]
    sdot[1] = thdd
    sdot[2] = s[3]
    sdot[3] = xdd
