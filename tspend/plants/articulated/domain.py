"""The articulated-pendulum domain: any hinge/slide MJCF, its equations derived from the model.

A machine is an MJCF and a scenario (docs/machines.md): the double and triple cart-pole,
the acrobot, the pendubot, the reaction wheel, the rotary double pendulum, or a model of
one's own.  The scenario's ``[plant]`` names the model (``kind = "articulated_mujoco"``
or ``"articulated_ode"``); everything else comes from the compiled model
(:class:`.machine.Machine`): the state ``[q, q']`` named after the joints, the input
``u`` of one actuator (its range and unit), the equations (:mod:`.derive`), the joints'
roles and so the default task (every pole within the fall angle of upright, the rail's
range), and the drawing (the model's own geoms, posed by MuJoCo's kinematics).

Both plants share the state's names; ``d`` is a generalised force on the tracked pole's
joint (times ``d_scale``, 1 here; the MuJoCo cart-pole's ``-m l / (M + m)``).  The view the paper's controllers see is ``[pole, pole']`` of the first pole.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, NamedTuple, Sequence

import numpy as np
from numba.extending import register_jitable

from tspend.config import PlantConfig
from tspend.errors import ScenarioError
from tspend.plants.analytic import COMPILED_RHS, AnalyticPlant, CompiledPlant, rk4_work
from tspend.plants.articulated.machine import Machine, load_machine
from tspend.plants.base import InputInfo, JointInfo, Plant, TaskDefaults
from tspend.plants.domain import (COMPILED_VIEW_ACCEL, END_COLOR, FULL_STATE,
    SYMBOLIC, VIEW_MODEL, Backend, Domain, Drawing, FullModel, PlantLabels, PlantModel, Quantity,
    bound_text)
from tspend.plants.mujoco_plant import MujocoPlant

if TYPE_CHECKING:
    from tspend.config import Scenario
    from tspend.task import Bound

__all__ = ["ArticulatedConfig", "ArticulatedODE", "ArticulatedMujoco", "ArticulatedDomain",
           "ModelDrawing", "DOMAIN"]

#: what ``plant.integrator`` takes on every MuJoCo machine ("" keeps the model's)
#: slip velocity of the smooth dry friction F tanh(v / v_s) of the ODE twin, m/s or rad/s
DRY_FRICTION_SLIP = 1e-3

INTEGRATOR_CHOICES = ("", "RK4", "Euler", "implicit", "implicitfast")

#: the fall angle of every pole by default: a pole past the horizontal has fallen
FALL_ANGLE_RAD = math.pi / 2


@dataclass(frozen=True)
class ArticulatedConfig(PlantConfig):
    """A hinge/slide MJCF on either backend (the ODE is the compiled model's equations).

    ``x0`` is the view's initial state ``[pole, pole']`` (the first pole); ``q0`` the
    initial positions of every joint in the model's order (() = all 0; the view's pole
    takes ``x0[0]``); ``poles``: the joints the task keeps upright (() = every joint
    gravity acts on, docs/machines.md); ``actuator``: the one ``u`` drives ("" = the
    model's only one); ``timestep`` > 0 replaces the model's.  ``model_values``: what
    ``[randomize]`` drew of the model's numbers, written into it before it compiles
    (:mod:`.model_numbers`; not a ``[plant]`` key).
    """

    kind: str = "articulated_mujoco"
    x0: tuple[float, ...] = (0.1, 0.0)
    model: str = "models/double_cartpole.xml"
    q0: tuple[float, ...] = ()
    poles: tuple[str, ...] = field(default=(), metadata={"strings": True})
    actuator: str = ""
    timestep: float = field(default=0.0, metadata={"low": 0.0})
    #: MuJoCo's integrator of the model ("" keeps the model's; the ODE is stepped by RK4)
    integrator: str = field(default="", metadata={"choices": INTEGRATOR_CHOICES})
    model_values: tuple = field(default=(), metadata={"internal": True})


def _initial(machine: Machine, q0: tuple[float, ...], x0: np.ndarray, where: str) -> np.ndarray:
    nv = machine.nv
    if q0 and len(q0) != nv:
        raise ScenarioError(f"{where}: plant.q0 needs {nv} entries ({', '.join(machine.joint_names)}), "
                            f"got {len(q0)}")
    x0 = np.asarray(x0, dtype=float)
    if x0.shape != (2,):
        raise ScenarioError(f"{where}: plant.x0 needs 2 entries (the view: "
                            f"{machine.joint_names[machine.view_joint]} and its rate), got {x0.size}")
    s = np.zeros(2 * nv)
    if q0:
        s[:nv] = q0
    v = machine.view_joint
    s[v], s[nv + v] = x0[0], x0[1]
    return s


class _Named:
    """What both backends say alike of their machine (the state's names: each its own,
    from the one compiled model)."""

    machine: Machine
    domain = "articulated"
    order = 2

    @property
    def inputs(self) -> tuple[InputInfo, ...]:
        a = self.machine.actuator
        lo, hi = a.ctrlrange if a.ctrlrange is not None else (-math.inf, math.inf)
        m = self.machine
        unit = m.input_unit
        forced = unit != m.force_unit
        return (InputInfo(a.name, unit, lo, hi, m.force_unit if forced else "",
                          m.force_per_unit if forced else 1.0),)

    def default_task(self) -> TaskDefaults:
        m = self.machine
        v = m.joint_names[m.view_joint]
        poles = tuple(m.joint_names[j] for j in m.poles)
        return TaskDefaults(view=(v, f"{v}_dot"), fall_angle=FALL_ANGLE_RAD if poles else 0.0,
                            pole=poles[0] if poles else "", poles=poles)

    def parameters(self) -> dict[str, float]:
        return self.machine.parameters()

    def extras(self) -> dict[str, float]:
        s = self.full_state()
        view = set(self.default_task().view)
        return {n: float(v) for n, v in zip(self.state_names, s) if n not in view}

    def extras_index(self) -> np.ndarray:
        view = set(self.default_task().view)
        return np.array([i for i, n in enumerate(self.state_names) if n not in view], dtype=np.intp)

    @property
    def gain_sign(self) -> int:
        m = self.machine
        a = m.accelerations(np.zeros(2 * m.nv), 1.0)[m.view_joint]
        b = m.accelerations(np.zeros(2 * m.nv), 0.0)[m.view_joint]
        return 1 if a >= b else -1


class DerivedRHS(NamedTuple):
    """A derived machine as the compiled closed loop steps it: the C address of its
    generated ``rhs_c`` (a ctypes function, typed by its signature alone, so the loop's
    compiled code is one and cached whatever the machine) and its arrays."""

    fn: Any
    u: np.ndarray
    qfrc: np.ndarray
    p: np.ndarray
    M: np.ndarray
    r: np.ndarray
    actuator: int
    d_joint: int
    #: the generalised force on ``d_joint`` per unit d (1; the cart-pole's -m l / (M + m))
    d_scale: float
    #: each joint's smooth dry friction force (:func:`applied_forces`; 0: none)
    dry: np.ndarray


@register_jitable
def applied_forces(qfrc: np.ndarray, s: np.ndarray, d_joint: int, d_scale: float, d: float,
                   dry: np.ndarray) -> None:
    """The generalised forces a derived ODE applies besides its equations, into ``qfrc``:
    ``d_scale d`` on joint ``d_joint``, and on each joint ``j`` with ``dry[j] > 0`` the
    smooth dry friction ``-dry[j] tanh(q'_j / v_s)`` (the cart-pole's ODE twin: MuJoCo's
    ``frictionloss`` is a soft constraint, this its smooth stand-in, as the hand-written
    cart-pole has it; every other machine leaves dry friction out, a named departure).
    One function for the generic and the compiled loop, so they agree bit for bit."""
    nv = qfrc.size
    qfrc[:] = 0.0
    qfrc[d_joint] = d_scale * d
    for j in range(nv):
        if dry[j] > 0.0:
            qfrc[j] -= dry[j] * math.tanh(s[nv + j] / DRY_FRICTION_SLIP)


@register_jitable
def derived_rhs(m: DerivedRHS, t: float, s: np.ndarray, u: float, d: float,
                sdot: np.ndarray) -> None:
    """``s' = f(s, u)`` of the derived equations into ``sdot`` (as :meth:`Machine.rhs_into`)."""
    m.u[:] = 0.0
    m.u[m.actuator] = u
    applied_forces(m.qfrc, s, m.d_joint, m.d_scale, d, m.dry)
    m.fn(s.ctypes.data, m.u.ctypes.data, m.qfrc.ctypes.data, m.p.ctypes.data,
         m.M.ctypes.data, m.r.ctypes.data, sdot.ctypes.data)


COMPILED_RHS[DerivedRHS] = derived_rhs


def derived_rhs_of(machine: Machine, d_joint: int, d_scale: float = 1.0,
                   dry: np.ndarray | None = None) -> DerivedRHS:
    """``machine``'s :class:`DerivedRHS`, ``d`` a generalised force ``d_scale d`` on joint
    ``d_joint``, ``dry`` each joint's smooth dry friction force (None: none)."""
    import ctypes

    fn = ctypes.CFUNCTYPE(None, *[ctypes.c_void_p] * 7)(machine.module.rhs_c.address)
    fn.argtypes, fn.restype = [ctypes.c_void_p] * 7, None
    nv = machine.nv
    return DerivedRHS(fn, np.zeros(len(machine.tree.actuators)), np.zeros(nv), machine.p,
                      np.zeros(nv * nv), np.zeros(nv), machine.actuator_index, d_joint,
                      float(d_scale), np.zeros(nv) if dry is None else np.array(dry, dtype=float))


class ArticulatedODE(_Named, AnalyticPlant):
    """The derived equations (3) of :mod:`.derive`, stepped by the shared RK4."""

    name = "articulated_ode"

    def __init__(self, machine: Machine, q0: tuple[float, ...] = ()) -> None:
        AnalyticPlant.__init__(self, lambda t, s, u, d: 0.0, 2, "articulated_ode",
                               domain="articulated")
        self.machine, self.q0 = machine, tuple(q0)
        self.s = np.zeros(2 * machine.nv)
        self._work = rk4_work(self.s.size)
        self._full_order = np.arange(self.s.size, dtype=np.intp)
        self._d_joint = machine.view_joint
        #: the generalised force on ``_d_joint`` per unit d, each joint's dry friction
        #: force (:func:`applied_forces`)
        self._d_scale = 1.0
        self._dry = np.zeros(machine.nv)
        self._qfrc = np.zeros(machine.nv)

    # the MuJoCo plant names its state from the same compiled model (MujocoPlant)
    @property
    def state_names(self) -> tuple[str, ...]:
        return self.machine.state_names

    @property
    def state_units(self) -> tuple[str, ...]:
        return self.machine.state_units

    @property
    def joints(self) -> tuple[JointInfo, ...]:
        return tuple(JointInfo(j.name, j.kind, "m" if j.kind == "slide" else "rad", j.range)
                     for j in self.machine.tree.joints)

    def reset(self, x0: np.ndarray) -> None:
        self.s[:] = _initial(self.machine, self.q0, x0, self.machine.where)
        self._clock[0] = 0.0

    def full_state(self) -> np.ndarray:
        return self.s.copy()

    def rhs_into(self, t: float, s: np.ndarray, u: float, d: float, sdot: np.ndarray) -> None:
        applied_forces(self._qfrc, s, self._d_joint, self._d_scale, d, self._dry)
        self.machine.rhs_forced(s, u, self._qfrc, sdot)

    def _rhs_params(self) -> Any:
        return self

    def compiled(self) -> CompiledPlant:
        """The plant for the compiled closed loop: RK4 over the generated ``rhs_c`` by its C
        address (:class:`DerivedRHS`; a type of a generated module would not do: numba
        caches the loop with every parameter type, and the next process loading that cache
        could not import a module of the derivation cache)."""
        return CompiledPlant(derived_rhs_of(self.machine, self._d_joint, self._d_scale,
                                            self._dry), self.s, self._clock,
                             self._work, self._full_order)


class ArticulatedMujoco(_Named, MujocoPlant):
    """The MJCF stepped by MuJoCo (:class:`~tspend.plants.mujoco_plant.MujocoPlant`): ``u``
    is the actuator's ctrl, ``d`` the generalised force on the tracked pole's joint."""

    name = "articulated_mujoco"

    def __init__(self, machine: Machine, q0: tuple[float, ...] = ()) -> None:
        self.machine, self.q0 = machine, tuple(q0)
        # the tree's actuators and joints are MuJoCo's, in its order (:func:`.tree.read_tree`)
        self._attach(machine.model, machine.where, machine.actuator_index, machine.view_joint)
        self.reset(np.zeros(2))

    def departures(self, dt: float | None = None) -> list[str]:
        out = list(self.machine.tree.departures)
        if self.machine.tree.integrator != "RK4":
            out.append(f"integrator {self.machine.tree.integrator}: the ODE is stepped by RK4")
        if dt is not None and abs(round(dt / self._ts) * self._ts - dt) > 1e-9 * dt:
            out.append(f"dt = {dt:g} s is not a whole multiple of the timestep {self._ts:g} s")
        return out

    def _place(self, x0: np.ndarray) -> None:
        s = _initial(self.machine, self.q0, x0, self.machine.where)
        nv = self.machine.nv
        self.data.qpos[:] = s[:nv]
        self.data.qvel[:] = s[nv:]


# -- drawing ------------------------------------------------------------------------------
def _xyzw(q: Any) -> list[float]:
    return [float(q[1]), float(q[2]), float(q[3]), float(q[0])]


#: the drawn rail runs over [-RAIL_M, RAIL_M]: cart machines drift tens of metres in a long run
RAIL_M = 100.0
RAIL_COLOR = (90, 90, 90)


class ModelDrawing(Drawing):
    """The model's own geoms, each body an entity posed per frame by MuJoCo's kinematics
    (``mj_kinematics`` on a scratch ``MjData``: geometry only, no dynamics).  A machine on
    a cart (a slide joint on a body of the world, along x) also gets its rail, with a tick
    every metre and labelled marks, and a readout of the cart's position, the camera
    following the cart; the task's bounds are drawn as the rail's ends and as rays from a
    hinge's pivot.  ``positions`` names the extra holding a joint's position where it is
    not the joint's own name (the cart-pole's ``cart_pos``)."""

    def __init__(self, machine: Machine, view: tuple[str, ...], title: str,
                 positions: dict[str, str] | None = None) -> None:
        self.machine, self.view_names, self.title = machine, view, title
        self.positions = dict(positions or {})
        m = machine.model
        import mujoco

        data = mujoco.MjData(m)
        mujoco.mj_kinematics(m, data)
        top = max([float(data.xpos[b.world_body][2]) for b in machine.tree.bodies] + [0.0])
        reach = 0.0
        for g in range(m.ngeom):
            reach = max(reach, float(np.linalg.norm(data.geom_xpos[g])) + float(np.max(m.geom_rbound[g:g + 1])))
        self.height = top
        self.reach = max(reach, 0.5)
        self.end_position = (0.0, 0.0, top + 0.1 * self.reach)
        # the cart: a slide joint along x on a body of the world
        self.cart, self.rail_joint = -1, -1
        for j, joint in enumerate(machine.tree.joints):
            body = machine.tree.bodies[joint.body]
            if (joint.kind == "slide" and body.parent == -1
                    and abs(float(data.xaxis[j][0])) > 1.0 - 1e-9):
                self.cart, self.rail_joint = body.world_body, j
                break
        self.half_width, self.rail_z = 0.3, 0.0
        if self.cart >= 0:
            boxes = [g for g in range(m.ngeom) if int(m.geom_bodyid[g]) == self.cart
                     and int(m.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_BOX)]
            cart_z = float(data.xpos[self.cart][2])
            if boxes:
                self.half_width = float(m.geom_size[boxes[0]][1])
                self.rail_z = float(data.geom_xpos[boxes[0]][2]) - float(m.geom_size[boxes[0]][2])
            else:
                self.rail_z = cart_z
            self.end_entity = f"{m.body(self.cart).name or f'body{self.cart}'}/end"
            # above the machine's highest geom at rest, following the cart
            tip = max([float(data.geom_xpos[g][2] + m.geom_rbound[g]) for g in range(m.ngeom)
                       if int(m.geom_bodyid[g]) != 0] + [top])
            # the camera frames the moving bodies (the rail and floor would put it far away)
            self.reach = max([float(np.linalg.norm(data.geom_xpos[g] - data.xpos[self.cart]))
                              + float(m.geom_rbound[g]) for g in range(m.ngeom)
                              if int(m.geom_bodyid[g]) != 0] + [0.5])
            self.end_position = (0.0, 0.0, tip - cart_z + 0.5)

    def _body_entity(self, world: str, b: int) -> str:
        name = self.machine.model.body(b).name or f"body{b}"
        return f"{world}/{name}" if b else world

    def log_static(self, rec: Any, world: str, shade: Callable[[tuple], tuple]) -> None:
        import mujoco
        import rerun as rr

        m = self.machine.model
        rec.log(world, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        G = mujoco.mjtGeom
        for g in range(m.ngeom):
            b = int(m.geom_bodyid[g])
            path = f"{self._body_entity(world, b)}/geom_{m.geom(g).name or g}"
            rgba = np.asarray(m.geom_rgba[g])
            if int(m.geom_matid[g]) >= 0 and np.allclose(rgba, (0.5, 0.5, 0.5, 1.0)):
                rgba = m.mat_rgba[int(m.geom_matid[g])]   # the colour MuJoCo renders
            color = shade(tuple(int(255 * c) for c in rgba[:3]))
            pos, quat = np.asarray(m.geom_pos[g]), np.asarray(m.geom_quat[g])
            size = np.asarray(m.geom_size[g])
            t = int(m.geom_type[g])
            rot = rr.Quaternion(xyzw=_xyzw(quat))
            if t == int(G.mjGEOM_CAPSULE) or t == int(G.mjGEOM_CYLINDER):
                import mujoco as mj

                R = np.zeros(9)
                mj.mju_quat2Mat(R, quat)
                start = pos - R.reshape(3, 3) @ np.array([0.0, 0.0, size[1]])
                arch = rr.Capsules3D if t == int(G.mjGEOM_CAPSULE) else rr.Cylinders3D
                if arch is rr.Capsules3D:
                    rec.log(path, rr.Capsules3D(lengths=[2 * size[1]], radii=[size[0]],
                                                translations=[start], quaternions=[rot],
                                                colors=[color]), static=True)
                else:
                    rec.log(path, rr.Cylinders3D(lengths=[2 * size[1]], radii=[size[0]],
                                                 centers=[pos], quaternions=[rot], colors=[color]),
                            static=True)
            elif t == int(G.mjGEOM_BOX):
                rec.log(path, rr.Boxes3D(half_sizes=[size], centers=[pos], quaternions=[rot],
                                         colors=[color], fill_mode=rr.components.FillMode.Solid),
                        static=True)
            elif t in (int(G.mjGEOM_SPHERE), int(G.mjGEOM_ELLIPSOID)):
                half = [size[0]] * 3 if t == int(G.mjGEOM_SPHERE) else size
                rec.log(path, rr.Ellipsoids3D(half_sizes=[half], centers=[pos], quaternions=[rot],
                                              colors=[color], fill_mode=rr.components.FillMode.Solid),
                        static=True)
        if self.cart >= 0:
            cart = self._body_entity(world, self.cart)
            rec.log(f"{cart}/readout", rr.Points3D(
                [[0.0, -self.half_width - 1.0, 0.0]], radii=[0.01], colors=[(40, 40, 40)],
                show_labels=True), static=True)
            self._log_rail(rec, world, -RAIL_M, RAIL_M)

    def _log_rail(self, rec: Any, world: str, lo: float, hi: float) -> None:
        """The rail over ``[lo, hi]`` m: two lines, a tick every metre, a labelled mark every
        10 m (every 5, 2 or 1 m on a shorter rail: about eight labels, which stay apart when
        the whole rail is in view; Rerun hides the labels of an entity with more than ~30)."""
        import rerun as rr

        w, z = self.half_width, self.rail_z
        rails = [[[lo, y, z], [hi, y, z]] for y in (-w, w)]
        every = next((e for e in (1.0, 2.0, 5.0) if (hi - lo) / e <= 8.0), 10.0)
        metres = np.arange(math.ceil(lo), math.floor(hi) + 0.5, 1.0)
        ticks = [[[x, -w - (0.4 if x % every == 0 else 0.2), z], [x, -w, z]] for x in metres]
        rec.log(f"{world}/rail", rr.LineStrips3D(rails + ticks, colors=[RAIL_COLOR], radii=[0.02]),
                static=True)
        marks = np.arange(math.ceil(lo / every) * every, math.floor(hi / every) * every + 0.5 * every,
                          every)
        rec.log(f"{world}/rail/marks", rr.Points3D(
            np.column_stack([marks, np.full(marks.size, -w - 0.7), np.full(marks.size, z)]),
            radii=[0.04], colors=[RAIL_COLOR],
            labels=[f"{x:+.0f} m" if x else "0 m" for x in marks], show_labels=True), static=True)

    def log_bounds(self, rec: Any, world: str, bounds: Sequence[Bound],
                   shade: Callable[[tuple], tuple]) -> None:
        """The rail's ends (the cart's bound; the rail is drawn up to them) as red posts
        labelled with their position; a hinge's bound (fall angle or range) as two red
        rays from its pivot, in its parent body's frame, along the angles that end the run."""
        import mujoco
        import rerun as rr

        m, nv = self.machine.model, self.machine.nv
        red = shade(END_COLOR)
        data = mujoco.MjData(m)
        for bound in bounds:
            ends = [v for v in (bound.lo, bound.hi) if math.isfinite(v)]
            if not ends or bound.index >= nv:
                continue
            j = bound.index
            joint = self.machine.tree.joints[j]
            if j == self.rail_joint:
                lo = bound.lo if math.isfinite(bound.lo) else -RAIL_M
                hi = bound.hi if math.isfinite(bound.hi) else RAIL_M
                self._log_rail(rec, world, lo - 1.0, hi + 1.0)
                w, z = self.half_width, self.rail_z
                posts = [[[x, y, z], [x, y, z + 1.5]] for x in ends for y in (-w, w)]
                rec.log(f"{world}/rail/ends", rr.LineStrips3D(posts, colors=[red], radii=[0.06]),
                        static=True)
                rec.log(f"{world}/rail/ends/labels", rr.Points3D(
                    [[x, -w, z + 1.8] for x in ends], radii=[0.05], colors=[red],
                    labels=[f"{bound.status} {x:+g} {bound.unit}".rstrip() for x in ends],
                    show_labels=True), static=True)
            elif joint.kind == "hinge":
                body = self.machine.tree.bodies[joint.body].world_body
                parent = int(m.body_parentid[body])
                rays = []
                for a in ends:
                    data.qpos[:] = 0.0
                    data.qpos[j] = a
                    mujoco.mj_kinematics(m, data)
                    pivot, com = data.xanchor[j].copy(), data.xipos[body].copy()
                    tip = pivot + 2.0 * (com - pivot)
                    R, origin = data.xmat[parent].reshape(3, 3), data.xpos[parent]
                    rays.append([list(R.T @ (pivot - origin)), list(R.T @ (tip - origin))])
                entity = f"{self._body_entity(world, parent)}/bounds"
                rec.log(entity, rr.LineStrips3D(rays, colors=[red], radii=[0.02]), static=True)
                # one label, in the rays' red, under the cart's readout: clear of the machine
                # and the rail's marks, inside a view half as wide (the cross-check's)
                rec.log(f"{entity}/label", rr.Points3D(
                    [[0.0, -self.half_width - 1.0, -1.6]], colors=[red], radii=[0.01],
                    show_labels=True, labels=[bound_text(bound)]), static=True)

    def log_frames(self, rec: Any, world: str, times: Any, x: np.ndarray,
                   extras: dict[str, np.ndarray]) -> None:
        import mujoco
        import rerun as rr

        m = self.machine.model
        nv = self.machine.nv
        n = x.shape[0]
        q = np.zeros((n, nv))
        for j, name in enumerate(self.machine.joint_names):
            key = self.positions.get(name, name)
            if name in self.view_names:
                q[:, j] = x[:, self.view_names.index(name)]
            elif key in extras:
                q[:, j] = extras[key]
        data = mujoco.MjData(m)
        bodies = [b.world_body for b in self.machine.tree.bodies]
        pos = np.zeros((len(bodies), n, 3))
        quat = np.zeros((len(bodies), n, 4))
        for k in range(n):
            data.qpos[:] = q[k]
            mujoco.mj_kinematics(m, data)
            for i, b in enumerate(bodies):
                pos[i, k] = data.xpos[b]
                quat[i, k] = data.xquat[b][[1, 2, 3, 0]]
        for i, b in enumerate(bodies):
            rec.send_columns(self._body_entity(world, b), indexes=[times],
                             columns=rr.Transform3D.columns(translation=pos[i], quaternion=quat[i]))
        if self.cart >= 0:
            labels = [f"x_c = {x:+.2f} m" for x in q[:, self.rail_joint]]
            rec.send_columns(f"{self._body_entity(world, self.cart)}/readout", indexes=[times],
                             columns=rr.Points3D.columns(labels=labels))

    def view(self, origin: str, suffix: str = "") -> Any:
        import rerun.blueprint as rrb

        r = self.reach
        # a cart's camera follows the cart (its drift shows as the rail's marks passing by)
        follow = {} if self.cart < 0 else {
            "tracking_entity": self._body_entity(origin, self.cart)}
        return rrb.Spatial3DView(
            origin=origin, name=f"{self.title}{suffix}", line_grid=rrb.LineGrid3D(visible=False),
            eye_controls=rrb.EyeControls3D(position=[0.0, -2.2 * r, 0.6 * r + 0.5 * self.height],
                                           look_target=[0.0, 0.0, 0.5 * self.height],
                                           eye_up=[0.0, 0.0, 1.0], **follow))

    def document(self) -> dict[str, Any]:
        return {"mjcf": str(self.machine.where), "bodies": [b.name for b in self.machine.tree.bodies]}


# -- the domain ---------------------------------------------------------------------------
def _machine_of(cfg: ArticulatedConfig, model_path: Path) -> Machine:
    return load_machine(model_path, cfg.timestep, cfg.actuator, tuple(cfg.poles),
                        tuple(cfg.model_values), cfg.integrator)


def _build_ode(cfg: PlantConfig, model_path: Path) -> Plant:
    assert isinstance(cfg, ArticulatedConfig)
    return ArticulatedODE(_machine_of(cfg, model_path), tuple(cfg.q0))


def _build_mujoco(cfg: PlantConfig, model_path: Path) -> Plant:
    assert isinstance(cfg, ArticulatedConfig)
    return ArticulatedMujoco(_machine_of(cfg, model_path), tuple(cfg.q0))


class DerivedFull(NamedTuple):
    """A derived machine as compiled full-state controllers (the swing-up) ask for it
    (:func:`derived_full_accel`, :func:`derived_pole_energy`): ``q''(s, u)`` and the energy of the pole ``pole`` with every other joint at rest at 0
    (the machine's ``T + V`` there, less its value upright at rest ``V0``), through the
    generated ``rhs_c`` and ``energy_c`` by their C addresses."""

    rhs: DerivedRHS
    energy_fn: Any
    pole: int
    s: np.ndarray
    sdot: np.ndarray
    T: np.ndarray
    V: np.ndarray
    pad: np.ndarray
    V0: float


@register_jitable
def derived_full_accel(m: DerivedFull, s: np.ndarray, u: float) -> tuple:
    """``q''(s, u)`` padded with zeros to 6 entries (the derivation's most joints): a
    tuple, as compiled code without allocation can return one."""
    derived_rhs(m.rhs, 0.0, s, u, 0.0, m.sdot)
    q = m.sdot[m.s.size // 2:]
    a = m.pad
    for i in range(6):
        a[i] = q[i] if i < q.size else 0.0
    return a[0], a[1], a[2], a[3], a[4], a[5]


@register_jitable
def derived_pole_energy(m: DerivedFull, s: np.ndarray) -> float:
    nv = m.s.size // 2
    m.s[:] = 0.0
    m.s[m.pole] = s[m.pole]
    m.s[nv + m.pole] = s[nv + m.pole]
    m.energy_fn(m.s.ctypes.data, m.s[nv:].ctypes.data, m.rhs.p.ctypes.data,
                m.T.ctypes.data, m.V.ctypes.data)
    return m.T[0] + m.V[0] - m.V0


def derived_full_of(machine: Machine, pole: int) -> DerivedFull:
    """``machine``'s :class:`DerivedFull` for its pole ``pole``."""
    import ctypes

    fn = ctypes.CFUNCTYPE(None, *[ctypes.c_void_p] * 5)(machine.module.energy_c.address)
    fn.argtypes, fn.restype = [ctypes.c_void_p] * 5, None
    nv = machine.nv
    full = DerivedFull(derived_rhs_of(machine, machine.view_joint), fn, pole, np.zeros(2 * nv),
                       np.zeros(2 * nv), np.zeros(1), np.zeros(1), np.zeros(6), 0.0)
    return full._replace(V0=derived_pole_energy(full, np.zeros(2 * nv)))


class DerivedView(NamedTuple):
    """The paper's controllers' model of the view: the tracked pole's acceleration with
    every other joint at rest (as :class:`~tspend.plants.domain.PlantModel` asks), from
    the derived equations through :class:`DerivedRHS`, for Python and compiled code."""

    rhs: DerivedRHS
    s: np.ndarray
    sdot: np.ndarray
    joint: int

    def accel(self, t: float, x: np.ndarray, u: float, d: float) -> float:
        return derived_view_accel(self, t, x, u, d)


@register_jitable
def derived_view_accel(v: DerivedView, t: float, x: np.ndarray, u: float, d: float) -> float:
    nv = v.s.size // 2
    v.s[:] = 0.0
    v.s[v.joint] = x[0]
    v.s[nv + v.joint] = x[1]
    derived_rhs(v.rhs, t, v.s, u, d, v.sdot)
    return v.sdot[nv + v.joint]


COMPILED_VIEW_ACCEL[DerivedView] = derived_view_accel


def derived_view(machine: Machine, d_scale: float = 1.0) -> DerivedView:
    """``machine``'s view model (its first pole's, ``d_scale d`` on that joint)."""
    nv = machine.nv
    return DerivedView(derived_rhs_of(machine, machine.view_joint, d_scale), np.zeros(2 * nv),
                       np.zeros(2 * nv), machine.view_joint)


class ArticulatedDomain(Domain):
    """Any kinematic tree of hinge and slide joints, from its MJCF (module docstring)."""

    name = "articulated"
    kinds = {"articulated_ode": Backend(ArticulatedConfig, _build_ode),
             "articulated_mujoco": Backend(ArticulatedConfig, _build_mujoco, mujoco=True)}
    labels = PlantLabels(
        states=(Quantity("q", "rad", "the tracked pole's angle"),
                Quantity("q'", "rad/s", "the tracked pole's rate")),
        control=Quantity("u", "", "the actuator's input"), extras={},
        disturbance=Quantity("d", "", "generalised force on the tracked pole's joint"))
    #: the view's two entries stand for the tracked pole's angle and rate (each plant names
    #: them after its model's joint: :meth:`view_names`)
    task = TaskDefaults(view=("pole", "pole_dot"), fall_angle=FALL_ANGLE_RAD)
    default_model = ArticulatedConfig.model
    provides = frozenset({VIEW_MODEL, FULL_STATE, SYMBOLIC})
    derives_equations = True

    def model_file(self, cfg: PlantConfig) -> str:
        return cfg.model if isinstance(cfg, ArticulatedConfig) else self.default_model

    def view_names(self, plant: Plant) -> tuple[str, ...]:
        return plant.default_task().view

    def machine(self, scenario: "Scenario") -> Machine:
        return self.build(scenario).machine  # type: ignore[attr-defined]

    def nominal_values(self, scenario: "Scenario") -> dict[str, float]:
        """The compiled model's ``BODY.mass``, ``JOINT.damping``, ``JOINT.armature``
        (:mod:`.model_numbers`): what a ``[randomize]`` entry may name, and its nominal."""
        from tspend.plants.articulated.model_numbers import model_values

        return model_values(self.machine(scenario).model)

    def plant_model(self, scenario: "Scenario", machine: Plant) -> PlantModel:
        view = derived_view(machine.machine)  # type: ignore[attr-defined]
        return PlantModel(scenario.plant.kind, 2, view.accel, affine_in_u=True,
                          x_op=(0.0, 0.0), switching_gain=20.0, compiled=view)

    def full_model(self, scenario: "Scenario", machine: Plant) -> FullModel:
        """The derived equations over ``[q, q']`` (the joints' names): numbers through the
        compiled module, CasADi through the derivation (no clips: MPC bounds u)."""
        m: Machine = machine.machine  # type: ignore[attr-defined]
        nv = m.nv

        def factory(sin, cos, tanh):
            if sin is math.sin:
                return lambda s, u: tuple(m.accelerations(np.asarray(s, dtype=float), float(u)))

            def q_dd(s, u):
                a = m.symbolic_accel(s, u)
                return tuple(a[i] for i in range(nv))

            return q_dd

        angles = tuple(j.kind == "hinge" for j in m.tree.joints) + (False,) * nv
        poles = m.poles
        return FullModel(domain=self.name, state_names=m.state_names, accel_factory=factory,
                         energy=m.energy, pole=poles[0] if poles else m.actuated,
                         actuated=m.actuated, angles=angles, parameters=m.parameters(),
                         machine=None, poles=poles,
                         accel_unit="m/s^2" if m.tree.joints[m.actuated].kind == "slide" else "rad/s^2")

    def linearisation(self, scenario: "Scenario", machine: Plant) -> tuple[np.ndarray, np.ndarray]:
        return machine.machine.linearisation()  # type: ignore[attr-defined]

    def jacobians(self, plant: Plant, at: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        return plant.machine.linearisation(at)  # type: ignore[attr-defined]

    def drawing(self, plant: Plant, scenario: "Scenario") -> Drawing | None:
        m: Machine = plant.machine  # type: ignore[attr-defined]
        return ModelDrawing(m, plant.default_task().view, Path(m.where).stem.replace("_", " "))

    def chirp_amplitude(self, plant: Plant) -> float:
        a = plant.machine.actuator  # type: ignore[attr-defined]
        if a.ctrlrange is not None:
            return 0.3 * min(abs(a.ctrlrange[0]), abs(a.ctrlrange[1]))
        return 1.0

    def ode_of(self, plant: Plant) -> Plant:
        return ArticulatedODE(plant.machine, plant.q0)  # type: ignore[attr-defined]

    def fits_mjcf(self, joint_types: tuple[str, ...]) -> bool:
        return bool(joint_types) and all(t in ("hinge", "slide") for t in joint_types) \
            and len(joint_types) <= 6

    def inspect(self, model_path: str, names: dict[str, str] | None = None,
                dt: float | None = None) -> tuple[dict[str, Any], list[str]]:
        """The model's joints with their roles, the actuator, the upright's open-loop poles
        and controllability."""
        m = load_machine(model_path)
        plant = ArticulatedMujoco(m)
        facts: dict[str, Any] = {
            "domain": self.name,
            "joints": {j.name: {"type": j.kind, "role": r,
                                **({"range": list(j.range)} if j.range else {})}
                       for j, r in zip(m.tree.joints, m.roles)},
            "actuator": {"name": m.actuator.name, "joint": m.joint_names[m.actuated],
                         "unit": m.input_unit,
                         **({"ctrlrange": list(m.actuator.ctrlrange)} if m.actuator.ctrlrange else {})},
            "tracked": m.joint_names[m.view_joint], "timestep": plant.timestep,
            "integrator": m.tree.integrator,
            "bodies": {b.name: {"mass": b.mass} for b in m.tree.bodies},
        }
        A, B = m.linearisation()
        facts["upright_poles"] = sorted((complex(e) for e in np.linalg.eigvals(A)),
                                        key=lambda e: (e.real, e.imag))
        facts["upright_poles"] = [round(e.real, 6) if abs(e.imag) < 1e-12 else
                                  f"{e.real:.6g}{e.imag:+.6g}j" for e in facts["upright_poles"]]
        n = A.shape[0]
        C = np.hstack([np.linalg.matrix_power(A, k) @ B for k in range(n)])
        facts["controllable"] = bool(np.linalg.matrix_rank(C, tol=1e-9 * max(1.0, np.abs(C).max())) == n)
        return facts, plant.departures(dt)


#: the articulated domain
DOMAIN = ArticulatedDomain()
