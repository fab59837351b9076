"""What makes a membership-function plot readable: an axis over the input's real interval
and each term's name at its curve's peak.

The curves are drawn on ``[0, width]`` whatever the interval (a 2D view keeps a 1:1
aspect), with ``y = -mu`` (Rerun's 2D views draw y downwards), so the axis labels carry
the real values.
"""

from __future__ import annotations

import numpy as np
import rerun as rr

AXIS_COLOR = (110, 110, 110)
#: ticks along the input axis
TICKS = 3
#: gap between a peak and its term label (membership units)
LABEL_GAP = 0.12


def _tick_text(value: float, span: float) -> str:
    if abs(value) < 1e-9 * max(span, 1e-300):
        return "0"
    return f"{value:.3g}"


def axis_parts(lo: float, hi: float, width: float) -> dict[str, object]:
    """Static archetypes of the axes: the input axis under the curves with ``TICKS``
    labelled ticks (the real values from ``lo`` to ``hi``), and the membership axis
    (0, 0.5, 1) on the left."""
    xs = np.linspace(0.0, width, TICKS)
    values = np.linspace(lo, hi, TICKS)
    tick = 0.04
    strips = [[[0.0, 0.0], [width, 0.0]], [[0.0, 0.0], [0.0, -1.0]]]
    strips += [[[x, 0.0], [x, tick]] for x in xs]
    strips += [[[0.0, -m], [-tick, -m]] for m in (0.5, 1.0)]
    return {
        "lines": rr.LineStrips2D(strips, colors=[AXIS_COLOR], radii=[-0.75]),
        "ticks": rr.Points2D(np.column_stack([xs, np.full(TICKS, 0.14)]), radii=[-0.1], colors=[AXIS_COLOR],
                             labels=[_tick_text(v, hi - lo) for v in values], show_labels=True),
        "mu": rr.Points2D([[-0.14, -1.0], [-0.14, -0.5]], radii=[-0.1], colors=[AXIS_COLOR],
                          labels=["1", "0.5"], show_labels=True),
    }


def term_label_positions(strips: np.ndarray) -> np.ndarray:
    """Where each term's name goes: just above its curve's peak.

    ``strips`` (R, T, G, 2) are the drawn curves (x, -mu); returns (R * T, 2).
    """
    peak = np.argmin(strips[..., 1], axis=-1)                      # lowest y = highest mu
    top = np.take_along_axis(strips, peak[..., None, None], axis=-2)[..., 0, :]
    positions = top.copy()
    positions[..., 1] -= LABEL_GAP
    return positions.reshape(-1, 2)
