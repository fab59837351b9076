"""The cart-pole's equations of motion, written once (docs/paper-notes.md section 7).

Coordinates: cart position ``x`` along the rail, pole angle ``theta`` from the upright,
``theta > 0`` leaning the pole toward -x.  With the pole's mass ``m`` at ``l`` from the
pivot, its inertia ``J`` about the pivot and the cart's mass ``M``, Lagrange gives

    (M + m) x''          - m l cos(theta) theta'' = Q_x     - m l sin(theta) theta'^2   (C1)
    - m l cos(theta) x'' + J theta''              = Q_theta + m g l sin(theta)         (C2)

with the generalised forces ``Q_x = u - b_x x' - F_x dry(x')`` (the motor force, viscous
and dry friction at the cart) and ``Q_theta = tau - b_th theta' - F_th dry(theta')``.
For the paper's uniform rod ``J = 4/3 m l^2``, no friction and ``tau = -d_d m l / (M + m)``
this is exactly Example 3's ODE

    theta'' = (m l w^2 sin cos - (M+m) g sin - u cos + d_d) / (m l cos^2 - 4/3 l (M+m)).

Dry friction is smooth here, ``F tanh(v / v_s)``, so an RK4 step stays well defined; MuJoCo's
``frictionloss`` is a soft constraint instead, so on dry friction the two backends agree
in kind, not to rounding (the cross-check names it as a departure).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba.extending import register_jitable

__all__ = ["CartPoleParams", "CartPoleMachine", "DRY_FRICTION_SLIP", "accelerations",
           "gain_sign", "linearize", "machine_accelerations", "machine_rhs", "rhs"]


#: slip velocity of the smooth dry friction F tanh(v / v_s), m/s or rad/s
DRY_FRICTION_SLIP = 1e-3


@dataclass(frozen=True)
class CartPoleParams:
    """One cart-pole machine: the paper's M, m, l, g, and what a real rig adds.

    ``J`` is the pole's inertia about the pivot (0 = the uniform rod's 4/3 m l^2);
    ``gear`` is the force in newtons per unit of u; ``theta_sign`` is -1 when the
    model's positive angle leans the pole toward +x (a reversed hinge axis).
    """

    M: float = 10.0
    m: float = 1.0
    l: float = 3.0
    g: float = 9.8
    J: float = 0.0
    cart_damping: float = 0.0
    hinge_damping: float = 0.0
    cart_friction: float = 0.0
    hinge_friction: float = 0.0
    gear: float = 1.0
    theta_sign: float = 1.0

    @property
    def pole_inertia_pivot(self) -> float:
        return self.J if self.J > 0.0 else 4.0 / 3.0 * self.m * self.l ** 2

    @property
    def disturbance_torque(self) -> float:
        """Hinge torque per unit d_d: ``tau = -d_d m l / (M + m)`` enters (C2) like d_d
        enters the paper's numerator (exact for the rod, the paper's meaning otherwise)."""
        return -self.m * self.l / (self.M + self.m)

    def machine(self) -> "CartPoleMachine":
        """These parameters as compiled code reads them (the properties resolved)."""
        return CartPoleMachine(
            M=self.M, m=self.m, l=self.l, g=self.g, J=self.pole_inertia_pivot,
            disturbance_torque=self.disturbance_torque, cart_damping=self.cart_damping,
            hinge_damping=self.hinge_damping, cart_friction=self.cart_friction,
            hinge_friction=self.hinge_friction, gear=self.gear, theta_sign=self.theta_sign)


class CartPoleMachine(NamedTuple):
    """:class:`CartPoleParams` with ``J`` the inertia about the pivot and the hinge torque
    per unit d_d resolved: a structure numba can pass by value."""

    M: float
    m: float
    l: float
    g: float
    J: float
    disturbance_torque: float
    cart_damping: float
    hinge_damping: float
    cart_friction: float
    hinge_friction: float
    gear: float
    theta_sign: float

    def rhs_into(self, t: float, s: np.ndarray, u: float, d: float, sdot: np.ndarray) -> None:
        machine_rhs(self, t, s, u, d, sdot)


def accelerations_factory(sin, cos, tanh):
    """``(theta'', x'')`` of (C1)-(C2) built over the math functions ``(sin, cos, tanh)``.

    The equations are written once, here: ``math``'s functions give
    :func:`machine_accelerations` (plain Python, and inlined by numba into compiled
    loops); CasADi's ``(casadi.sin, casadi.cos, casadi.tanh)`` give the same expressions
    symbolically, for nonlinear MPC (:mod:`tspend.controllers.mpc`).  The parameters
    ``p`` are numbers in both cases (the branch on a friction force is on a number).
    """

    @register_jitable
    def dry(force, v):
        return force * tanh(v / DRY_FRICTION_SLIP) if force > 0.0 else 0.0

    def accelerations_of(p, theta, w, cart_vel, u, d):
        s_th = p.theta_sign
        th, om = s_th * theta, s_th * w
        sn, cs = sin(th), cos(th)
        ml, mm = p.m * p.l, p.M + p.m
        q_x = p.gear * u - p.cart_damping * cart_vel - dry(p.cart_friction, cart_vel) - ml * sn * om * om
        # the hinge's own torques act on the model's angle; in the paper's they change sign
        q_model = p.disturbance_torque * d - p.hinge_damping * w - dry(p.hinge_friction, w)
        q_th = s_th * q_model + ml * p.g * sn
        b = ml * cs
        J = p.J
        det = mm * J - b * b
        thdd = (mm * q_th + b * q_x) / det
        xdd = (J * q_x + b * q_th) / det
        return s_th * thdd, xdd

    return accelerations_of


#: ``(theta'', x'')`` of (C1)-(C2) in the model's angle convention (``theta_sign``), as
#: ``machine_accelerations(p: CartPoleMachine, theta, w, cart_vel, u, d)``: plain Python
#: when called from Python; compiled inline when called from numba code (the compiled
#: closed loop, :mod:`tspend.loop.fastloop`)
machine_accelerations = register_jitable(accelerations_factory(math.sin, math.cos, math.tanh))


def accelerations(p: CartPoleParams | CartPoleMachine, theta: float, w: float,
                  cart_vel: float, u: float, d: float) -> tuple[float, float]:
    """``(theta'', x'')`` of (C1)-(C2), evaluated in Python (pass a :class:`CartPoleMachine`
    when calling often: resolving the parameters each call costs more than the math)."""
    machine = p if isinstance(p, CartPoleMachine) else p.machine()
    return machine_accelerations(machine, theta, w, cart_vel, u, d)


def gain_sign(p: CartPoleParams) -> float:
    """Sign of d(theta'')/du at the upright, at rest: Assumption 5's sign."""
    return math.copysign(1.0, accelerations(p, 0.0, 0.0, 0.0, 1.0, 0.0)[0]
                         - accelerations(p, 0.0, 0.0, 0.0, 0.0, 0.0)[0])


def linearize(p: CartPoleParams | CartPoleMachine, theta: float = 0.0,
              u: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Continuous-time ``A, B`` of (C1)-(C2) at rest at pole angle ``theta``, input ``u``.

    The exact Jacobian: at rest every velocity-product term and its first derivative
    vanish, so with ``det = (M + m) J - b^2``, ``b = m l cos(theta)``,
    ``theta''_p = ((M + m) Q_theta + b Q_x) / det`` and ``x'' = (J Q_x + b Q_theta) / det``
    each column is the quotient rule on the generalised forces' slopes (the smooth dry
    friction's is ``F / v_s`` at rest).  ``theta = 0`` is the upright.

    Returns
    -------
    A : (4, 4) array
        over ``[x, theta, x', theta']`` (the MJCF's ``slider, hinge, slider_dot,
        hinge_dot``).
    B : (4, 1) array
        per unit of u.
    """
    mc = p if isinstance(p, CartPoleMachine) else p.machine()
    s_th = mc.theta_sign
    th = s_th * theta
    sn, cs = math.sin(th), math.cos(th)
    ml, mm, J = mc.m * mc.l, mc.M + mc.m, mc.J
    b = ml * cs
    det = mm * J - b * b
    q_x = mc.gear * u                       # at rest: no friction, no centripetal term
    q_th = ml * mc.g * sn
    thdd = (mm * q_th + b * q_x) / det      # the paper's angle
    xdd = (J * q_x + b * q_th) / det
    # slopes in the paper's angle th = s_th theta, then back to the model's
    db = -ml * sn
    ddet = -2.0 * b * db
    dq_th = ml * mc.g * cs
    dthdd_dth = (mm * dq_th + db * q_x - thdd * ddet) / det
    dxdd_dth = (db * q_th + b * dq_th - xdd * ddet) / det
    dq_x_dv = -mc.cart_damping - (mc.cart_friction / DRY_FRICTION_SLIP if mc.cart_friction > 0.0 else 0.0)
    dq_model_dw = -mc.hinge_damping - (mc.hinge_friction / DRY_FRICTION_SLIP
                                       if mc.hinge_friction > 0.0 else 0.0)
    dq_th_dw = s_th * dq_model_dw           # Q_theta's slope in the model's angular rate
    A = np.zeros((4, 4))
    A[0, 2] = A[1, 3] = 1.0
    # x'' row: d/dtheta = d/dth * s_th; d/dx' via Q_x; d/dw via Q_theta
    A[2, 1] = dxdd_dth * s_th
    A[2, 2] = J * dq_x_dv / det
    A[2, 3] = b * dq_th_dw / det
    # theta'' = s_th theta''_p
    A[3, 1] = s_th * dthdd_dth * s_th
    A[3, 2] = s_th * b * dq_x_dv / det
    A[3, 3] = s_th * mm * dq_th_dw / det
    B = np.array([[0.0], [0.0], [J * mc.gear / det], [s_th * b * mc.gear / det]])
    return A, B


def rhs(p: CartPoleParams | CartPoleMachine, s: np.ndarray, u: float, d: float) -> np.ndarray:
    """Derivative of ``[theta, theta', x, x']``."""
    thdd, xdd = accelerations(p, s[0], s[1], s[3], u, d)
    return np.array([s[1], thdd, s[3], xdd])


@register_jitable
def machine_rhs(p: CartPoleMachine, t: float, s: np.ndarray, u: float, d: float,
                sdot: np.ndarray) -> None:
    """:func:`rhs` into ``sdot``, for :func:`tspend.plants.analytic.rk4_step`."""
    thdd, xdd = machine_accelerations(p, s[0], s[1], s[3], u, d)
    sdot[0] = s[1]
    sdot[1] = thdd
    sdot[2] = s[3]
    sdot[3] = xdd


