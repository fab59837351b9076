"""The Furuta pendulum (the QUBE-Servo 2) drawn as the rig looks (:class:`FurutaDrawing`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from tspend.plants.drawing.base import END_COLOR, Drawing, bound_text

if TYPE_CHECKING:
    from tspend.task import Bound

__all__ = ["FurutaDrawing"]


def _quat_z(angle: np.ndarray) -> np.ndarray:
    z = np.zeros_like(angle)
    return np.column_stack([z, z, np.sin(0.5 * angle), np.cos(0.5 * angle)])


def _quat_x(angle: np.ndarray) -> np.ndarray:
    z = np.zeros_like(angle)
    return np.column_stack([np.sin(0.5 * angle), z, z, np.cos(0.5 * angle)])


@dataclass(frozen=True)
class FurutaDrawing(Drawing):
    """The QUBE seen from its front: base, the arm turning about z, the pendulum about
    the arm (entity ``world/arm/pendulum``, so Rerun composes the two rotations)."""

    arm_length: float
    pendulum_length: float
    arm_height: float = 0.16
    title = "Furuta pendulum"

    def document(self) -> dict[str, Any]:
        return {"arm_length": self.arm_length, "pendulum_length": self.pendulum_length}

    def log_static(self, rec: Any, world: str, shade: Callable[[tuple], tuple]) -> None:
        import rerun as rr

        rec.log(world, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.log(f"{world}/base", rr.Boxes3D(half_sizes=[[0.051, 0.051, 0.051]],
                                            centers=[[0.0, 0.0, 0.051]],
                                            colors=[shade((30, 30, 36))],
                                            fill_mode=rr.components.FillMode.Solid), static=True)
        # the riser up to the arm's hinge, the arm along its +x, the pendulum along its +z
        # (thicker than the rig's rods, so they read at the view's distance)
        rec.log(f"{world}/riser", rr.Capsules3D(
            lengths=[self.arm_height - 0.102], radii=[0.02], translations=[[0.0, 0.0, 0.102]],
            colors=[shade((30, 30, 36))]), static=True)
        rec.log(f"{world}/arm", rr.Capsules3D(
            lengths=[self.arm_length], radii=[0.006], colors=[shade((178, 184, 191))],
            rotation_axis_angles=[rr.RotationAxisAngle(axis=[0.0, 1.0, 0.0], degrees=90.0)]),
            static=True)
        rec.log(f"{world}/arm/pendulum", rr.Capsules3D(
            lengths=[self.pendulum_length], radii=[0.005], colors=[shade((245, 158, 46))]),
            static=True)

    def log_frames(self, rec: Any, world: str, times: Any, x: np.ndarray,
                   extras: dict[str, np.ndarray]) -> None:
        import rerun as rr

        pendulum = np.asarray(x[:, 0], dtype=np.float64)
        arm = np.asarray(extras.get("arm", np.zeros_like(pendulum)), dtype=np.float64)
        n = pendulum.size
        rec.send_columns(f"{world}/arm", indexes=[times], columns=rr.Transform3D.columns(
            translation=np.tile([0.0, 0.0, self.arm_height], (n, 1)), quaternion=_quat_z(arm)))
        rec.send_columns(f"{world}/arm/pendulum", indexes=[times], columns=rr.Transform3D.columns(
            translation=np.tile([self.arm_length, 0.0, 0.0], (n, 1)),
            quaternion=_quat_x(pendulum)))

    def log_bounds(self, rec: Any, world: str, bounds: Sequence["Bound"],
                   shade: Callable[[tuple], tuple]) -> None:
        """The pendulum's bound (the fall angle) as two red rays from its pivot, in the
        plane it swings in (they turn with the arm); a limited arm's range as two red rays
        from the base."""
        import rerun as rr

        red = shade(END_COLOR)
        for bound in bounds:
            ends = [v for v in (bound.lo, bound.hi) if math.isfinite(v)]
            if bound.index == 1 and ends:  # the pendulum about the arm's tip (+x of the arm)
                r = self.pendulum_length
                tips = [[0.0, -r * math.sin(a), r * math.cos(a)] for a in ends]
                rec.log(f"{world}/arm/bounds", rr.Transform3D(translation=[self.arm_length, 0.0, 0.0]),
                        static=True)
                rec.log(f"{world}/arm/bounds", rr.LineStrips3D(
                    [[[0.0, 0.0, 0.0], tip] for tip in tips], colors=[red], radii=[0.0015]), static=True)
                high = max(tips, key=lambda tip: tip[2])
                rec.log(f"{world}/arm/bounds/label", rr.Points3D(
                    [[high[0], high[1], high[2] + 0.02]], colors=[red], radii=[0.002],
                    labels=[bound_text(bound)], show_labels=True), static=True)
            elif bound.index == 0 and ends:  # the arm about z
                r = 1.2 * self.arm_length
                tips = [[r * math.cos(a), r * math.sin(a), self.arm_height] for a in ends]
                rec.log(f"{world}/arm_bounds", rr.LineStrips3D(
                    [[[0.0, 0.0, self.arm_height], tip] for tip in tips], colors=[red], radii=[0.0015]),
                    static=True)
                rec.log(f"{world}/arm_bounds/label", rr.Points3D(
                    tips[-1:], colors=[red], radii=[0.002], labels=[bound_text(bound)],
                    show_labels=True), static=True)

    end_position = (0.0, 0.0, 0.32)

    def view(self, origin: str, suffix: str = "") -> Any:
        import rerun.blueprint as rrb

        return rrb.Spatial3DView(
            origin=origin, name=f"Furuta pendulum{suffix}",
            # close enough that the 8.5 cm arm and the 13 cm pendulum fill the view
            eye_controls=rrb.EyeControls3D(position=[0.24, -0.30, 0.27],
                                           look_target=[0.03, 0.0, 0.17], eye_up=[0.0, 0.0, 1.0]))
