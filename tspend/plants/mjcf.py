"""Any MJCF cart-pole read as it is, and M, m, l, J written so the compiled model has them.

:func:`read_facts` measures, from the *compiled* model, everything a cart-pole's
numbers (:class:`CartPoleParams`, the ``[plant]`` keys and the metrics' ``plant``) say: the
cart and pole masses, where the pole's centre of mass is (anywhere in its frame) and its
inertia about the hinge axis, the directions of the slide and the hinge (any hinge not
parallel to the slide), the actuator as MuJoCo applies it (motor, velocity, position or
general with gain and bias; its control, force and joint force ranges), joint damping,
stiffness, friction loss and armature, limits, the integrator and timestep, the geom
pairs that can collide, and the sign of d(q'')/du at the upright.  What the ODE cannot
be is refused with the reason (a hinge parallel to the slide, more than the two joints,
actuator dynamics).  :func:`departures` turns the facts into one-line statements of how
the model departs from the paper's ideal ODE (``tspend inspect`` prints them; a run warns
with them); :func:`unmodelled` names only what the ODE of the compiled model does not
reproduce (what the cross-check can blame).

:func:`apply_overrides` writes M, m, l (and J, the uniform rod's by default) into an
``MjSpec`` whatever the compiler settings are: the pole's and cart's geoms stop
contributing mass and the two bodies get explicit inertials; :func:`verify_overrides`
then reads the compiled model back and names the body that did not take a value.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

import mujoco
import numpy as np

from tspend.runtime.errors import ScenarioError
from tspend.plants.articulated.tree import (INTEGRATOR_NAMES, collision_pairs, law_refusals,
                                            read_actuator, read_gravity, read_joint)

__all__ = ["CartPoleParams", "actuator_force_range", "ActuatorFacts", "JointFacts", "ModelFacts", "read_facts", "departures",
           "unmodelled", "apply_overrides", "verify_overrides", "collision_pairs"]

# Axial inertia of the rod relative to its transverse one: never enters the planar
# dynamics but must be positive; reproduces models/cartpole.xml's 1e-4 kg m^2.
AXIAL_INERTIA_RATIO = 1.0 / 3e4

#: the machine's numbers a scenario can write into a model (``[plant]`` keys of
#: ``cartpole_mujoco``, 0: the model's own; docs/third-party-models.md)
OVERRIDABLE = ("M", "m", "l", "J", "g")

#: relative mismatch tolerated between a requested and a compiled parameter
VERIFY_RTOL = 1e-9

#: |slide axis x hinge axis| below this is a hinge parallel to the slide
PARALLEL_TOL = 1e-9

_DSBL = mujoco.mjtDisableBit


INF = math.inf


@dataclass(frozen=True)
class CartPoleParams:
    """One cart-pole's numbers: the paper's M, m, l, g, and what a real rig adds (the
    ``[plant]`` keys, the metrics' ``plant``; the grey-box model's parameters,
    :mod:`tspend.studies.cartpole_greybox`, whose module docstring names the geometry).

    ``J`` is the pole's inertia about the hinge axis (0 = the uniform rod's 4/3 m l^2);
    ``theta_sign`` is -1 when the model's positive angle leans the pole toward +x (a
    reversed hinge axis).  ``rail_coupling``, ``rail_phase``, ``gravity_coupling``,
    ``gravity_phase`` and ``rail_gravity`` are ``k_r``, ``phi_r``, ``k_g``, ``phi_g``,
    ``g_s`` (the paper's pole: 1, 0, 1, 0, 0).  The actuator: ``gear``, ``gain`` (``g0``;
    the force per unit u of a motor is ``gear gain``), ``gain_length``, ``gain_velocity``
    (``g1``, ``g2``), ``bias``, ``bias_length``, ``bias_velocity`` (``b0``, ``b1``,
    ``b2``) and its ranges (``ctrl_*`` on u, ``force_*`` on the actuator's force,
    ``joint_force_*`` on the force at the joint; +/-inf: none).
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
    rail_coupling: float = 1.0
    rail_phase: float = 0.0
    gravity_coupling: float = 1.0
    gravity_phase: float = 0.0
    rail_gravity: float = 0.0
    cart_stiffness: float = 0.0
    cart_spring_ref: float = 0.0
    hinge_stiffness: float = 0.0
    hinge_spring_ref: float = 0.0
    gain: float = 1.0
    gain_length: float = 0.0
    gain_velocity: float = 0.0
    bias: float = 0.0
    bias_length: float = 0.0
    bias_velocity: float = 0.0
    ctrl_min: float = -INF
    ctrl_max: float = INF
    force_min: float = -INF
    force_max: float = INF
    joint_force_min: float = -INF
    joint_force_max: float = INF

    @property
    def pole_inertia_pivot(self) -> float:
        return self.J if self.J > 0.0 else 4.0 / 3.0 * self.m * self.l ** 2

    @property
    def disturbance_torque(self) -> float:
        """Hinge torque per unit d_d: ``tau = -d_d m l / (M + m)`` enters (C2) like d_d
        enters the paper's numerator (exact for the rod, the paper's meaning otherwise):
        with a hinge torque the Lagrangian gives ``theta'' = (... - tau (M+m)/(m l)) /
        (m l cos^2 - 4/3 l (M+m))``; positive ``tau`` pushes ``theta`` up."""
        return -self.m * self.l / (self.M + self.m)

    @property
    def force_per_u(self) -> float:
        """The cart force per unit u at rest, N (``gear gain``)."""
        return self.gear * self.gain

    def finite(self) -> dict[str, float]:
        """The parameters as plain numbers, leaving out the ranges that are not set (inf)."""
        return {f.name: float(getattr(self, f.name)) for f in fields(self)
                if math.isfinite(getattr(self, f.name))}


def actuator_force_range(p: CartPoleParams, u_lo: float = -INF, u_hi: float = INF
                         ) -> tuple[float, float]:
    """The least and the largest force the actuator puts on the cart at rest (x = 0,
    x' = 0) for u in ``[u_lo, u_hi]`` and its own ranges (+/-inf: unbounded): MuJoCo's
    ``F = clip(gear clip(gain clip(u, ctrl) + bias, force), joint)`` at rest."""
    huge = 1e300   # an unbounded u: the force ranges, if any, bound the force

    def force(u: float) -> float:
        x = 0.0   # the actuator's length and velocity at rest, written as MuJoCo's law has them
        uc = min(max(u, p.ctrl_min), p.ctrl_max)
        f = ((p.gain + p.gain_length * x + p.gain_velocity * x) * uc
             + p.bias + p.bias_length * x + p.bias_velocity * x)
        return min(max(p.gear * min(max(f, p.force_min), p.force_max), p.joint_force_min),
                   p.joint_force_max)

    lo, hi = max(u_lo, p.ctrl_min), min(u_hi, p.ctrl_max)
    ends = [force(v) for v in (max(lo, -huge), min(hi, huge))]
    ends = [math.copysign(INF, f) if abs(f) >= 1e250 else f for f in ends]
    return min(ends), max(ends)


def _vec(v: Any) -> tuple[float, float, float]:
    return tuple(round(float(c), 12) + 0.0 for c in v)  # type: ignore[return-value]


def _fmt(v: Any) -> str:
    return "(" + ", ".join(f"{float(c):.6g}" for c in v) + ")"


@dataclass(frozen=True)
class JointFacts:
    name: str
    damping: float
    frictionloss: float
    armature: float
    stiffness: float
    limited: bool
    range: tuple[float, float]
    spring_ref: float = 0.0
    #: world direction at the reference pose (q = 0)
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)


@dataclass(frozen=True)
class ActuatorFacts:
    """The actuator as MuJoCo applies it (the grey-box model's ``F(u, x, x')``,
    :mod:`tspend.studies.cartpole_greybox`)."""

    name: str
    kind: str              #: motor, velocity, position or general
    gear: float
    gain: float
    gain_length: float
    gain_velocity: float
    bias: float
    bias_length: float
    bias_velocity: float
    ctrl_range: tuple[float, float] | None
    force_range: tuple[float, float] | None
    joint_force_range: tuple[float, float] | None
    damping: float         #: the actuator's own passive damping (MuJoCo 4), N s/m per gear^2
    armature: float

    def max_force_at_rest(self) -> float:
        """The largest |force| it can put on the cart at x = 0, x' = 0, N (inf: unbounded)."""
        lo, hi = actuator_force_range(CartPoleParams(**self.param_fields()))
        return max(abs(lo), abs(hi))

    def param_fields(self) -> dict[str, float]:
        c = self.ctrl_range or (-math.inf, math.inf)
        f = self.force_range or (-math.inf, math.inf)
        j = self.joint_force_range or (-math.inf, math.inf)
        return dict(gear=self.gear, gain=self.gain, gain_length=self.gain_length,
                    gain_velocity=self.gain_velocity, bias=self.bias,
                    bias_length=self.bias_length, bias_velocity=self.bias_velocity,
                    ctrl_min=c[0], ctrl_max=c[1], force_min=f[0], force_max=f[1],
                    joint_force_min=j[0], joint_force_max=j[1])


@dataclass(frozen=True)
class ModelFacts:
    """What a compiled MJCF cart-pole holds (SI units; angles in rad)."""

    path: str
    cart_mass: float                 #: everything the slider carries but the pole
    pole_mass: float                 #: the hinge body's subtree
    pole_com: float                  #: distance hinge axis -> pole COM
    pole_inertia_pivot: float        #: about the hinge axis
    rod_inertia_pivot: float         #: 4/3 m l^2, what the paper's ODE assumes
    gain_sign: int                   #: sign of d(q'')/du at the upright, at rest (MuJoCo's)
    theta_sign: int                  #: +1: q > 0 leans the pole toward -x along the slide
    gear: float
    ctrl_limited: bool
    ctrl_range: tuple[float, float] | None
    force_limited: bool
    force_range: tuple[float, float] | None
    actuator_type: str               #: motor, velocity, position or general
    slide: JointFacts
    hinge: JointFacts
    timestep: float
    integrator: str
    contacts: bool                   #: some geom pair can collide (collision_pairs)
    gravity: float                   #: |g|, m/s^2
    actuator: ActuatorFacts | None = None
    #: pole COM relative to the hinge anchor at q = 0 (world frame), m
    pole_com_vector: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rail_coupling: float = 1.0
    rail_phase: float = 0.0
    gravity_coupling: float = 1.0
    gravity_phase: float = 0.0
    rail_gravity: float = 0.0
    collision_pairs: tuple[str, ...] = ()
    #: what the ODE of this model does not reproduce (without the sample time)
    unmodelled: tuple[str, ...] = ()
    departures: tuple[str, ...] = field(default=())

    @property
    def gain(self) -> float:
        return self.actuator.gain if self.actuator is not None else 1.0

    @property
    def force_per_u(self) -> float:
        """The cart force per unit u at rest, N (``gear x gain``: the ``gear`` key)."""
        return self.gear * self.gain

    def params(self) -> CartPoleParams:
        """The ODE of this very machine: armatures count as mass and inertia, the
        actuator's own damping and armature are reflected through gear^2."""
        act = self.actuator
        gear2 = act.gear ** 2 if act is not None else 0.0
        extra_m = act.armature * gear2 if act is not None else 0.0
        extra_b = act.damping * gear2 if act is not None else 0.0
        return CartPoleParams(
            M=self.cart_mass + self.slide.armature + extra_m, m=self.pole_mass,
            l=self.pole_com, g=self.gravity, J=self.pole_inertia_pivot + self.hinge.armature,
            cart_damping=self.slide.damping + extra_b, hinge_damping=self.hinge.damping,
            cart_friction=self.slide.frictionloss, hinge_friction=self.hinge.frictionloss,
            theta_sign=float(self.theta_sign), rail_coupling=self.rail_coupling,
            rail_phase=self.rail_phase, gravity_coupling=self.gravity_coupling,
            gravity_phase=self.gravity_phase, rail_gravity=self.rail_gravity,
            cart_stiffness=self.slide.stiffness, cart_spring_ref=self.slide.spring_ref,
            hinge_stiffness=self.hinge.stiffness, hinge_spring_ref=self.hinge.spring_ref,
            **(act.param_fields() if act is not None else {}))

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        for key in ("departures", "unmodelled", "collision_pairs"):
            d[key] = list(getattr(self, key))
        return d


def _joint(model: mujoco.MjModel, data: mujoco.MjData, j: int) -> JointFacts:
    """Joint ``j`` (:func:`~tspend.plants.articulated.tree.read_joint`) with its dry friction,
    whether its limit acts and its world direction at the pose of ``data``."""
    t, off = read_joint(model, j), model.opt.disableflags
    return JointFacts(name=model.joint(j).name, damping=t.damping,
                      frictionloss=0.0 if off & (_DSBL.mjDSBL_FRICTIONLOSS | _DSBL.mjDSBL_CONSTRAINT)
                      else float(model.dof_frictionloss[int(model.jnt_dofadr[j])]),
                      armature=t.armature, stiffness=t.stiffness,
                      limited=t.range is not None and not off & (
                          _DSBL.mjDSBL_LIMIT | _DSBL.mjDSBL_CONSTRAINT),
                      range=(float(model.jnt_range[j][0]), float(model.jnt_range[j][1])),
                      spring_ref=t.springref, axis=_vec(data.xaxis[j]))


def subtree(model: mujoco.MjModel, root: int) -> list[int]:
    return [b for b in range(model.nbody)
            if b == root or _is_below(model, b, root)]


def _is_below(model: mujoco.MjModel, b: int, root: int) -> bool:
    while b > 0:
        b = int(model.body_parentid[b])
        if b == root:
            return True
    return False


def pole_inertials(model: mujoco.MjModel, data: mujoco.MjData, hinge: int
                   ) -> tuple[float, float, float, np.ndarray]:
    """Mass, COM distance from the hinge axis, inertia about it, and the COM relative to
    the anchor.

    Summed over the hinge body's subtree at the pose of ``data`` (kinematics current).
    """
    pole = int(model.jnt_bodyid[hinge])
    axis, anchor = data.xaxis[hinge].copy(), data.xanchor[hinge].copy()
    mass, moment, inertia = 0.0, np.zeros(3), 0.0
    for b in subtree(model, pole):
        mb = float(model.body_mass[b])
        r = data.xipos[b] - anchor
        R = data.ximat[b].reshape(3, 3)
        a_local = R.T @ axis
        inertia += float(a_local @ (model.body_inertia[b] * a_local)) + mb * float(
            np.linalg.norm(np.cross(axis, r)) ** 2)
        mass += mb
        moment += mb * r
    com = moment / mass if mass > 0.0 else np.zeros(3)
    arm = com - float(com @ axis) * axis
    return mass, float(np.linalg.norm(arm)), inertia, com


def _actuator(model: mujoco.MjModel, a: int, slide: int, where: str) -> ActuatorFacts:
    """The actuator's force law, or ScenarioError naming what the ODE cannot carry."""
    name = model.actuator(a).name
    refused = law_refusals(model, a)
    if refused:
        raise ScenarioError(f"{where}: {'; '.join(refused)}: the cart-pole ODE cannot carry it "
                            f"(use a motor, velocity, position or general actuator without "
                            f"dynamics, its gain fixed or affine, its bias none or affine)")
    law = read_actuator(model, a)
    (g0, g1, g2), (b0, b1, b2) = law.gain, law.bias
    if (g1, g2, b0, b1, b2) == (0.0,) * 5:
        kind = "motor"
    elif (g1, g2, b0, b1) == (0.0,) * 4 and b2 == -g0:
        kind = "velocity"
    elif (g1, g2, b0) == (0.0,) * 3 and b1 == -g0:
        kind = "position"
    else:
        kind = "general"
    damping = float(model.actuator_damping[a]) if hasattr(model, "actuator_damping") else 0.0
    armature = float(model.actuator_armature[a]) if hasattr(model, "actuator_armature") else 0.0
    return ActuatorFacts(name=name, kind=kind, gear=law.gear, gain=g0,
                         gain_length=g1, gain_velocity=g2, bias=b0, bias_length=b1,
                         bias_velocity=b2, ctrl_range=law.ctrlrange, force_range=law.forcerange,
                         joint_force_range=read_joint(model, slide).actfrcrange,
                         damping=damping, armature=armature)  # type: ignore[arg-type]


def read_facts(model: mujoco.MjModel, slide_joint: str, hinge_joint: str, actuator: str,
               path: str = "") -> ModelFacts:
    """Measure the compiled ``model`` (joint and actuator names already checked); raise
    ScenarioError for what the cart-pole ODE cannot be (the message says why)."""
    where = path or "model"
    s, h = model.joint(slide_joint).id, model.joint(hinge_joint).id
    a = model.actuator(actuator).id
    if model.nv != 2:
        names = ", ".join(model.joint(j).name or f"joint{j}" for j in range(model.njnt))
        raise ScenarioError(f"{where}: the cart-pole ODE has 2 degrees of freedom (slide "
                            f"'{slide_joint}', hinge '{hinge_joint}'); the model has "
                            f"{model.nv} (joints: {names})")
    cart, pole = int(model.jnt_bodyid[s]), int(model.jnt_bodyid[h])
    if not _is_below(model, pole, cart):
        raise ScenarioError(f"{where}: hinge '{hinge_joint}' is on body "
                            f"'{model.body(pole).name}', which the slide '{slide_joint}' "
                            f"(body '{model.body(cart).name}') does not carry")
    data = mujoco.MjData(model)
    data.qpos[:] = 0.0      # the geometry at q = 0 (a joint's ref moves qpos0, not this)
    mujoco.mj_forward(model, data)
    m, l, J, com = pole_inertials(model, data, h)
    M = float(model.body_subtreemass[cart]) - m
    slide_axis, hinge_axis = data.xaxis[s].copy(), data.xaxis[h].copy()
    if float(np.linalg.norm(np.cross(slide_axis, hinge_axis))) < PARALLEL_TOL:
        raise ScenarioError(f"{where}: hinge '{hinge_joint}' axis {_fmt(hinge_axis)} is "
                            f"parallel to slide '{slide_joint}' axis {_fmt(slide_axis)}: the "
                            f"cart cannot move the pole (no cart-pole)")
    if l < 1e-12 * max(1.0, float(np.linalg.norm(com))):
        raise ScenarioError(f"{where}: the pole's centre of mass is on hinge "
                            f"'{hinge_joint}''s axis: the cart cannot swing it (no cart-pole)")
    gravity = np.asarray(read_gravity(model), dtype=float)
    if not np.isfinite(gravity).all():
        raise ScenarioError(f"{where}: gravity {_fmt(gravity)} is not finite (set it in the "
                            f"model's <option gravity=...> or with plant.g)")
    g = float(np.linalg.norm(gravity))
    down = gravity / g if g > 0.0 else np.array([0.0, 0.0, -1.0])
    # the COM's motion about the axis: X(q) = ax cos q + bx sin q (along the rail),
    # H(q) = az cos q + bz sin q (up); the grey-box model's k and phi from them
    c_perp = com - float(com @ hinge_axis) * hinge_axis
    turned = np.cross(hinge_axis, c_perp)
    ax, bx = float(slide_axis @ c_perp), float(slide_axis @ turned)
    az, bz = -float(down @ c_perp), -float(down @ turned)
    theta_sign = 1 if bx <= 0.0 else -1
    act = _actuator(model, a, s, where)

    # the sign of Assumption 5, measured: q'' at the upright for a small push
    dof = int(model.jnt_dofadr[h])
    data.qvel[:] = 0.0
    data.ctrl[:] = 0.0
    mujoco.mj_forward(model, data)
    base = float(data.qacc[dof])
    probe = 1e-3
    if act.ctrl_range is not None and act.ctrl_range[1] > 0.0:
        probe = min(probe, 0.5 * act.ctrl_range[1])
    data.ctrl[a] = probe
    mujoco.mj_forward(model, data)
    push = float(data.qacc[dof]) - base
    gain_sign = 0 if push == 0.0 else (1 if push > 0.0 else -1)

    pairs = collision_pairs(model)
    facts = ModelFacts(
        path=path, cart_mass=M, pole_mass=m, pole_com=l, pole_inertia_pivot=J,
        rod_inertia_pivot=4.0 / 3.0 * m * l * l, gain_sign=gain_sign, theta_sign=theta_sign,
        gear=act.gear, ctrl_limited=act.ctrl_range is not None, ctrl_range=act.ctrl_range,
        force_limited=act.force_range is not None, force_range=act.force_range,
        actuator_type=act.kind, slide=_joint(model, data, s), hinge=_joint(model, data, h),
        timestep=float(model.opt.timestep),
        integrator=INTEGRATOR_NAMES.get(model.opt.integrator, str(int(model.opt.integrator))),
        contacts=bool(pairs), gravity=g, actuator=act, pole_com_vector=_vec(com),
        rail_coupling=math.hypot(ax, bx) / l, rail_phase=math.atan2(-ax, -theta_sign * bx),
        gravity_coupling=math.hypot(az, bz) / l,
        gravity_phase=math.atan2(-theta_sign * bz, az) if math.hypot(az, bz) > 0.0 else 0.0,
        rail_gravity=float(gravity @ slide_axis), collision_pairs=tuple(pairs))
    facts = replace(facts, unmodelled=tuple(_unmodelled(model, facts, cart, a)))
    return replace(facts, departures=tuple(departures(facts)))


def _unmodelled(model: mujoco.MjModel, f: ModelFacts, cart: int, act: int) -> list[str]:
    """What the ODE of the compiled model leaves out (limits and contacts aside: the
    cross-check stops comparing when one becomes active and says when)."""
    out: list[str] = []
    for label, j in (("slide", f.slide), ("hinge", f.hinge)):
        if j.frictionloss:
            out.append(f"{label} joint '{j.name}' has dry friction (frictionloss "
                       f"{j.frictionloss:g}): MuJoCo's is a soft constraint, the ODE's a smooth "
                       f"tanh, so they agree in kind, not to rounding")
    for j in range(model.njnt):
        dof = int(model.jnt_dofadr[j])
        poly = getattr(model, "dof_dampingpoly", None)
        if poly is not None and np.any(poly[dof] != 0.0):
            out.append(f"joint '{model.joint(j).name}' has nonlinear damping (dampingpoly)")
        spoly = getattr(model, "jnt_stiffnesspoly", None)
        if spoly is not None and np.any(spoly[j] != 0.0):
            out.append(f"joint '{model.joint(j).name}' has nonlinear stiffness (stiffnesspoly)")
    if f.integrator != "RK4":
        out.append(f"integrator {f.integrator}, not RK4: MuJoCo and the ODE differ by its "
                   f"truncation error (plant.integrator = \"RK4\" to match)")
    moving = subtree(model, cart)
    if any(float(model.body_gravcomp[b]) != 0.0 for b in moving):
        out.append("gravity compensation (gravcomp) on a moving body")
    if model.opt.density > 0.0 or model.opt.viscosity > 0.0 or np.any(model.opt.wind != 0.0):
        out.append(f"fluid forces (density {model.opt.density:g}, viscosity "
                   f"{model.opt.viscosity:g}, wind {_fmt(model.opt.wind)})")
    if model.neq > 0:
        out.append(f"{model.neq} equality constraint(s)")
    for k in range(model.nu):
        if k != act and int(model.actuator_biastype[k]) != mujoco.mjtBias.mjBIAS_NONE:
            out.append(f"actuator '{model.actuator(k).name}' (held at ctrl 0) applies a bias force")
    delay = getattr(model, "actuator_delay", None)
    if delay is not None and float(np.max(np.abs(delay[act]))) > 0.0:
        out.append(f"actuator '{model.actuator(act).name}' has a delay")
    return out


#: a cart force bound (N) at or above this is beyond every paper case's need (733 N at
#: most, measured in models/cartpole.xml's comment): not reported as a departure
UNREACHED_FORCE = 1000.0


def _sample_time(f: ModelFacts, dt: float | None) -> list[str]:
    if dt is None:
        return []
    k = dt / f.timestep
    if abs(k - round(k)) > 1e-9 * max(k, 1.0) or round(k) < 1:
        return [f"timestep {f.timestep:g} s does not divide dt = {dt:g} s (set plant.timestep)"]
    if round(k) > 1:
        return [f"timestep {f.timestep:g} s: {round(k)} physics steps per control sample "
                f"(dt = {dt:g} s), the ODE takes one RK4 step of dt"]
    return []


def unmodelled(f: ModelFacts, dt: float | None = None) -> list[str]:
    """What the ODE of the compiled model (``f.params()``) does not reproduce, one line
    each: the only departures a failing cross-check can name."""
    return list(f.unmodelled) + _sample_time(f, dt)


def departures(f: ModelFacts, dt: float | None = None, *, gear_chosen: bool = False) -> list[str]:
    """How the model departs from the paper's ideal cart-pole ODE, one line each
    (``gear_chosen``: the scenario set or drew the gear, so it is the machine asked for,
    not a surprise in the file)."""
    out: list[str] = []
    if abs(f.pole_inertia_pivot - f.rod_inertia_pivot) > 1e-6 * max(f.rod_inertia_pivot, 1e-12):
        out.append(f"pole inertia about the pivot is {f.pole_inertia_pivot:.6g} kg m^2, not the "
                   f"uniform rod's 4/3 m l^2 = {f.rod_inertia_pivot:.6g}")
    if abs(f.rail_phase) > 1e-12 or abs(f.gravity_phase) > 1e-12:
        out.append(f"the pole's centre of mass {_fmt(f.pole_com_vector)} m (from the pivot) is "
                   f"off its line: it leans {f.gravity_phase:.4g} rad at q = 0, the upright "
                   f"equilibrium is q = {-f.theta_sign * f.gravity_phase:.4g} rad")
    if abs(f.rail_coupling - 1.0) > 1e-12 or abs(f.gravity_coupling - 1.0) > 1e-12:
        out.append(f"hinge '{f.hinge.name}' axis {_fmt(f.hinge.axis)} is tilted: the rail sees "
                   f"{f.rail_coupling:.6g} and gravity {f.gravity_coupling:.6g} of the pole's "
                   f"swing (slide '{f.slide.name}' axis {_fmt(f.slide.axis)})")
    if abs(f.rail_gravity) > 1e-12:
        out.append(f"the rail is not level: gravity pulls the cart with {f.rail_gravity:.6g} m/s^2")
    if f.gain_sign < 0:
        out.append("reversed gain sign: u > 0 gives theta'' < 0 at the upright (the paper "
                   "controller takes this sign from the model unless controller.gain_sign "
                   "says otherwise)")
    act = f.actuator
    if act is not None and act.kind != "motor":
        out.append(f"actuator '{act.name}' is a {act.kind} actuator: force = gear (("
                   f"{act.gain:g} + {act.gain_length:g} L + {act.gain_velocity:g} V) u + "
                   f"{act.bias:g} + {act.bias_length:g} L + {act.bias_velocity:g} V), L = "
                   f"gear x, V = gear x': u is not a force")
    if f.gear * f.gain != 1.0 and not gear_chosen:
        out.append(f"actuator gear {f.gear:g}, gain {f.gain:g}: the cart force is "
                   f"{f.gear * f.gain:g} u at rest")
    force_max = act.max_force_at_rest() if act is not None else math.inf
    if f.ctrl_limited and f.ctrl_range is not None and force_max < UNREACHED_FORCE:
        out.append(f"clipped actuator: ctrlrange [{f.ctrl_range[0]:g}, {f.ctrl_range[1]:g}] "
                   f"(force at most {force_max:g} N)")
    if f.force_limited and f.force_range is not None:
        out.append(f"clipped actuator: forcerange [{f.force_range[0]:g}, {f.force_range[1]:g}] N")
    if act is not None and act.joint_force_range is not None:
        out.append(f"clipped actuator: slide joint actuatorfrcrange [{act.joint_force_range[0]:g}, "
                   f"{act.joint_force_range[1]:g}] N")
    for label, j in (("slide", f.slide), ("hinge", f.hinge)):
        if j.damping:
            out.append(f"{label} joint '{j.name}' has damping {j.damping:g}")
        if j.armature:
            out.append(f"{label} joint '{j.name}' has armature {j.armature:g}")
        if j.stiffness:
            out.append(f"{label} joint '{j.name}' has stiffness {j.stiffness:g}")
        if j.limited:
            out.append(f"{label} joint '{j.name}' is limited to [{j.range[0]:g}, {j.range[1]:g}]")
    if f.collision_pairs:
        shown = ", ".join(f.collision_pairs[:3]) + (", ..." if len(f.collision_pairs) > 3 else "")
        out.append(f"contacts are enabled: {len(f.collision_pairs)} geom pair(s) can touch "
                   f"({shown})")
    out.extend(f.unmodelled)
    for line in _sample_time(f, dt):
        if line not in out:
            out.append(line)
    return [line for i, line in enumerate(out) if line not in out[:i]]


# -- overrides ---------------------------------------------------------------------------
def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 0.0 else np.array([0.0, 0.0, 1.0])


def apply_overrides(spec: mujoco.MjSpec, cart: Any, hinge: Any, p: CartPoleParams,
                    where: str, keys: frozenset[str] = frozenset("Mmlg")) -> None:
    """Write ``keys`` of M, m, l, J and g from ``p`` into ``spec`` so that the compiled
    model has them (the others stay the model's own).

    With any of m, l, J the pole body gets an explicit inertial: mass m, COM at l along
    the pole (toward its own COM, so a leaning pole keeps its lean), the transverse
    inertia that makes J about the pivot (the rod's 4/3 m l^2 when J is 0); with M the
    cart body gets the mass that makes everything the slider carries but the pole equal
    M.  The bodies written stop taking mass from their geoms, so ``inertiafromgeom``
    cannot undo this.  A pole body with child bodies cannot take m, l (the error names it).
    """
    for name in ("M", "m", "l", "g"):
        v = getattr(p, name)
        if name in keys and not (math.isfinite(v) and v > 0.0):
            raise ScenarioError(f"{where}: cart-pole parameter {name} must be positive, got {v}")
    pole = hinge.parent
    if keys & {"m", "l", "J"}:
        if list(pole.bodies):
            raise ScenarioError(f"{where}: cannot set m, l on body '{pole.name}': it has child "
                                f"bodies ({', '.join(b.name or '<unnamed>' for b in pole.bodies)}) "
                                f"whose masses the pole would also carry")
        pivot = np.asarray(hinge.pos, dtype=float)
        axis = _pole_direction(pole, pivot)
        J = p.pole_inertia_pivot
        i_perp = J - p.m * p.l ** 2
        if i_perp <= 0.0:
            raise ScenarioError(f"{where}: pole inertia about the pivot J = {J:g} must exceed "
                                f"m l^2 = {p.m * p.l ** 2:g} (body '{pole.name}')")
        _massless_geoms(pole)
        pole.explicitinertial = True
        pole.mass = p.m
        pole.ipos = pivot + p.l * axis
        pole.fullinertia = [math.nan, 0.0, 0.0, 0.0, 0.0, 0.0]
        pole.inertia = [i_perp, i_perp, i_perp * AXIAL_INERTIA_RATIO]
        iquat = np.zeros(4)
        mujoco.mju_quatZ2Vec(iquat, axis)
        pole.iquat = iquat

    if "M" in keys:
        others = [b for b in _descendants(cart) if b is not pole]
        carried = sum(float(b.mass) for b in others)
        cart_mass = p.M - carried
        if cart_mass <= 0.0:
            raise ScenarioError(f"{where}: cannot set M = {p.M:g} on body '{cart.name}': the "
                                f"bodies it carries besides the pole already weigh {carried:g} kg")
        scale = cart_mass / float(cart.mass) if float(cart.mass) > 0.0 else 1.0
        inertia = np.asarray(cart.inertia, dtype=float) * scale
        _massless_geoms(cart)
        cart.explicitinertial = True
        cart.mass = cart_mass
        cart.fullinertia = [math.nan, 0.0, 0.0, 0.0, 0.0, 0.0]
        cart.inertia = inertia if np.all(inertia > 0.0) else [1.0, 1.0, 1.0]
    if "g" in keys:
        spec.option.gravity = [0.0, 0.0, -p.g]
    # explicit inertials win over geoms only when the compiler is told to use them
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_AUTO


def _pole_direction(pole: Any, pivot: np.ndarray) -> np.ndarray:
    """Where the pole points in its body frame: toward its COM, else its longest geom, else z."""
    arm = np.asarray(pole.ipos, dtype=float) - pivot
    if float(np.linalg.norm(arm)) > 1e-9:
        return _unit(arm)
    for geom in pole.geoms:
        fromto = np.asarray(geom.fromto, dtype=float)
        if not math.isnan(fromto[0]):
            a, b = fromto[:3] - pivot, fromto[3:] - pivot
            far = b if np.linalg.norm(b) >= np.linalg.norm(a) else a
            if np.linalg.norm(far) > 1e-9:
                return _unit(far)
        pos = np.asarray(geom.pos, dtype=float) - pivot
        if np.linalg.norm(pos) > 1e-9:
            return _unit(pos)
    return np.array([0.0, 0.0, 1.0])


def _massless_geoms(body: Any) -> None:
    for geom in body.geoms:
        geom.mass = 0.0
        geom.density = 0.0


def _descendants(body: Any) -> list[Any]:
    out = []
    for child in body.bodies:
        out.append(child)
        out.extend(_descendants(child))
    return out


def verify_overrides(facts: ModelFacts, p: CartPoleParams, cart: str, pole: str,
                     where: str, keys: frozenset[str] = frozenset("MmlJg")) -> None:
    """The compiled model must hold the requested ``keys`` of M, m, l, J, g: else name
    the body and why."""
    checks = (("M", facts.cart_mass, p.M, cart), ("m", facts.pole_mass, p.m, pole),
              ("l", facts.pole_com, p.l, pole), ("J", facts.pole_inertia_pivot,
                                                  p.pole_inertia_pivot, pole),
              ("g", facts.gravity, p.g, "option"))
    for name, got, want, body in checks:
        if name in keys and abs(got - want) > VERIFY_RTOL * max(abs(want), 1.0):
            raise ScenarioError(f"{where}: {name} = {want:g} did not take effect on body "
                                f"'{body}': the compiled model has {got:.9g} (check the "
                                f"compiler's settotalmass, boundmass or a frame around it)")


def apply_gear(act: Any, gear: float, where: str) -> None:
    """Make the actuator's force per unit of u at rest ``gear`` (``gear x gain``, what
    :attr:`ModelFacts.force_per_u` reads back): its transmission becomes ``gear / g0``
    (``g0``: its gain, ``gainprm[0]``; a position or velocity actuator's ``kp``/``kv``)."""
    if not (math.isfinite(gear) and gear > 0.0):
        raise ScenarioError(f"{where}: actuator gear must be positive, got {gear}")
    gain = float(act.gainprm[0])
    if gain == 0.0:
        raise ScenarioError(f"{where}: actuator '{act.name}' has gain 0: no gear makes it push")
    value = np.zeros(6)
    value[0] = gear / gain
    act.gear = value


def verify_gear(facts: ModelFacts, gear: float, actuator: str, where: str) -> None:
    """The compiled model's actuator must push ``gear`` per unit of u at rest."""
    got = facts.force_per_u
    if abs(got - gear) > VERIFY_RTOL * max(abs(gear), 1.0):
        raise ScenarioError(f"{where}: gear = {gear:g} did not take effect on actuator "
                            f"'{actuator}': the compiled model pushes {got:.9g} N per unit u")


# -- a cart-pole's model compiled with its [plant] numbers -------------------------------
def _names(elements: Any) -> str:
    return ", ".join(e.name or "<unnamed>" for e in elements) or "none"


def _spec_joint(spec: mujoco.MjSpec, name: str, jtype: mujoco.mjtJoint, kind: str,
                where: str) -> Any:
    joint = spec.joint(name)
    if joint is None:
        raise ScenarioError(f"{where}: no {kind} joint named {name!r} "
                            f"(joints in the model: {_names(spec.joints)})")
    if joint.type != jtype:
        actual = joint.type.name.removeprefix("mjJNT_").lower()
        raise ScenarioError(f"{where}: joint {name!r} is a {actual} joint, "
                            f"expected a {kind} joint")
    return joint


def _override_keys(spec: mujoco.MjSpec, overrides: "CartPoleParams | dict[str, float] | None",
                   slide: str, hinge: str, actuator: str, where: str
                   ) -> tuple[frozenset[str], CartPoleParams]:
    """Which of M, m, l, J, g to write, and the machine they make: all of them for a
    :class:`CartPoleParams`; for a dict the keys given, the model's own values for the
    rest (J: the uniform rod's when m or l changes and J is not given)."""
    if overrides is None or (isinstance(overrides, dict) and not overrides):
        return frozenset(), CartPoleParams()
    if isinstance(overrides, CartPoleParams):
        return frozenset("MmlJg"), overrides
    unknown = sorted(set(overrides) - set(OVERRIDABLE))
    if unknown:
        raise ScenarioError(f"{where}: cannot override {', '.join(unknown)} (overridable: "
                            f"{', '.join(OVERRIDABLE)})")
    try:
        # a copy: compiling the spec itself keeps its geoms' masses over the explicit
        # inertial written later (an M override on gymnasium's model did not take)
        own = read_facts(spec.copy().compile(), slide, hinge, actuator, where)
    except ValueError as exc:
        raise ScenarioError(f"{where}: cannot compile MJCF: {exc}") from exc
    base = CartPoleParams(M=own.cart_mass, m=own.pole_mass, l=own.pole_com, g=own.gravity,
                          J=own.pole_inertia_pivot)
    values = dict(overrides)
    if ("m" in values or "l" in values) and "J" not in values:
        values["J"] = 0.0
    return frozenset(overrides), replace(base, **values)


def _stretch_pole_geoms(pole: Any, pivot: np.ndarray, axis: np.ndarray, scale: float) -> None:
    """Stretch the pole's visual geoms along the pole so the drawing matches l.

    Positions move along the pole (the pivot stays put); capsules, cylinders and
    boxes whose own z runs along the pole get longer.  Anything across the pole
    (the pivot pin, the tip ball) keeps its size.
    """
    def along(v: np.ndarray) -> np.ndarray:
        r = v - pivot
        return pivot + r + (scale - 1.0) * float(r @ axis) * axis

    for geom in pole.geoms:
        fromto = np.asarray(geom.fromto, dtype=float)
        if not math.isnan(fromto[0]):
            geom.fromto = np.concatenate([along(fromto[:3]), along(fromto[3:])])
            continue
        geom.pos = along(np.asarray(geom.pos, dtype=float))
        gz = np.zeros(3)
        mujoco.mju_rotVecQuat(gz, np.array([0.0, 0.0, 1.0]), np.asarray(geom.quat, dtype=float))
        if abs(float(gz @ axis)) < 1.0 - 1e-9:
            continue
        size = np.asarray(geom.size, dtype=float).copy()
        if geom.type in (mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER):
            size[1] *= scale
        elif geom.type == mujoco.mjtGeom.mjGEOM_BOX:
            size[2] *= scale
        else:
            continue
        geom.size = size


def compile_cartpole(model_path: Any, slide_joint: str = "slider", hinge_joint: str = "hinge",
                     actuator: str = "force",
                     overrides: "CartPoleParams | dict[str, float] | None" = None,
                     integrator: str | None = None, timestep: float | None = None,
                     cart_damping: float | None = None, hinge_damping: float | None = None,
                     cart_friction: float | None = None, hinge_friction: float | None = None,
                     gear: float | None = None, ctrl_unbounded: bool = False
                     ) -> tuple[mujoco.MjModel, ModelFacts, dict[str, float]]:
    """A cart-pole MJCF compiled with what a scenario writes into it (the arguments of
    :class:`~tspend.plants.cartpole.MujocoCartPole`), checked on the compiled model: the
    model, its facts (:func:`read_facts`) and what was written (name -> value; empty: the
    model's own).  ScenarioError for a missing or unparsable file, a missing or mistyped
    joint or actuator, an actuator that does not drive the slide, an unknown integrator
    or a number that did not take."""
    from tspend.plants.articulated.machine import open_spec

    where = str(model_path)
    spec = open_spec(model_path, timestep, integrator or "")

    slide = _spec_joint(spec, slide_joint, mujoco.mjtJoint.mjJNT_SLIDE, "slide", where)
    hinge = _spec_joint(spec, hinge_joint, mujoco.mjtJoint.mjJNT_HINGE, "hinge", where)
    act = spec.actuator(actuator)
    if act is None:
        raise ScenarioError(f"{where}: no actuator named {actuator!r} "
                            f"(actuators in the model: {_names(spec.actuators)})")
    if act.trntype != mujoco.mjtTrn.mjTRN_JOINT or act.target != slide_joint:
        raise ScenarioError(f"{where}: actuator {actuator!r} drives {act.target!r}, "
                            f"not the slide joint {slide_joint!r}")

    for joint, damping, friction in ((slide, cart_damping, cart_friction),
                                     (hinge, hinge_damping, hinge_friction)):
        if damping is not None:  # MuJoCo 4 keeps [linear, 0, 0] damping coefficients
            joint.damping = [damping, 0.0, 0.0]
        if friction is not None:
            joint.frictionloss = friction
    if gear is not None:
        apply_gear(act, gear, where)
    if ctrl_unbounded:  # the paper's machine: no bound on u
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
    keys, target = _override_keys(spec, overrides, slide_joint, hinge_joint, actuator, where)
    if keys:
        pivot = np.asarray(hinge.pos, dtype=float)
        axis = _pole_direction(hinge.parent, pivot)
        old_l = float(np.linalg.norm(np.asarray(hinge.parent.ipos, dtype=float) - pivot))
        apply_overrides(spec, slide.parent, hinge, target, where, keys)
        if "l" in keys and old_l > 0.0 and target.l != old_l:
            _stretch_pole_geoms(hinge.parent, pivot, axis, target.l / old_l)

    try:
        model = spec.compile()
    except ValueError as exc:
        raise ScenarioError(f"{where}: cannot compile MJCF: {exc}") from exc
    if not (model.opt.timestep > 0.0 and math.isfinite(model.opt.timestep)):
        raise ScenarioError(f"{where}: option timestep must be a positive number, got "
                            f"{model.opt.timestep!r}")
    facts = read_facts(model, slide_joint, hinge_joint, actuator, where)
    if keys:
        checked = keys | ({"J"} if keys & {"m", "l", "J"} else set())
        verify_overrides(facts, target, slide.parent.name, hinge.parent.name, where,
                         frozenset(checked))
    if gear is not None:
        verify_gear(facts, gear, actuator, where)
    written = {k: float(getattr(target, k)) for k in sorted(keys)}
    if gear is not None:
        written["gear"] = float(gear)
    return model, facts, written
