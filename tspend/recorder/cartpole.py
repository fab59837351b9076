"""The 3D cart-pole: poses of cart and pole, and sizes/colours (from the MJCF geoms when given)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from tspend.plants.base import CartPoleDrawing
from tspend.loop.sinks import RunInfo
from tspend.recorder.common import Color


#: default cart box (x, y, z) in metres
CART_SIZE = (1.0, 0.6, 0.4)
POLE_RADIUS = 0.05
#: pole half-length used when the plant metadata does not give one
DEFAULT_POLE_HALF_LENGTH = 3.0


class CartPolePoses(NamedTuple):
    """World poses (z up) of the cart box centre and of the pole's centre of mass."""

    cart_translation: np.ndarray   # (N, 3)
    pole_translation: np.ndarray   # (N, 3), the pole's COM
    pole_quaternion: np.ndarray    # (N, 4), xyzw; rotates local +z onto the pole axis


def cartpole_poses(cart_pos: np.ndarray | float, theta: np.ndarray | float, l: float,
                   cart_height: float = CART_SIZE[2]) -> CartPolePoses:
    """Poses of cart and pole for cart positions ``cart_pos`` and pole angles ``theta``.

    x points right (the cart's rail), z up.  The cart box sits on z = 0; the pole's
    pivot is the centre of the box's top face; the pole (length ``2 l``) points along
    ``(-sin theta, 0, cos theta)``, so ``theta > 0`` leans it toward -x, and its centre
    of mass is ``l`` from the pivot.  Draw the pole as a capsule from local
    ``(0, 0, -l)`` to ``(0, 0, l)``.
    """
    xc = np.atleast_1d(np.asarray(cart_pos, dtype=np.float64))
    th = np.atleast_1d(np.asarray(theta, dtype=np.float64))
    xc, th = np.broadcast_arrays(xc, th)
    zeros = np.zeros_like(th)
    cart = np.column_stack([xc, zeros, np.full_like(th, 0.5 * cart_height)])
    pole = np.column_stack([xc - l * np.sin(th), zeros, cart_height + l * np.cos(th)])
    # rotation by -theta about +y maps +z onto (-sin theta, 0, cos theta)
    half = -0.5 * th
    quat = np.column_stack([zeros, np.sin(half), zeros, np.cos(half)])
    return CartPolePoses(cart, pole, quat)


@dataclass(frozen=True)
class CartPoleGeometry:
    """Sizes and colours of the drawn cart-pole."""

    l: float = DEFAULT_POLE_HALF_LENGTH
    cart_half_sizes: tuple[float, float, float] = (0.5 * CART_SIZE[0], 0.5 * CART_SIZE[1], 0.5 * CART_SIZE[2])
    cart_color: Color = (70, 110, 170)
    pole_radius: float = POLE_RADIUS
    pole_color: Color = (220, 140, 40)


def is_cartpole(info: RunInfo) -> bool:
    """Whether the run's plant is a cart-pole worth drawing in 3D."""
    kind = info.plant_kind.lower().replace("-", "").replace("_", "")
    return info.order == 2 and ("cartpole" in kind or "cart_pos" in info.extras)


def cartpole_geometry(drawing: CartPoleDrawing | None) -> CartPoleGeometry:
    """Geometry from the plant metadata; box/capsule sizes from the MJCF when given.

    Reading the MJCF is best effort: any failure keeps the default drawing.
    """
    geom = CartPoleGeometry(l=drawing.l if drawing is not None else DEFAULT_POLE_HALF_LENGTH)
    mjcf = drawing.mjcf if drawing is not None else ""
    if mjcf:
        geom = _geometry_from_mjcf(str(mjcf), geom)
    return geom


def _geometry_from_mjcf(path: str, base: CartPoleGeometry) -> CartPoleGeometry:
    """Cart = the box on the slider's body; pole = the longest capsule/cylinder on the hinge's body.

    Colours as MuJoCo renders them (the material's when the geom keeps the default rgba).
    """
    try:
        import mujoco

        model = mujoco.MjModel.from_xml_path(path)
    except Exception:  # noqa: BLE001 - drawing must never stop a run
        return base

    def body_of(joint_type: int) -> int | None:
        found = [int(model.jnt_bodyid[j]) for j in range(model.njnt) if int(model.jnt_type[j]) == joint_type]
        return found[0] if found else None

    def color(g: int) -> Color:
        rgba = model.geom_rgba[g]
        if int(model.geom_matid[g]) >= 0 and np.allclose(rgba, (0.5, 0.5, 0.5, 1.0)):
            rgba = model.mat_rgba[int(model.geom_matid[g])]
        return tuple(int(round(255 * c)) for c in rgba[:3])  # type: ignore[return-value]

    cart_body, pole_body = body_of(mujoco.mjtJoint.mjJNT_SLIDE), body_of(mujoco.mjtJoint.mjJNT_HINGE)
    geoms = range(model.ngeom)
    boxes = [g for g in geoms if int(model.geom_bodyid[g]) == cart_body
             and int(model.geom_type[g]) == mujoco.mjtGeom.mjGEOM_BOX]
    rods = [g for g in geoms if int(model.geom_bodyid[g]) == pole_body
            and int(model.geom_type[g]) in (mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER)]
    geom = base
    if boxes:
        size = model.geom_size[boxes[0]]
        geom = replace(geom, cart_half_sizes=(float(size[0]), float(size[1]), float(size[2])),
                       cart_color=color(boxes[0]))
    if rods:
        rod = max(rods, key=lambda g: float(model.geom_size[g][1]))
        geom = replace(geom, pole_radius=float(model.geom_size[rod][0]), pole_color=color(rod))
    return geom
