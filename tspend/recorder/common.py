"""What the recorder's modules share: the timeline, entity paths and colours."""

from __future__ import annotations

TIMELINE = "sim_time"

Color = tuple[int, int, int]

PALETTE: tuple[Color, ...] = (
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
    (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207),
)


def join_path(prefix: str, path: str) -> str:
    """Entity path ``prefix/path`` with exactly one separator, no leading slash."""
    prefix = prefix.strip("/")
    return f"{prefix}/{path}" if prefix else path


def prefix_label(prefix: str) -> str:
    """Human label of a prefix: ``"mujoco/"`` -> ``"mujoco"``."""
    return prefix.strip("/")

#: width on screen of every membership-function plot (height 1): see RerunSink._display_x
BMF_WIDTH = 2.0
