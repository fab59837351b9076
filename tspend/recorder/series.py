"""Which per-step series go to which entity: :class:`SeriesSpec`, :func:`series_specs`,
:func:`series_location`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from ..controllers.base import Diagnostic
from .common import PALETTE, Color, join_path


@dataclass(frozen=True)
class SeriesSpec:
    """One plotted entity: several series packed as instances of one ``Scalars``."""

    entity: str                         # relative to the sink prefix
    title: str                          # the name of its view in the blueprint
    names: tuple[str, ...]
    colors: tuple[Color, ...]
    extract: Callable[[dict[str, np.ndarray]], np.ndarray] = field(compare=False)


def _col(key: str, j: int | None = None) -> Callable[[dict[str, np.ndarray]], np.ndarray]:
    """Extractor of column ``j`` of block array ``key`` (the whole array if ``j`` is None)."""
    if j is None:
        return lambda d: d[key]
    return lambda d: d[key][:, j]


def _stack(*getters: Callable[[dict[str, np.ndarray]], np.ndarray]) -> Callable[[dict[str, np.ndarray]], np.ndarray]:
    """Extractor stacking 1-D or 2-D pieces column-wise into a (k, m) array."""

    def extract(d: dict[str, np.ndarray]) -> np.ndarray:
        parts = [np.asarray(g(d), dtype=np.float64) for g in getters]
        return np.column_stack([p if p.ndim == 2 else p[:, None] for p in parts])

    return extract


#: the runner's own panels: entity, title, and the panel name diagnostics join them by
STANDARD_PANELS = (("tracking", "reference and output"), ("error", "tracking error"),
                   ("control", "control u"), ("disturbance", "disturbance"))
PANEL_TITLES = {"compensator": "compensator part u_s", "lyapunov": "Lyapunov function",
                "norms": "parameter norms", "params": "model output p"}


def series_specs(order: int, extras: Sequence[str] = (),
                 diagnostics: Sequence[Diagnostic] = ()) -> list[SeriesSpec]:
    """The time-series layout for a plant of order ``order`` with ``extras`` under a
    controller that declares ``diagnostics``.

    The single source of truth for where each per-step quantity is logged: the sink
    uses it to send, the blueprint to lay out its views, :func:`series_location` to
    find a series again.  The runner's own series come first; each diagnostic joins
    the view of its ``panel`` (a standard one, or one of its own).
    """
    n = order
    e_names = tuple(f"e_{i + 1}" for i in range(n))
    names: dict[str, list[str]] = {
        "tracking": ["r", "x1"], "error": list(e_names), "control": ["u"], "disturbance": ["d"]}
    colors: dict[str, list[Color]] = {
        "tracking": [(150, 150, 150), (31, 119, 180)], "error": list(PALETTE[:n]),
        "control": [(214, 39, 40)], "disturbance": [(127, 127, 127)]}
    getters: dict[str, list] = {
        "tracking": [_col("ref", 0), _col("x", 0)], "error": [_col("e")], "control": [_col("u")],
        "disturbance": [_col("d")]}
    titles = dict(STANDARD_PANELS)
    for diag in diagnostics:
        panel = diag.panel or diag.name
        if panel not in names:
            names[panel], colors[panel], getters[panel] = [], [], []
            titles[panel] = PANEL_TITLES.get(panel, panel)
        for label in diag.column_labels:
            names[panel].append(label)
            colors[panel].append(PALETTE[(len(colors[panel]) + 3) % len(PALETTE)]
                                 if panel in dict(STANDARD_PANELS) else PALETTE[len(colors[panel]) % len(PALETTE)])
        getters[panel].append(_col(diag.name))
    specs = [SeriesSpec(f"series/{panel}", titles[panel], tuple(names[panel]), tuple(colors[panel]),
                        _stack(*getters[panel])) for panel in names]
    if extras:
        specs.append(SeriesSpec(
            "series/plant", "plant extras", tuple(extras),
            tuple(PALETTE[(9 + i) % len(PALETTE)] for i in range(len(extras))),
            _stack(*[_col(f"extra/{name}") for name in extras])))
    return specs


def series_location(name: str, order: int, extras: Sequence[str] = (),
                    prefix: str = "", diagnostics: Sequence[Diagnostic] = ()) -> tuple[str, int]:
    """``(entity, instance)`` where series ``name`` (``"x1"``, ``"u"``, ``"b_hat"``) is logged."""
    for spec in series_specs(order, extras, diagnostics):
        if name in spec.names:
            return join_path(prefix, spec.entity), spec.names.index(name)
    raise KeyError(f"no logged series named {name!r}")
