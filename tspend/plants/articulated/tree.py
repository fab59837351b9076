"""A compiled MJCF read as a kinematic tree of hinge and slide joints: what the derivation needs.

:func:`read_tree` measures, from the *compiled* ``mujoco.MjModel`` (so every default,
``inertiafromgeom`` and ``<compiler>`` setting has been applied by MuJoCo itself), each
body's place in the tree (``body_pos``, ``body_quat`` in its parent's frame), its mass,
centre of mass (``body_ipos``) and principal inertia (``body_inertia`` in the frame
``body_iquat``), each joint's axis and anchor in its body's frame, armature, damping,
stiffness with its spring reference, the actuators as MuJoCo applies them (joint
transmission, gear, fixed or affine gain and bias, control and force ranges) and gravity.

What the derived equations cannot be is returned as *refusals* (free or ball joints,
tendons, equality constraints, actuator dynamics, fluid forces, gravity compensation, a
joint-space actuator force limit): the domain refuses such a model with exit 2 naming
them.  What it can be but does not model exactly (dry friction, contacts that can occur)
is returned as *departures*, named on every run as the cart-pole's are.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np

__all__ = ["BodyFacts", "JointFacts", "ActuatorFacts", "Tree", "read_tree", "ROLES"]

#: the roles a joint can play (docs/machines.md): a cart on a rail, a pole that must stay
#: up, an arm turning about a vertical axis, a balanced rotor (reaction wheel)
ROLES = ("cart", "pole", "arm", "rotor")

_HINGE, _SLIDE = int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)


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
            parts.append((j.kind, j.body, j.axis, j.anchor, j.qpos0))
        for a in self.actuators:
            parts.append((a.joint, a.ctrlrange is not None, a.forcerange is not None))
        text = repr(parts).encode()
        return hashlib.sha256(text).hexdigest()[:20]


def _t(v: Any) -> tuple[float, ...]:
    return tuple(float(c) for c in v)


def _limited(flag: Any, rng: Any) -> tuple[float, float] | None:
    return (float(rng[0]), float(rng[1])) if bool(flag) else None


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
        if int(m.actuator_dyntype[a]) != int(mujoco.mjtDyn.mjDYN_NONE):
            out.append(f"actuator {name!r} has activation dynamics")
        if int(m.actuator_gaintype[a]) not in (int(mujoco.mjtGain.mjGAIN_FIXED),
                                               int(mujoco.mjtGain.mjGAIN_AFFINE)):
            out.append(f"actuator {name!r} has a gain that is neither fixed nor affine")
        if int(m.actuator_biastype[a]) not in (int(mujoco.mjtBias.mjBIAS_NONE),
                                               int(mujoco.mjtBias.mjBIAS_AFFINE)):
            out.append(f"actuator {name!r} has a bias that is neither none nor affine")
        if np.any(np.asarray(m.actuator_gainprm[a, 3:]) != 0) or \
                np.any(np.asarray(m.actuator_biasprm[a, 3:]) != 0):
            out.append(f"actuator {name!r} uses gain or bias terms beyond the affine three")
        if hasattr(m, "actuator_damping") and np.any(np.asarray(m.actuator_damping[a]) != 0):
            out.append(f"actuator {name!r} has actuator damping")
    if np.any(np.asarray(m.body_gravcomp) != 0):
        out.append("a body has gravity compensation (gravcomp)")
    if m.opt.density or m.opt.viscosity or np.any(np.asarray(m.opt.wind) != 0):
        out.append("the model has fluid forces (density, viscosity or wind)")
    if np.any(np.asarray(m.jnt_actfrclimited)):
        out.append("a joint limits its actuator force (actuatorfrcrange)")
    for name in ("dof_dampingpoly", "jnt_stiffnesspoly"):
        v = getattr(m, name, None)
        if v is not None and np.any(np.asarray(v) != 0):
            out.append(f"the model uses polynomial {name.split('_')[1].removesuffix('poly')}")
    if getattr(m, "jnt_springyield", None) is not None and \
            np.any(np.isfinite(np.asarray(m.jnt_springyield)) & (np.asarray(m.jnt_springyield) != 0)):
        out.append("a joint spring yields (springyield)")
    return out


def collision_pairs(m: mujoco.MjModel) -> list[str]:
    """The geom pairs of different bodies that MuJoCo's collision filter lets touch."""
    if m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_CONTACT):
        return []
    out = []
    for a in range(m.ngeom):
        for b in range(a + 1, m.ngeom):
            if m.geom_bodyid[a] == m.geom_bodyid[b]:
                continue
            if (m.geom_contype[a] & m.geom_conaffinity[b]) or (m.geom_contype[b] & m.geom_conaffinity[a]):
                out.append(f"{m.geom(a).name or a!s}/{m.geom(b).name or b!s}")
    return out


def read_tree(m: mujoco.MjModel) -> Tree:
    """The compiled model ``m`` as a :class:`Tree` (with its refusals and departures)."""
    refusals = _refusals(m)
    bodies: list[BodyFacts] = []
    joints: list[JointFacts] = []
    index_of_body: dict[int, int] = {}
    dof_of_joint: dict[int, int] = {}
    flags = int(m.opt.disableflags)
    no_damper = bool(flags & int(mujoco.mjtDisableBit.mjDSBL_DAMPER))
    no_spring = bool(flags & int(mujoco.mjtDisableBit.mjDSBL_SPRING))
    no_clamp = bool(flags & int(mujoco.mjtDisableBit.mjDSBL_CLAMPCTRL))
    if flags & int(mujoco.mjtDisableBit.mjDSBL_ACTUATION):
        refusals.append("actuation is disabled (<flag actuation=\"disable\"/>)")
    if not refusals:
        for b in range(1, m.nbody):
            jids = list(range(int(m.body_jntadr[b]), int(m.body_jntadr[b]) + int(m.body_jntnum[b])))
            parent = int(m.body_parentid[b])
            mine = []
            for j in jids:
                dof = int(m.jnt_dofadr[j])
                dof_of_joint[j] = len(joints)
                mine.append(len(joints))
                joints.append(JointFacts(
                    name=m.joint(j).name or f"joint{j}",
                    kind="hinge" if int(m.jnt_type[j]) == _HINGE else "slide",
                    body=len(bodies), axis=_t(m.jnt_axis[j]), anchor=_t(m.jnt_pos[j]),
                    qpos0=float(m.qpos0[int(m.jnt_qposadr[j])]),
                    armature=float(m.dof_armature[dof]),
                    damping=0.0 if no_damper else float(np.ravel(m.dof_damping[dof])[0]),
                    stiffness=0.0 if no_spring else float(np.ravel(m.jnt_stiffness[j])[0]),
                    springref=float(m.qpos_spring[int(m.jnt_qposadr[j])]),
                    range=_limited(m.jnt_limited[j], m.jnt_range[j])))
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
            j = int(m.actuator_trnid[a, 0])
            actuators.append(ActuatorFacts(
                name=m.actuator(a).name or f"actuator{a}", joint=dof_of_joint[j],
                gear=float(m.actuator_gear[a, 0]),
                gain=(float(m.actuator_gainprm[a, 0]),
                      *((float(m.actuator_gainprm[a, 1]), float(m.actuator_gainprm[a, 2]))
                        if int(m.actuator_gaintype[a]) == int(mujoco.mjtGain.mjGAIN_AFFINE)
                        else (0.0, 0.0))),
                bias=tuple(float(v) for v in m.actuator_biasprm[a, :3])
                if int(m.actuator_biastype[a]) == int(mujoco.mjtBias.mjBIAS_AFFINE) else (0.0, 0.0, 0.0),
                ctrlrange=None if no_clamp else _limited(m.actuator_ctrllimited[a],
                                                         m.actuator_ctrlrange[a]),
                forcerange=_limited(m.actuator_forcelimited[a], m.actuator_forcerange[a])))
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
    if m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_GRAVITY):
        gravity = (0.0, 0.0, 0.0)
    else:
        gravity = _t(m.opt.gravity)
    from tspend.plants.mjcf import INTEGRATOR_NAMES

    return Tree(bodies=tuple(bodies), joints=tuple(joints), actuators=tuple(actuators),
                gravity=gravity, timestep=float(m.opt.timestep),
                integrator=INTEGRATOR_NAMES.get(m.opt.integrator, str(m.opt.integrator)),
                refusals=tuple(refusals), departures=tuple(departures), geom_pairs=tuple(pairs))
