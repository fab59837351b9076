"""Any compiled MJCF drawn from its own geoms, posed by MuJoCo's kinematics (:class:`ModelDrawing`).

Every machine derived from its model (the cart-pole, the articulated machines) is drawn
this way; a machine on a cart also gets its rail.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from tspend.plants.drawing.base import END_COLOR, Drawing, bound_text

if TYPE_CHECKING:
    from tspend.plants.articulated.machine import Machine
    from tspend.task import Bound

__all__ = ["ModelDrawing", "RAIL_M"]


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
