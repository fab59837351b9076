"""Test oracle: the rotary inverted (Furuta) pendulum's equations of motion written by hand
(docs/furuta.md), as tspend stepped them before its equations were derived from the model
(tspend/plants/articulated/); tests/test_articulated.py holds the derived ones to these.

Coordinates, as MuJoCo's ``qpos``/``qvel`` of ``models/furuta.xml``: the state is
``[arm, pendulum, arm_vel, pendulum_vel]`` (rad, rad/s); ``arm`` turns about the motor's
vertical axis, ``pendulum`` about a second hinge carried by the arm; ``pendulum = 0`` is
the model's reference pose (upright in models/furuta.xml, ``pi`` hanging).

Both bodies are full 3D rigid bodies.  The arm turns about a fixed vertical axis ``z``, so
only its inertia about ``z`` matters.  The pendulum, mass ``m``, turns about the unit axis
``a`` through the point ``p`` of the arm; at ``pendulum = 0`` its COM is ``c0`` from ``p``
and its inertia about the COM is ``Ic`` (all in the arm's frame).  With
``R(pendulum)`` the rotation about ``a``, Lagrange gives (docs/furuta.md derives it)

    M(al) [th'', al'']^T = [tau - D_r th' - dm11 al' th' - dm12 al'^2,
                            d   - D_p al' + 1/2 dm11 th'^2 - dV]^T

with ``th = arm``, ``al = pendulum``, ``dX = dX/d al``, the mass matrix

    m11 = J_arm + m |z x p|^2 + 2 m (z x p).(z x R c0) + z^T R I_p R^T z
    m12 = z^T R I_p a + m (z x p).(a x R c0)
    m22 = a^T I_p a                       (+ each joint's armature on its diagonal)

(``I_p`` the pendulum's inertia about the pivot at ``pendulum = 0``), the potential
``V = m g z.(R c0)`` and the motor torque ``tau`` of MuJoCo's affine actuator (below).  The
only angle that enters is ``al``, through ``R``: Rodrigues' formula makes every entry a
trigonometric polynomial, so :class:`FurutaMachine` holds their coefficients

    m11 = a0 + a1 cos al + a2 sin al + a3 cos 2al + a4 sin 2al
    m12 = b0 + b1 cos al + b2 sin al,       V = v_c cos al + v_s sin al (+ const)

and :func:`machine_accelerations` evaluates them, their derivatives and the 2x2 solve.

The motor is MuJoCo's ``general`` actuator on the arm joint, exactly:
``tau = gear * clip(gain * clip(u, ctrl_range) + b0 + b1 gear arm + b2 gear arm_vel,
force_range)``; with gear 1, ``gain = k_t/R_m``, ``b2 = -k_t k_m/R_m`` this is the DC
motor ``tau = k_t (V - k_m arm_vel) / R_m`` driven by the voltage ``u`` (volts).  ``d`` is a
disturbance torque on the pendulum joint (N m), MuJoCo's ``qfrc_applied`` there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import mujoco
import numpy as np
from numba.extending import register_jitable

__all__ = [
    "QUBE_R_M_OHM", "QUBE_K_T_NM_PER_A", "QUBE_K_M_V_S_PER_RAD", "QUBE_J_ROTOR_KG_M2",
    "QUBE_J_HUB_KG_M2", "QUBE_ARM_MASS_KG", "QUBE_ARM_LENGTH_M", "QUBE_PENDULUM_MASS_KG",
    "QUBE_PENDULUM_LENGTH_M", "QUBE_ARM_DAMPING_NMS", "QUBE_PENDULUM_DAMPING_NMS",
    "QUBE_VOLTAGE_LIMIT_V", "GRAVITY_M_S2", "AXIAL_INERTIA_RATIO",
    "FurutaParams", "FurutaMachine", "machine_accelerations", "machine_rhs", "motor_torque",
    "accelerations", "accelerations_factory", "clip", "linearize", "mass_terms",
    "params_from_model", "pendulum_energy",
]

# -- the QUBE-Servo 2 and its rotary pendulum module (sources: docs/furuta.md) ------------
QUBE_R_M_OHM = 8.4                 #: motor terminal resistance
QUBE_K_T_NM_PER_A = 0.042          #: motor torque constant
QUBE_K_M_V_S_PER_RAD = 0.042       #: motor back-EMF constant
QUBE_J_ROTOR_KG_M2 = 4.0e-6        #: motor rotor inertia
QUBE_J_HUB_KG_M2 = 0.6e-6          #: module attachment hub inertia
QUBE_ARM_MASS_KG = 0.095           #: rotary arm
QUBE_ARM_LENGTH_M = 0.085          #: rotary arm, motor axis (pivot) to its end
QUBE_PENDULUM_MASS_KG = 0.024      #: pendulum link
QUBE_PENDULUM_LENGTH_M = 0.129     #: pendulum link, pivot to its end
QUBE_ARM_DAMPING_NMS = 0.0015      #: arm's equivalent viscous damping, N m s/rad
QUBE_PENDULUM_DAMPING_NMS = 0.0005  #: pendulum's equivalent viscous damping, N m s/rad
QUBE_VOLTAGE_LIMIT_V = 10.0        #: amplifier's recommended output range, +/-
GRAVITY_M_S2 = 9.81                #: Quanser's g
#: a rod's inertia about its own axis relative to the transverse one: not published, tiny
#: but positive (the value of models/cartpole.xml and tspend.plants.mjcf)
AXIAL_INERTIA_RATIO = 1.0 / 3e4

_QUBE_PENDULUM_TRANSVERSE = QUBE_PENDULUM_MASS_KG * QUBE_PENDULUM_LENGTH_M ** 2 / 12.0


@dataclass(frozen=True)
class FurutaParams:
    """One Furuta pendulum, by default the QUBE-Servo 2 with its rotary pendulum module.

    Vectors are in one fixed frame at ``arm = pendulum = 0``, where the arm's frame is
    taken (the world's in :func:`params_from_model`; for the QUBE: z up along the motor
    axis, x along the arm).  Only what the dynamics see is kept: the arm body enters
    through its inertia about the motor axis alone.

    Attributes
    ----------
    gravity : float
        g, m/s^2, acting along ``-arm_axis`` (negative if the axis points down).
    arm_axis : tuple of 3 floats
        the motor's axis (unit after normalisation); positive ``arm`` turns about it.
    arm_inertia : float
        kg m^2, the arm body about the motor axis (the QUBE's rod: m_r L_r^2 / 3).
    arm_armature : float
        kg m^2, inertia added to the arm's diagonal (the QUBE's rotor and hub, J_m + J_h).
    pivot : tuple of 3 floats
        m, from a point of the motor axis to a point of the pendulum's axis (L_r along x).
    pendulum_axis : tuple of 3 floats
        the pendulum hinge's axis (unit after normalisation).
    pendulum_mass : float
        kg.
    pendulum_com : tuple of 3 floats
        m, the pendulum's COM from ``pivot`` at ``pendulum = 0`` (L_p/2 up).
    pendulum_inertia : tuple of 6 floats
        kg m^2, about the pendulum's COM at ``pendulum = 0``: (xx, yy, zz, xy, xz, yz) as
        MuJoCo's ``fullinertia`` (the QUBE's rod: m_p L_p^2/12 transverse, tiny axially).
    pendulum_armature : float
        kg m^2, inertia added to the pendulum's diagonal.
    arm_damping, pendulum_damping : float
        N m s/rad, viscous damping of each joint.
    motor_gear : float
        MuJoCo's actuator gear (dimensionless for a hinge): torque = gear * force.
    motor_gain : float
        N m/V, actuator force per volt, k_t / R_m.
    motor_bias : float
        N m, constant actuator force.
    motor_bias_position : float
        N m/rad, actuator force per unit of its length (gear * arm).
    motor_bias_velocity : float
        N m s/rad, actuator force per unit of its velocity (gear * arm_vel): the back-EMF's
        -k_t k_m / R_m.
    ctrl_range : tuple of 2 floats
        V, the clip applied to u (infinite: none).
    force_range : tuple of 2 floats
        N m, the clip applied to the actuator force (infinite: none).
    """

    gravity: float = GRAVITY_M_S2
    arm_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    arm_inertia: float = QUBE_ARM_MASS_KG * QUBE_ARM_LENGTH_M ** 2 / 3.0
    arm_armature: float = QUBE_J_ROTOR_KG_M2 + QUBE_J_HUB_KG_M2
    pivot: tuple[float, float, float] = (QUBE_ARM_LENGTH_M, 0.0, 0.0)
    pendulum_axis: tuple[float, float, float] = (1.0, 0.0, 0.0)
    pendulum_mass: float = QUBE_PENDULUM_MASS_KG
    pendulum_com: tuple[float, float, float] = (0.0, 0.0, QUBE_PENDULUM_LENGTH_M / 2.0)
    pendulum_inertia: tuple[float, float, float, float, float, float] = (
        _QUBE_PENDULUM_TRANSVERSE, _QUBE_PENDULUM_TRANSVERSE,
        _QUBE_PENDULUM_TRANSVERSE * AXIAL_INERTIA_RATIO, 0.0, 0.0, 0.0)
    pendulum_armature: float = 0.0
    arm_damping: float = QUBE_ARM_DAMPING_NMS
    pendulum_damping: float = QUBE_PENDULUM_DAMPING_NMS
    motor_gear: float = 1.0
    motor_gain: float = QUBE_K_T_NM_PER_A / QUBE_R_M_OHM
    motor_bias: float = 0.0
    motor_bias_position: float = 0.0
    motor_bias_velocity: float = -QUBE_K_T_NM_PER_A * QUBE_K_M_V_S_PER_RAD / QUBE_R_M_OHM
    ctrl_range: tuple[float, float] = (-QUBE_VOLTAGE_LIMIT_V, QUBE_VOLTAGE_LIMIT_V)
    force_range: tuple[float, float] = (-math.inf, math.inf)

    def pendulum_inertia_matrix(self) -> np.ndarray:
        """The pendulum's inertia about its COM at ``pendulum = 0`` as a 3x3 matrix, kg m^2."""
        xx, yy, zz, xy, xz, yz = self.pendulum_inertia
        return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]], dtype=float)

    def machine(self) -> "FurutaMachine":
        """These parameters as compiled code reads them: the Lagrangian's coefficients.

        Rodrigues: ``R v = (a.v) a + cos(al) (v - (a.v) a) + sin(al) a x v``, so the COM
        ``R c0 = u0 + cos u1 + sin u2`` and ``R^T z = w0 + cos w1 + sin w2``; products of
        two such expansions bring in ``cos^2 = (1 + cos 2al)/2``, ``sin^2`` and ``sin cos``.
        """
        z = _unit(self.arm_axis, "arm_axis")
        a = _unit(self.pendulum_axis, "pendulum_axis")
        p = np.asarray(self.pivot, dtype=float)
        c0 = np.asarray(self.pendulum_com, dtype=float)
        m = float(self.pendulum_mass)
        # inertia about the pivot (parallel axis), at pendulum = 0
        I_p = self.pendulum_inertia_matrix() + m * (float(c0 @ c0) * np.eye(3) - np.outer(c0, c0))
        u = (float(a @ c0) * a, c0 - float(a @ c0) * a, np.cross(a, c0))
        w0 = float(a @ z) * a
        w = (w0, z - w0, -np.cross(a, z))
        zp = np.cross(z, p)
        # (z x p).(z x R c0) and (z x p).(a x R c0), term by term of R c0
        h = [float(zp @ np.cross(z, uk)) for uk in u]
        k = [float(zp @ np.cross(a, uk)) for uk in u]
        q = np.array([[float(wi @ I_p @ wj) for wj in w] for wi in w])
        return FurutaMachine(
            a0=self.arm_inertia + self.arm_armature + m * float(zp @ zp) + 2.0 * m * h[0]
            + q[0, 0] + 0.5 * (q[1, 1] + q[2, 2]),
            a1=2.0 * m * h[1] + 2.0 * q[0, 1],
            a2=2.0 * m * h[2] + 2.0 * q[0, 2],
            a3=0.5 * (q[1, 1] - q[2, 2]),
            a4=q[1, 2],
            b0=float(w[0] @ I_p @ a) + m * k[0],
            b1=float(w[1] @ I_p @ a) + m * k[1],
            b2=float(w[2] @ I_p @ a) + m * k[2],
            m22=float(a @ I_p @ a) + self.pendulum_armature,
            v_c=m * self.gravity * float(z @ u[1]),
            v_s=m * self.gravity * float(z @ u[2]),
            arm_damping=float(self.arm_damping), pendulum_damping=float(self.pendulum_damping),
            motor_gear=float(self.motor_gear), motor_gain=float(self.motor_gain),
            motor_bias=float(self.motor_bias),
            motor_bias_position=float(self.motor_bias_position),
            motor_bias_velocity=float(self.motor_bias_velocity),
            u_min=float(self.ctrl_range[0]), u_max=float(self.ctrl_range[1]),
            force_min=float(self.force_range[0]), force_max=float(self.force_range[1]))


def _unit(v: tuple[float, float, float], name: str) -> np.ndarray:
    x = np.asarray(v, dtype=float)
    n = float(np.linalg.norm(x))
    if not (n > 0.0 and math.isfinite(n)):
        raise ValueError(f"{name} must be a nonzero finite vector, got {v}")
    return x / n


class FurutaMachine(NamedTuple):
    """:class:`FurutaParams` resolved into the coefficients of the equations of motion: a
    structure numba passes by value.

    ``m11 = a0 + a1 cos + a2 sin + a3 cos 2al + a4 sin 2al`` (kg m^2),
    ``m12 = b0 + b1 cos + b2 sin`` (kg m^2), ``m22`` (kg m^2),
    ``V = v_c cos + v_s sin`` (N m); the rest as in :class:`FurutaParams`, with the ranges
    split into ``u_min, u_max`` (V) and ``force_min, force_max`` (N m).
    """

    a0: float
    a1: float
    a2: float
    a3: float
    a4: float
    b0: float
    b1: float
    b2: float
    m22: float
    v_c: float
    v_s: float
    arm_damping: float
    pendulum_damping: float
    motor_gear: float
    motor_gain: float
    motor_bias: float
    motor_bias_position: float
    motor_bias_velocity: float
    u_min: float
    u_max: float
    force_min: float
    force_max: float

    def rhs_into(self, t: float, s: np.ndarray, u: float, d: float, sdot: np.ndarray) -> None:
        """For :func:`tspend.plants.analytic.rk4_step` called from Python."""
        machine_rhs(self, t, s, u, d, sdot)


@register_jitable
def clip(v: float, lo: float, hi: float) -> float:
    """``v`` clipped to ``[lo, hi]``, as MuJoCo clips ctrl and the actuator force."""
    return min(max(v, lo), hi)


def accelerations_factory(sin, cos, tanh, clip=clip):
    """``(motor_torque, mass_terms, accelerations)`` built over the math functions
    ``(sin, cos, tanh)`` and the clip ``clip(v, lo, hi)``.

    The equations are written once, here (as
    :func:`tspend.studies.cartpole_greybox.accelerations_factory` for the cart-pole): ``math``'s functions and :func:`clip` give :func:`motor_torque`,
    :func:`mass_terms` and :func:`machine_accelerations` (plain Python, inlined by numba in
    compiled code); CasADi's ``(casadi.sin, casadi.cos, casadi.tanh)`` give the same
    expressions symbolically for nonlinear MPC (:mod:`tspend.controllers.mpc`), with an
    identity ``clip``: the MPC bounds ``u`` to the control range, where MuJoCo's clip of
    ``u`` is inactive (the QUBE's force range is infinite).  ``tanh`` is unused: the
    Furuta's friction is viscous only.  ``p`` is a :class:`FurutaMachine` of numbers.
    """

    @register_jitable
    def motor_torque_of(p, arm, arm_vel, u):
        v = clip(u, p.u_min, p.u_max)
        force = (p.motor_gain * v + p.motor_bias + p.motor_bias_position * p.motor_gear * arm
                 + p.motor_bias_velocity * p.motor_gear * arm_vel)
        return p.motor_gear * clip(force, p.force_min, p.force_max)

    @register_jitable
    def mass_terms_of(p, al):
        sn, cs = sin(al), cos(al)
        s2, c2 = 2.0 * sn * cs, cs * cs - sn * sn
        m11 = p.a0 + p.a1 * cs + p.a2 * sn + p.a3 * c2 + p.a4 * s2
        dm11 = -p.a1 * sn + p.a2 * cs - 2.0 * p.a3 * s2 + 2.0 * p.a4 * c2
        m12 = p.b0 + p.b1 * cs + p.b2 * sn
        dm12 = -p.b1 * sn + p.b2 * cs
        dV = -p.v_c * sn + p.v_s * cs
        ddV = -p.v_c * cs - p.v_s * sn
        return m11, m12, dm11, dm12, dV, ddV

    def accelerations_of(p, s, u, d):
        th, al, thd, ald = s[0], s[1], s[2], s[3]
        m11, m12, dm11, dm12, dV, _ = mass_terms_of(p, al)
        # generalised forces minus the velocity-product terms of d/dt dL/dq' - dL/dq
        f1 = (motor_torque_of(p, th, thd, u) - p.arm_damping * thd
              - dm11 * ald * thd - dm12 * ald * ald)
        f2 = d - p.pendulum_damping * ald + 0.5 * dm11 * thd * thd - dV
        det = m11 * p.m22 - m12 * m12
        return (p.m22 * f1 - m12 * f2) / det, (m11 * f2 - m12 * f1) / det

    return motor_torque_of, mass_terms_of, accelerations_of


_motor_torque, _mass_terms, _accelerations = accelerations_factory(math.sin, math.cos, math.tanh)

#: Torque of MuJoCo's affine ``general`` actuator on the arm joint, N m, as
#: ``motor_torque(p: FurutaMachine, arm, arm_vel, u)``: ``u`` (volts) is clipped to the
#: control range first, the force to the force range after, as MuJoCo does; with the
#: QUBE's numbers ``k_t (V - k_m arm_vel) / R_m``.
motor_torque = _motor_torque

#: ``m11, m12`` and their derivatives in ``al``, then ``dV/dal`` and ``d2V/dal2``, as
#: ``mass_terms(p: FurutaMachine, al)``
mass_terms = _mass_terms

#: ``(arm'', pendulum'')`` at the state ``s = [arm, pendulum, arm_vel, pendulum_vel]``
#: (rad, rad, rad/s, rad/s), as ``machine_accelerations(p: FurutaMachine, s, u, d)`` with
#: ``u`` the motor voltage (V, clipped to the control range) and ``d`` a disturbance
#: torque on the pendulum joint (N m); rad/s^2.  Plain Python when called from Python;
#: compiled inline from numba code.
machine_accelerations = register_jitable(_accelerations)


@register_jitable
def pendulum_energy(p: "FurutaMachine", pendulum: float, pendulum_vel: float) -> float:
    """The pendulum's energy about its pivot in the arm's frame, J, 0 upright at rest:
    ``E = 1/2 m22 al'^2 + V(al) - V(0)`` with ``V = v_c cos al + v_s sin al``.

    Its rate is ``E' = al' (m22 al'' + dV/dal)``: by the pendulum's equation it changes
    only through the arm (``-m12 th'' + 1/2 dm11 th'^2``) and the damping (swing-up,
    :mod:`tspend.controllers.swingup`).
    """
    return (0.5 * p.m22 * pendulum_vel * pendulum_vel
            + p.v_c * (math.cos(pendulum) - 1.0) + p.v_s * math.sin(pendulum))


@register_jitable
def machine_rhs(p: FurutaMachine, t: float, s: np.ndarray, u: float, d: float,
                sdot: np.ndarray) -> None:
    """Derivative of ``s = [arm, pendulum, arm_vel, pendulum_vel]`` into ``sdot`` (the
    signature of :func:`tspend.plants.analytic.rk4_step`'s right-hand side)."""
    thdd, aldd = machine_accelerations(p, s, u, d)
    sdot[0] = s[2]
    sdot[1] = s[3]
    sdot[2] = thdd
    sdot[3] = aldd


def accelerations(p: FurutaParams | FurutaMachine, s: np.ndarray, u: float,
                  d: float = 0.0) -> tuple[float, float]:
    """:func:`machine_accelerations` from Python, for parameters or a machine (pass a
    machine when calling often: resolving the parameters costs more than the math)."""
    machine = p if isinstance(p, FurutaMachine) else p.machine()
    return machine_accelerations(machine, np.asarray(s, dtype=float), float(u), float(d))


def linearize(p: FurutaParams | FurutaMachine, pendulum: float = 0.0, arm: float = 0.0,
              u: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Continuous-time ``A, B`` of ``s' = f(s, u)`` at rest at ``(arm, pendulum)``, input ``u``.

    The exact Jacobian: at rest the velocity-product terms and their first derivatives
    vanish, so with ``q'' = M^-1 f``, ``dq''/dal = M^-1 (df/dal - dM/dal q'')`` and every
    other column is ``M^-1`` times the derivative of the generalised forces.  ``pendulum =
    0`` is the upright of models/furuta.xml, ``pi`` the hanging position.

    Returns
    -------
    A : (4, 4) array
        over ``[arm, pendulum, arm_vel, pendulum_vel]``.
    B : (4, 1) array
        per volt.
    """
    mc = p if isinstance(p, FurutaMachine) else p.machine()
    m11, m12, dm11, dm12, _, ddV = _mass_terms(mc, pendulum)
    M = np.array([[m11, m12], [m12, mc.m22]])
    dM = np.array([[dm11, dm12], [dm12, 0.0]])
    qdd = np.array(machine_accelerations(mc, np.array([arm, pendulum, 0.0, 0.0]), u, 0.0))
    # slopes of the motor torque: zero where a clip is active
    v = min(max(u, mc.u_min), mc.u_max)
    force = (mc.motor_gain * v + mc.motor_bias
             + mc.motor_bias_position * mc.motor_gear * arm)
    unclipped_force = 1.0 if mc.force_min < force < mc.force_max else 0.0
    unclipped_u = 1.0 if mc.u_min < u < mc.u_max else 0.0
    g2 = mc.motor_gear ** 2 * unclipped_force
    dtau_du = mc.motor_gear * mc.motor_gain * unclipped_u * unclipped_force
    dtau_dth = g2 * mc.motor_bias_position
    dtau_dthd = g2 * mc.motor_bias_velocity
    Minv = np.linalg.inv(M)
    A = np.zeros((4, 4))
    A[0, 2] = A[1, 3] = 1.0
    A[2:, 0] = Minv @ np.array([dtau_dth, 0.0])
    A[2:, 1] = Minv @ (np.array([0.0, -ddV]) - dM @ qdd)
    A[2:, 2] = Minv @ np.array([dtau_dthd - mc.arm_damping, 0.0])
    A[2:, 3] = Minv @ np.array([0.0, -mc.pendulum_damping])
    B = np.zeros((4, 1))
    B[2:, 0] = Minv @ np.array([dtau_du, 0.0])
    return A, B


# -- reading a compiled MuJoCo model -------------------------------------------------------
def _subtree(model: mujoco.MjModel, root: int) -> list[int]:
    def below(b: int) -> bool:
        while b > 0:
            if b == root:
                return True
            b = int(model.body_parentid[b])
        return False

    return [b for b in range(1, model.nbody) if below(b)]


def _floats(v: np.ndarray) -> tuple[float, ...]:
    return tuple(float(x) for x in v)


def _inertia_world(model: mujoco.MjModel, data: mujoco.MjData, b: int) -> np.ndarray:
    """Body ``b``'s inertia about its COM in world axes (kinematics of ``data`` current)."""
    R = data.ximat[b].reshape(3, 3)
    return R @ np.diag(model.body_inertia[b]) @ R.T


def _unsupported(model: mujoco.MjModel, joints: tuple[int, int], act: int) -> list[str]:
    """What in ``model`` adds forces the ODE does not have, one line each."""
    out: list[str] = []
    off = int(model.opt.disableflags)
    if model.nv != 2:
        out.append(f"the model has {model.nv} degrees of freedom, not the two hinges")
    for j in joints:
        name = model.joint(j).name
        dof = int(model.jnt_dofadr[j])
        if int(model.jnt_type[j]) != mujoco.mjtJoint.mjJNT_HINGE:
            out.append(f"joint '{name}' is not a hinge")
        if model.jnt_stiffness[j] != 0.0 or np.any(model.jnt_stiffnesspoly[j] != 0.0):
            out.append(f"joint '{name}' has stiffness")
        if model.dof_frictionloss[dof] != 0.0 and not off & mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS:
            out.append(f"joint '{name}' has dry friction (frictionloss)")
        if np.any(model.dof_dampingpoly[dof] != 0.0) and not off & mujoco.mjtDisableBit.mjDSBL_DAMPER:
            out.append(f"joint '{name}' has nonlinear damping (dampingpoly)")
        if model.jnt_limited[j] and not off & mujoco.mjtDisableBit.mjDSBL_LIMIT:
            out.append(f"joint '{name}' is limited")
        if model.jnt_actfrclimited[j]:
            out.append(f"joint '{name}' limits the actuator force (actuatorfrcrange)")
        if model.jnt_actgravcomp[j]:
            out.append(f"joint '{name}' applies gravity compensation through actuators")
    if np.any(model.body_gravcomp != 0.0):
        out.append("some body has gravity compensation (gravcomp)")
    if model.opt.density > 0.0 or model.opt.viscosity > 0.0:
        out.append("the medium has density or viscosity (fluid forces)")
    if model.neq > 0 and not off & mujoco.mjtDisableBit.mjDSBL_EQUALITY:
        out.append("the model has equality constraints")
    if model.ntendon > 0:
        out.append("the model has tendons")
    if model.nplugin > 0:
        out.append("the model has plugins")
    if (not off & mujoco.mjtDisableBit.mjDSBL_CONTACT
            and np.any((model.geom_contype != 0) | (model.geom_conaffinity != 0))):
        out.append("contacts are enabled and some geoms collide")
    if not off & mujoco.mjtDisableBit.mjDSBL_ACTUATION:
        others = [model.actuator(i).name for i in range(model.nu) if i != act]
        if others:
            out.append(f"other actuators act on the model: {', '.join(others)}")
    name = model.actuator(act).name
    if (int(model.actuator_trntype[act]) != mujoco.mjtTrn.mjTRN_JOINT
            or int(model.actuator_trnid[act][0]) != joints[0]):
        out.append(f"actuator '{name}' does not drive joint '{model.joint(joints[0]).name}'")
    if int(model.actuator_dyntype[act]) != mujoco.mjtDyn.mjDYN_NONE:
        out.append(f"actuator '{name}' has activation dynamics")
    if int(model.actuator_gaintype[act]) != mujoco.mjtGain.mjGAIN_FIXED:
        out.append(f"actuator '{name}' gain is not fixed")
    if int(model.actuator_biastype[act]) not in (mujoco.mjtBias.mjBIAS_NONE,
                                                 mujoco.mjtBias.mjBIAS_AFFINE):
        out.append(f"actuator '{name}' bias is neither none nor affine")
    if model.actuator_delay[act] != 0.0:
        out.append(f"actuator '{name}' has a delay")
    if np.any(model.actuator_dampingpoly[act] != 0.0):
        out.append(f"actuator '{name}' has nonlinear damping (dampingpoly)")
    return out


def params_from_model(model: mujoco.MjModel, arm: str = "arm", pendulum: str = "pendulum",
                      actuator: str = "motor") -> FurutaParams:
    """The :class:`FurutaParams` of a compiled MuJoCo model, read as it is.

    Masses, COMs and full inertia tensors are summed over each joint's rigid part (the
    pendulum joint's body and its subtree; the arm joint's body and its subtree without
    the pendulum's) at ``qpos = 0``, the ODE's zero; joint damping and armature, the
    actuator's own damping and armature (reflected through gear^2 and, being passive, not
    clipped by the force range, as MuJoCo does), its gear, gain, affine bias and control
    and force ranges are read as compiled, and the disable flags (gravity, damper,
    clampctrl, actuation) are honoured.  Vectors are
    given in world axes.

    Parameters
    ----------
    model : mujoco.MjModel
        compiled model with two hinges: ``arm`` (the motor's) and ``pendulum`` below it.
    arm, pendulum, actuator : str
        names of the two joints and of the motor acting on ``arm``.

    Raises
    ------
    ValueError
        naming everything the model has that the ODE does not (more degrees of freedom,
        stiffness, dry friction, limits, contacts, tendons, other actuators, an actuator
        with dynamics or a nonlinear gain or bias, an arm axis not along gravity...).
    """
    try:
        ja, jp = model.joint(arm).id, model.joint(pendulum).id
        act = model.actuator(actuator).id
    except KeyError as exc:
        raise ValueError(f"model has no joint or actuator named {exc}") from None
    problems = _unsupported(model, (ja, jp), act)
    arm_body, pend_body = int(model.jnt_bodyid[ja]), int(model.jnt_bodyid[jp])
    arm_part, pend_part = _subtree(model, arm_body), _subtree(model, pend_body)
    if pend_body not in arm_part or pend_body == arm_body:
        problems.append(f"joint '{pendulum}' is not on a body below joint '{arm}'")

    data = mujoco.MjData(model)
    data.qpos[:] = 0.0
    mujoco.mj_kinematics(model, data)
    off = int(model.opt.disableflags)
    z = data.xaxis[ja].copy()
    gvec = (np.zeros(3) if off & mujoco.mjtDisableBit.mjDSBL_GRAVITY
            else np.asarray(model.opt.gravity, dtype=float))
    if np.linalg.norm(np.cross(gvec, z)) > 1e-12 * max(float(np.linalg.norm(gvec)), 1.0):
        problems.append(f"joint '{arm}''s axis is not along gravity")
    if problems:
        raise ValueError("the Furuta ODE does not model this MuJoCo model: "
                         + "; ".join(problems))

    arm_anchor, pend_anchor = data.xanchor[ja].copy(), data.xanchor[jp].copy()
    pend_set = set(pend_part)
    J_arm = 0.0
    for b in arm_part:
        if b in pend_set:
            continue
        r = data.xipos[b] - arm_anchor
        J_arm += float(z @ _inertia_world(model, data, b) @ z) + float(
            model.body_mass[b]) * float(np.cross(z, r) @ np.cross(z, r))
    m = float(sum(model.body_mass[b] for b in pend_part))
    com = sum(model.body_mass[b] * data.xipos[b] for b in pend_part) / m
    Ic = np.zeros((3, 3))
    for b in pend_part:
        r = data.xipos[b] - com
        Ic += _inertia_world(model, data, b) + model.body_mass[b] * (
            float(r @ r) * np.eye(3) - np.outer(r, r))

    da, dp = int(model.jnt_dofadr[ja]), int(model.jnt_dofadr[jp])
    damper = 0.0 if off & mujoco.mjtDisableBit.mjDSBL_DAMPER else 1.0
    gear = float(model.actuator_gear[act][0])
    actuated = 0.0 if off & mujoco.mjtDisableBit.mjDSBL_ACTUATION else 1.0
    bias = (np.asarray(model.actuator_biasprm[act][:3], dtype=float)
            if int(model.actuator_biastype[act]) == mujoco.mjtBias.mjBIAS_AFFINE
            else np.zeros(3))
    clamp = (bool(model.actuator_ctrllimited[act])
             and not off & mujoco.mjtDisableBit.mjDSBL_CLAMPCTRL)
    ctrl_range = tuple(float(v) for v in model.actuator_ctrlrange[act]) if clamp else (
        -math.inf, math.inf)
    force_range = (tuple(float(v) for v in model.actuator_forcerange[act])
                   if model.actuator_forcelimited[act] else (-math.inf, math.inf))
    return FurutaParams(
        gravity=-float(gvec @ z), arm_axis=_floats(z), arm_inertia=J_arm,
        arm_armature=float(model.dof_armature[da]) + float(model.actuator_armature[act]) * gear ** 2,
        pivot=_floats(pend_anchor - arm_anchor), pendulum_axis=_floats(data.xaxis[jp]),
        pendulum_mass=m, pendulum_com=_floats(com - pend_anchor),
        pendulum_inertia=_floats(Ic[[0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]]),
        pendulum_armature=float(model.dof_armature[dp]),
        arm_damping=damper * (float(model.dof_damping[da])
                              + float(model.actuator_damping[act]) * gear ** 2),
        pendulum_damping=damper * float(model.dof_damping[dp]),
        motor_gear=gear, motor_gain=actuated * float(model.actuator_gainprm[act][0]),
        motor_bias=actuated * float(bias[0]), motor_bias_position=actuated * float(bias[1]),
        motor_bias_velocity=actuated * float(bias[2]), ctrl_range=ctrl_range, force_range=force_range)
