"""What the recorder draws of a machine in 3D, and the colour that marks a run's end.

A domain says how its machine is drawn (:meth:`tspend.plants.domain.Domain.drawing`); the
drawing itself is neither physics nor task, so it lives here: :class:`Drawing`, the
protocol the recorder (:mod:`tspend.recorder.sink`) and :mod:`tspend.loop.sinks` call,
:class:`~tspend.plants.drawing.model.ModelDrawing`, any MJCF drawn from its own geoms (with a
cart's rail), and :class:`~tspend.plants.drawing.furuta.FurutaDrawing`, the QUBE rig.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

if TYPE_CHECKING:
    from tspend.task import Bound

__all__ = ["Drawing", "END_COLOR", "bound_text"]

#: the colour of what marks the end of a run and the bounds that end one
END_COLOR = (214, 39, 40)


def bound_text(bound: "Bound") -> str:
    """What crossing ``bound`` means, short enough for a label in a 3D view:
    ``"fell if |hinge| > 1.57 rad"`` for a symmetric bound, else both ends (a condition,
    drawn on every run: a completed run's view must not read as if it ended there)."""
    unit = f" {bound.unit}" if bound.unit else ""
    if math.isfinite(bound.hi) and bound.lo == -bound.hi:
        return f"{bound.status} if |{bound.name}| > {bound.hi:.3g}{unit}"
    return f"{bound.status} if {bound.name} is outside [{bound.lo:.3g}, {bound.hi:.3g}]{unit}"


class Drawing(ABC):
    """What a recorder draws of a plant in 3D: a static scene, then poses per frame.

    The recorder (:mod:`tspend.recorder.sink`) calls :meth:`log_static` once and
    :meth:`log_frames` with batches of frames; it knows nothing of the machine.
    """

    #: the 3D view's title
    title: str = "plant"

    @abstractmethod
    def log_static(self, rec: Any, world: str, shade: Callable[[tuple], tuple]) -> None:
        """Log the scene under entity ``world``; ``shade`` maps colours (overlaid runs)."""

    @abstractmethod
    def log_frames(self, rec: Any, world: str, times: Any, x: np.ndarray,
                   extras: dict[str, np.ndarray]) -> None:
        """Log the poses for the samples ``times`` (a Rerun time column) given the view
        ``x`` (N, n) and the plant's extras (N,) by name."""

    @abstractmethod
    def view(self, origin: str, suffix: str = "") -> Any:
        """The Rerun 3D view of ``origin``."""

    #: where :meth:`log_end` writes the reason a run ended (relative to ``world``; a child
    #: of a moving body follows it) and at which point of that entity's frame
    end_entity: str = "end"
    end_position: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def log_bounds(self, rec: Any, world: str, bounds: Sequence["Bound"],
                   shade: Callable[[tuple], tuple]) -> None:
        """Draw the task's bounds on the full state (rail ends, joint limits, the fall
        angle: :meth:`tspend.task.Task.bounds`) under ``world``; default: nothing."""

    def log_end(self, rec: Any, world: str, times: Any, text: str) -> None:
        """Write ``text`` (why the run ended) in the scene from ``times`` (one time) on."""
        import rerun as rr

        path = f"{world}/{self.end_entity}"
        rec.log(path, rr.Points3D.from_fields(colors=[END_COLOR], radii=[-4.0], show_labels=True),
                static=True)
        rec.send_columns(path, indexes=[times], columns=rr.Points3D.columns(
            positions=[list(self.end_position)], labels=[text]))

    def document(self) -> dict[str, Any]:
        """Facts shown in the run's info document."""
        return {}
