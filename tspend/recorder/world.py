"""The static 3D scene of a cart-pole: ground frame, cart and pole shapes, the rail
with distance marks, and the cart-position readout."""

from __future__ import annotations

from typing import Callable

import numpy as np
import rerun as rr

from tspend.recorder.cartpole import CartPoleGeometry
from tspend.recorder.common import Color

#: the rail runs over [-RAIL_M, RAIL_M]: cart-poles drift tens of metres in a long run
RAIL_M = 100.0
#: a short tick every metre, a labelled mark every LABEL_EVERY_M (Rerun hides labels
#: of entities with more than ~30 instances, so the labels stay fewer than that)
LABEL_EVERY_M = 10.0
RAIL_COLOR = (90, 90, 90)


def readout_labels(cart_pos: np.ndarray) -> list[str]:
    """The text shown on the cart at each frame."""
    return [f"x_c = {x:+.2f} m" for x in np.asarray(cart_pos, dtype=np.float64)]


def log_world(rec: rr.RecordingStream, world: str, geom: CartPoleGeometry,
              shade: Callable[[Color], Color]) -> None:
    """Log the static scene under entity ``world``; ``shade`` maps colours (overlaid runs)."""
    rec.log(world, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log(f"{world}/cart", rr.Boxes3D(half_sizes=[geom.cart_half_sizes], colors=[shade(geom.cart_color)],
                                        fill_mode=rr.components.FillMode.Solid), static=True)
    rec.log(f"{world}/cart/readout", rr.Points3D(
        [[0.0, -geom.cart_half_sizes[1] - 1.0, 0.0]], radii=[0.01], colors=[(40, 40, 40)], show_labels=True),
        static=True)
    rec.log(f"{world}/pole", rr.Capsules3D(
        lengths=[2.0 * geom.l], radii=[geom.pole_radius], translations=[[0.0, 0.0, -geom.l]],
        colors=[shade(geom.pole_color)]), static=True)
    half_width = geom.cart_half_sizes[1]
    rails = [[[-RAIL_M, y, 0.0], [RAIL_M, y, 0.0]] for y in (-half_width, half_width)]
    metres = np.arange(-RAIL_M, RAIL_M + 0.5, 1.0)
    ticks = [[[x, -half_width - (0.4 if x % LABEL_EVERY_M == 0 else 0.2), 0.0], [x, -half_width, 0.0]]
             for x in metres]
    rec.log(f"{world}/rail", rr.LineStrips3D(rails + ticks, colors=[RAIL_COLOR], radii=[0.02]), static=True)
    marks = np.arange(-RAIL_M, RAIL_M + 0.5, LABEL_EVERY_M)
    rec.log(f"{world}/rail/marks", rr.Points3D(
        np.column_stack([marks, np.full(marks.size, -half_width - 0.7), np.zeros(marks.size)]),
        radii=[0.04], colors=[RAIL_COLOR], labels=[f"{x:+.0f} m" if x else "0 m" for x in marks],
        show_labels=True), static=True)
