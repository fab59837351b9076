"""Which per-step series go to which entity: :class:`SeriesSpec`, :func:`series_specs`,
:func:`series_location`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

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


def series_specs(order: int, extras: Sequence[str] = ()) -> list[SeriesSpec]:
    """The time-series layout for a plant of order ``order`` with ``extras``.

    The single source of truth for where each per-step quantity is logged: the sink
    uses it to send, the blueprint to lay out its views, :func:`series_location` to
    find a series again.
    """
    n = order
    e_names = tuple(f"e_{i + 1}" for i in range(n))
    p_names = tuple(f"p_{i + 1}" for i in range(n)) + ("b_hat",)
    specs = [
        SeriesSpec("series/tracking", "reference and output", ("r", "x1"), ((150, 150, 150), (31, 119, 180)),
                   _stack(_col("ref", 0), _col("x", 0))),
        SeriesSpec("series/error", "error and e_delta", e_names + ("e_delta",),
                   PALETTE[:n] + ((0, 0, 0),), _stack(_col("e"), _col("e_delta"))),
        SeriesSpec("series/control", "control u and u_s", ("u", "u_s"), ((214, 39, 40), (255, 127, 14)),
                   _stack(_col("u"), _col("u_s"))),
        SeriesSpec("series/compensation", "d_hat and disturbance d", ("d_hat", "d"), ((44, 160, 44), (127, 127, 127)),
                   _stack(_col("d_hat"), _col("d"))),
        SeriesSpec("series/params", "estimated p_k and b_hat", p_names,
                   tuple(PALETTE[i % len(PALETTE)] for i in range(n)) + ((214, 39, 40),),
                   _stack(_col("p"))),
        SeriesSpec("series/lyapunov", "Lyapunov V", ("V",), ((148, 103, 189),), _stack(_col("V"))),
        SeriesSpec("series/norms", "parameter norms", ("norm_P", "norm_q", "min_b"),
                   ((140, 86, 75), (227, 119, 194), (188, 189, 34)),
                   _stack(_col("norm_P"), _col("norm_q"), _col("min_b"))),
    ]
    if extras:
        specs.append(SeriesSpec(
            "series/plant", "plant extras", tuple(extras),
            tuple(PALETTE[(9 + i) % len(PALETTE)] for i in range(len(extras))),
            _stack(*[_col(f"extra/{name}") for name in extras])))
    return specs


def series_location(name: str, order: int, extras: Sequence[str] = (),
                    prefix: str = "") -> tuple[str, int]:
    """``(entity, instance)`` where series ``name`` (``"x1"``, ``"u"``, ``"b_hat"``) is logged."""
    for spec in series_specs(order, extras):
        if name in spec.names:
            return join_path(prefix, spec.entity), spec.names.index(name)
    raise KeyError(f"no logged series named {name!r}")
