"""A compiled MJCF read as a kinematic tree of hinge and slide joints: what the derivation needs.

:func:`read_tree` measures, from the *compiled* ``mujoco.MjModel`` (so every default,
``inertiafromgeom`` and ``<compiler>`` setting has been applied by MuJoCo itself), each
body's place in the tree (``body_pos``, ``body_quat`` in its parent's frame), its mass,
centre of mass (``body_ipos``) and principal inertia (``body_inertia`` in the frame
``body_iquat``), each joint's axis and anchor in its body's frame, armature, damping,
stiffness with its spring reference, the actuators as MuJoCo applies them (joint
transmission, gear, fixed or affine gain and bias, control and force ranges) and gravity.

What the derived equations cannot be is returned as *refusals* (free or ball joints,
tendons, equality constraints, actuator dynamics, fluid forces, gravity compensation):
the domain refuses such a model with exit 2 naming them.  What it can be but does not model exactly (dry friction, contacts that can occur)
is returned as *departures*, named on every run as the cart-pole's are.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np

__all__ = ["BodyFacts", "JointFacts", "ActuatorFacts", "Tree", "read_tree", "read_joint",
           "read_actuator", "read_gravity", "law_refusals", "collision_pairs",
           "INTEGRATOR_NAMES", "ROLES"]

#: the roles a joint can play (docs/machines.md): a cart on a rail, a pole that must stay
#: up, an arm turning about a vertical axis, a balanced rotor (reaction wheel)
ROLES = ("cart", "pole", "arm", "rotor")

_HINGE, _SLIDE = int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)
_DSBL = mujoco.mjtDisableBit

#: MuJoCo integrators by their MJCF names
INTEGRATOR_NAMES = {mujoco.mjtIntegrator.mjINT_RK4: "RK4", mujoco.mjtIntegrator.mjINT_EULER: "Euler",
                    mujoco.mjtIntegrator.mjINT_IMPLICIT: "implicit",
                    mujoco.mjtIntegrator.mjINT_IMPLICITFAST: "implicitfast"}


@dataclass(frozen=True)
class JointFacts:
    """One hinge or slide joint of the compiled model (vectors in its body's frame)."""

    name: str
    kind: str                      # "hinge" | "slide"
    body: int                      # index into Tree.bodies
    axis: tuple[float, float, float]
    anchor: tuple[float, float, float]
    qpos0: float
    armature: float
    damping: float
    stiffness: float
    springref: float
    range: tuple[float, float] | None
    #: the clamp of the total actuator force on the joint (``actuatorfrcrange``), None: none
    actfrcrange: tuple[float, float] | None = None


@dataclass(frozen=True)
class BodyFacts:
    """One moving body: its parent (-1 = the world), its frame in the parent's, its inertial
    (mass, centre of mass, principal moments in the frame ``iquat``) and its joints."""

    name: str
    parent: int
    pos: tuple[float, float, float]
    quat: tuple[float, float, float, float]
    mass: float
    ipos: tuple[float, float, float]
    iquat: tuple[float, float, float, float]
    inertia: tuple[float, float, float]
    joints: tuple[int, ...]
    world_body: int                # MuJoCo's body id (for drawing)


@dataclass(frozen=True)
class ActuatorFacts:
    """One actuator with a joint transmission, as MuJoCo applies it:
    ``f = clip(gain * clip(u, ctrl) + b0 + b1 L + b2 V, force)``, ``gain = g0 + g1 L + g2 V``,
    ``L = gear q``, ``V = gear q'``, generalised force ``gear f`` on its joint."""

    name: str
    joint: int
    gear: float
    gain: tuple[float, float, float]
    bias: tuple[float, float, float]
    ctrlrange: tuple[float, float] | None
    forcerange: tuple[float, float] | None


@dataclass(frozen=True)
class Tree:
    """A kinematic tree of hinge and slide joints: everything its equations depend on."""

    bodies: tuple[BodyFacts, ...]
    joints: tuple[JointFacts, ...]
    actuators: tuple[ActuatorFacts, ...]
    gravity: tuple[float, float, float]
    timestep: float
    integrator: str
    refusals: tuple[str, ...] = ()
    departures: tuple[str, ...] = ()
    geom_pairs: tuple[str, ...] = field(default=(), compare=False)

    @property
    def nv(self) -> int:
        return len(self.joints)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    def structure_key(self) -> str:
        """A hash of what the generated code depends on beyond its parameter vector: the
        tree's shape, joint types, axes, anchors and frames, and the actuators' structure."""
        parts: list[Any] = []
        for b in self.bodies:
            parts.append((b.parent, b.quat, b.iquat, b.joints))
        for j in self.joints:
            # a joint's force clamp only where there is one: the keys of every other tree
            # (and so their cached modules) stay what they were
            parts.append((j.kind, j.body, j.axis, j.anchor, j.qpos0)
                         + (("actfrcrange",) if j.actfrcrange is not None else ()))
        for a in self.actuators:
            parts.append((a.joint, a.ctrlrange is not None, a.forcerange is not None))
        text = repr(parts).encode()
        return hashlib.sha256(text).hexdigest()[:20]


def _t(v: Any) -> tuple[float, ...]:
    return tuple(float(c) for c in v)


def _limited(flag: Any, rng: Any) -> tuple[float, float] | None:
    return (float(rng[0]), float(rng[1])) if bool(flag) else None


def _kind(enum: Any, value: int) -> str:
    return enum(value).name.split("_", 1)[1].lower()


def law_refusals(m: mujoco.MjModel, a: int) -> list[str]:
    """What of actuator ``a``'s force law no equations of state and input can carry:
    activation dynamics, a gain other than fixed or affine, a bias other than none or affine."""
    name, out = m.actuator(a).name or str(a), []
    dyn, gain, bias = int(m.actuator_dyntype[a]), int(m.actuator_gaintype[a]), int(m.actuator_biastype[a])
    if dyn != int(mujoco.mjtDyn.mjDYN_NONE):
        out.append(f"actuator {name!r} has activation dynamics (dyntype {_kind(mujoco.mjtDyn, dyn)})")
    if gain not in (int(mujoco.mjtGain.mjGAIN_FIXED), int(mujoco.mjtGain.mjGAIN_AFFINE)):
        out.append(f"actuator {name!r} has a gain that is neither fixed nor affine (gaintype "
                   f"{_kind(mujoco.mjtGain, gain)})")
    if bias not in (int(mujoco.mjtBias.mjBIAS_NONE), int(mujoco.mjtBias.mjBIAS_AFFINE)):
        out.append(f"actuator {name!r} has a bias that is neither none nor affine (biastype "
                   f"{_kind(mujoco.mjtBias, bias)})")
    return out


def _refusals(m: mujoco.MjModel) -> list[str]:
    out = []
    kinds = {int(mujoco.mjtJoint.mjJNT_FREE): "free", int(mujoco.mjtJoint.mjJNT_BALL): "ball"}
    for j in range(m.njnt):
        if int(m.jnt_type[j]) in kinds:
            out.append(f"joint {m.joint(j).name or j!r} is a {kinds[int(m.jnt_type[j])]} joint "
                       f"(only hinge and slide joints are derived)")
    if m.nv == 0:
        out.append("the model has no joints")
    if m.nv > 6:
        out.append(f"the model has {m.nv} degrees of freedom (1 to 6 are derived)")
    if m.ntendon:
        out.append(f"the model has {m.ntendon} tendon(s)")
    if m.neq:
        out.append(f"the model has {m.neq} equality constraint(s)")
    if m.nflex if hasattr(m, "nflex") else 0:
        out.append("the model has flexes")
    for a in range(m.nu):
        name = m.actuator(a).name or str(a)
        if int(m.actuator_trntype[a]) != int(mujoco.mjtTrn.mjTRN_JOINT):
            out.append(f"actuator {name!r} does not drive a joint directly")
        out.extend(law_refusals(m, a))
        if np.any(np.asarray(m.actuator_gainprm[a, 3:]) != 0) or \
                np.any(np.asarray(m.actuator_biasprm[a, 3:]) != 0):
            out.append(f"actuator {name!r} uses gain or bias terms beyond the affine three")
        if hasattr(m, "actuator_damping") and np.any(np.asarray(m.actuator_damping[a]) != 0):
            out.append(f"actuator {name!r} has actuator damping")
    if np.any(np.asarray(m.body_gravcomp) != 0):
        out.append("a body has gravity compensation (gravcomp)")
    if m.opt.density or m.opt.viscosity or np.any(np.asarray(m.opt.wind) != 0):
        out.append("the model has fluid forces (density, viscosity or wind)")
    for name in ("dof_dampingpoly", "jnt_stiffnesspoly"):
        v = getattr(m, name, None)
        if v is not None and np.any(np.asarray(v) != 0):
            out.append(f"the model uses polynomial {name.split('_')[1].removesuffix('poly')}")
    if getattr(m, "jnt_springyield", None) is not None and \
            np.any(np.isfinite(np.asarray(m.jnt_springyield)) & (np.asarray(m.jnt_springyield) != 0)):
        out.append("a joint spring yields (springyield)")
    return out


def collision_pairs(model: mujoco.MjModel) -> list[str]:
    """Geom pairs that can touch (contype/conaffinity, explicit pairs; not within one
    body, not between static geoms, not parent-child unless the filter is off)."""
    if model.opt.disableflags & (_DSBL.mjDSBL_CONTACT | _DSBL.mjDSBL_CONSTRAINT):
        return []
    filter_parent = not model.opt.disableflags & _DSBL.mjDSBL_FILTERPARENT
    excluded = {frozenset((int(model.exclude_signature[k]) >> 16,
                           int(model.exclude_signature[k]) & 0xFFFF))
                for k in range(model.nexclude)}
    out = []
    for i in range(model.ngeom):
        for j in range(i + 1, model.ngeom):
            bi, bj = int(model.geom_bodyid[i]), int(model.geom_bodyid[j])
            wi, wj = int(model.body_weldid[bi]), int(model.body_weldid[bj])
            if wi == wj or frozenset((bi, bj)) in excluded:
                continue
            # MuJoCo's parent filter spares the world: a body touches the ground it hangs from
            if filter_parent and wi and wj and (
                    int(model.body_weldid[model.body_parentid[wi]]) == wj
                    or int(model.body_weldid[model.body_parentid[wj]]) == wi):
                continue
            if (int(model.geom_contype[i]) & int(model.geom_conaffinity[j])) or (
                    int(model.geom_contype[j]) & int(model.geom_conaffinity[i])):
                out.append(f"{model.geom(i).name or f'geom{i}'}/{model.geom(j).name or f'geom{j}'}")
    for k in range(model.npair):
        g1, g2 = int(model.pair_geom1[k]), int(model.pair_geom2[k])
        out.append(f"{model.geom(g1).name or f'geom{g1}'}/{model.geom(g2).name or f'geom{g2}'}")
    return out


def read_gravity(m: mujoco.MjModel) -> tuple[float, float, float]:
    """Gravity as MuJoCo applies it (0 when disabled)."""
    off = int(m.opt.disableflags) & _DSBL.mjDSBL_GRAVITY
    return (0.0, 0.0, 0.0) if off else _t(m.opt.gravity)  # type: ignore[return-value]


def read_joint(m: mujoco.MjModel, j: int, body: int = -1) -> JointFacts:
    """Joint ``j`` of the compiled model as MuJoCo applies it (a disabled damper or spring
    reads 0); ``body``: its body's index in :attr:`Tree.bodies`."""
    flags = int(m.opt.disableflags)
    dof, adr = int(m.jnt_dofadr[j]), int(m.jnt_qposadr[j])
    return JointFacts(
        name=m.joint(j).name or f"joint{j}",
        kind="hinge" if int(m.jnt_type[j]) == _HINGE else "slide",
        body=body, axis=_t(m.jnt_axis[j]), anchor=_t(m.jnt_pos[j]), qpos0=float(m.qpos0[adr]),
        armature=float(m.dof_armature[dof]),
        damping=0.0 if flags & _DSBL.mjDSBL_DAMPER else float(np.ravel(m.dof_damping[dof])[0]),
        stiffness=0.0 if flags & _DSBL.mjDSBL_SPRING else float(np.ravel(m.jnt_stiffness[j])[0]),
        springref=float(m.qpos_spring[adr]), range=_limited(m.jnt_limited[j], m.jnt_range[j]),
        actfrcrange=_limited(m.jnt_actfrclimited[j], m.jnt_actfrcrange[j]))


def read_actuator(m: mujoco.MjModel, a: int, joint: int = -1) -> ActuatorFacts:
    """Actuator ``a``'s force law as MuJoCo applies it (a fixed gain's or no bias's terms
    read 0, a disabled clamp no ctrl range); ``joint``: its joint's index in :attr:`Tree.joints`."""
    affine_gain = int(m.actuator_gaintype[a]) == int(mujoco.mjtGain.mjGAIN_AFFINE)
    affine_bias = int(m.actuator_biastype[a]) == int(mujoco.mjtBias.mjBIAS_AFFINE)
    gain = m.actuator_gainprm[a]
    return ActuatorFacts(
        name=m.actuator(a).name or f"actuator{a}", joint=joint, gear=float(m.actuator_gear[a, 0]),
        gain=(float(gain[0]), *((float(gain[1]), float(gain[2])) if affine_gain else (0.0, 0.0))),
        bias=_t(m.actuator_biasprm[a, :3]) if affine_bias else (0.0, 0.0, 0.0),
        ctrlrange=None if int(m.opt.disableflags) & _DSBL.mjDSBL_CLAMPCTRL
        else _limited(m.actuator_ctrllimited[a], m.actuator_ctrlrange[a]),
        forcerange=_limited(m.actuator_forcelimited[a], m.actuator_forcerange[a]))


def read_tree(m: mujoco.MjModel) -> Tree:
    """The compiled model ``m`` as a :class:`Tree` (with its refusals and departures)."""
    refusals = _refusals(m)
    bodies: list[BodyFacts] = []
    joints: list[JointFacts] = []
    index_of_body: dict[int, int] = {}
    dof_of_joint: dict[int, int] = {}
    if int(m.opt.disableflags) & _DSBL.mjDSBL_ACTUATION:
        refusals.append("actuation is disabled (<flag actuation=\"disable\"/>)")
    if not refusals:
        for b in range(1, m.nbody):
            jids = list(range(int(m.body_jntadr[b]), int(m.body_jntadr[b]) + int(m.body_jntnum[b])))
            parent = int(m.body_parentid[b])
            mine = []
            for j in jids:
                dof_of_joint[j] = len(joints)
                mine.append(len(joints))
                joints.append(read_joint(m, j, len(bodies)))
            index_of_body[b] = len(bodies)
            bodies.append(BodyFacts(
                name=m.body(b).name or f"body{b}", parent=index_of_body.get(parent, -1),
                pos=_t(m.body_pos[b]), quat=_t(m.body_quat[b]), mass=float(m.body_mass[b]),
                ipos=_t(m.body_ipos[b]), iquat=_t(m.body_iquat[b]), inertia=_t(m.body_inertia[b]),
                joints=tuple(mine), world_body=b))
        # the order of MuJoCo's qpos must be the order of the derived state
        order = [int(m.jnt_qposadr[j]) for j in range(m.njnt)]
        if order != sorted(order):
            refusals.append("the joints' qpos addresses are not in body order")
    actuators: list[ActuatorFacts] = []
    if not refusals:
        for a in range(m.nu):
            actuators.append(read_actuator(m, a, dof_of_joint[int(m.actuator_trnid[a, 0])]))
        if np.any(np.abs(np.asarray(m.actuator_gear)[:, 1:]) > 0):
            refusals.append("an actuator's gear has rotational terms")
    departures = []
    for j in range(m.njnt):
        if j < len(m.dof_frictionloss) and float(m.dof_frictionloss[int(m.jnt_dofadr[j])]) > 0:
            departures.append(f"joint {m.joint(j).name!r} has dry friction (frictionloss "
                              f"{float(m.dof_frictionloss[int(m.jnt_dofadr[j])]):g}), not in the "
                              f"derived equations")
    pairs = collision_pairs(m)
    if pairs:
        departures.append(f"contacts are enabled: {len(pairs)} geom pair(s) can touch "
                          f"({', '.join(pairs[:4])}{', ...' if len(pairs) > 4 else ''}); the derived "
                          f"equations hold while none touches")
    return Tree(bodies=tuple(bodies), joints=tuple(joints), actuators=tuple(actuators),
                gravity=read_gravity(m), timestep=float(m.opt.timestep),
                integrator=INTEGRATOR_NAMES.get(m.opt.integrator, str(m.opt.integrator)),
                refusals=tuple(refusals), departures=tuple(departures), geom_pairs=tuple(pairs))
