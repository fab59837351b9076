"""Which per-step series go to which entity: :class:`SeriesSpec`, :func:`series_specs`,
:func:`series_location`.

Every series has a stable *key* (``r``, ``x1``, ``e_1``, ``u``, a diagnostic's column
label, an extra's name) by which code finds it again, and a display *name* with the
plant's physical symbol (``theta``, ``e_theta``) shown in legends.  A view's title
carries the unit.  Diagnostics declared ``log`` are recorded as ``log10`` of their
value (Rerun's plots have no logarithmic axis); the key stays the diagnostic's label.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from tspend.controllers.base import Diagnostic
from tspend.recorder.common import PALETTE, Color, join_path
from tspend.recorder.labels import Quantity, extra_quantity, plant_labels

#: floor of a ``log`` diagnostic before its log10 is taken (a norm may start at 0)
LOG_FLOOR = 1e-12

Extractor = Callable[[dict[str, np.ndarray]], np.ndarray]


@dataclass(frozen=True)
class SeriesSpec:
    """One plotted entity: several series packed as instances of one ``Scalars``."""

    entity: str                         # relative to the sink prefix
    title: str                          # the name of its view in the blueprint, unit included
    names: tuple[str, ...]              # legend entries (physical names)
    colors: tuple[Color, ...]
    extract: Extractor = field(compare=False)
    keys: tuple[str, ...] = ()          # stable names for series_location; default: names
    #: min/max aggregation when the viewer thins the series (u and chattering signals)
    minmax: bool = False
    log10: bool = False

    @property
    def lookup(self) -> tuple[str, ...]:
        return self.keys or self.names


def _col(key: str, j: int | None = None) -> Extractor:
    """Extractor of column ``j`` of block array ``key`` (the whole array if ``j`` is None)."""
    if j is None:
        return lambda d: d[key]
    return lambda d: d[key][:, j]


def _stack(*getters: Extractor) -> Extractor:
    """Extractor stacking 1-D or 2-D pieces column-wise into a (k, m) array."""

    def extract(d: dict[str, np.ndarray]) -> np.ndarray:
        parts = [np.asarray(g(d), dtype=np.float64) for g in getters]
        return np.column_stack([p if p.ndim == 2 else p[:, None] for p in parts])

    return extract


def _log10(getter: Extractor) -> Extractor:
    return lambda d: np.log10(np.maximum(np.asarray(getter(d), dtype=np.float64), LOG_FLOOR))


#: the runner's own panels (entity name, and the panel name diagnostics join them by)
STANDARD_PANELS = ("tracking", "error", "control", "disturbance")
#: titles of panels the paper controller declares; any other panel is titled by its name
PANEL_TITLES = {"compensator": "compensator part u_s of u", "lyapunov": "Lyapunov function V",
                "norms": "parameter norms", "params": "model output p and gain estimate b_hat"}
#: panels whose diagnostics are parts of u, hence in u's unit whatever they declare
CONTROL_PANELS = ("control", "compensator")


def _unit_suffix(units: Sequence[str]) -> str:
    distinct = sorted({u for u in units if u})
    return f" ({', '.join(distinct)})" if distinct else ""


def _error_name(state: Quantity, i: int) -> str:
    return f"e_{i + 1}" if state.symbol == f"x{i + 1}" else f"e_{state.symbol}"


@dataclass
class _Panel:
    title: str
    names: list[str] = field(default_factory=list)
    keys: list[str] = field(default_factory=list)
    colors: list[Color] = field(default_factory=list)
    getters: list[Extractor] = field(default_factory=list)
    units: list[str] = field(default_factory=list)
    minmax: bool = False
    log10: bool = False
    unit_in_title: bool = True


def series_specs(order: int, extras: Sequence[str] = (), diagnostics: Sequence[Diagnostic] = (),
                 plant_kind: str = "") -> list[SeriesSpec]:
    """The time-series layout for a plant of ``plant_kind`` and order ``order`` with
    ``extras`` under a controller that declares ``diagnostics``.

    The single source of truth for where each per-step quantity is logged: the sink
    uses it to send, the blueprint to lay out its views, :func:`series_location` to
    find a series again.  The runner's own series come first; each diagnostic joins
    the view of its ``panel`` (a standard one, or one of its own); ``log`` and linear
    diagnostics of one panel get separate views; each extra gets its own view.
    """
    labels = plant_labels(plant_kind, order)
    s0 = labels.states[0]
    control = labels.control
    panels: dict[str, _Panel] = {
        "tracking": _Panel(f"{s0.meaning or 'output'} {s0.symbol} and reference r{_unit_suffix([s0.unit])}",
                           ["r", s0.symbol], ["r", "x1"], [(150, 150, 150), (31, 119, 180)],
                           [_col("ref", 0), _col("x", 0)]),
        "error": _Panel("tracking error e = x - r",
                        [_error_name(s, i) + (f" ({s.unit})" if s.unit else "") for i, s in enumerate(labels.states)],
                        [f"e_{i + 1}" for i in range(order)], list(PALETTE[:order]), [_col("e")],
                        unit_in_title=False),
        "control": _Panel(f"control {control.symbol}{_unit_suffix([control.unit])}"
                          + (f", {control.meaning}" if control.meaning else ""),
                          ["u"], ["u"], [(214, 39, 40)], [_col("u")], minmax=True),
        "disturbance": _Panel("disturbance d and its estimates", ["d"], ["d"], [(127, 127, 127)], [_col("d")]),
    }
    for diag in diagnostics:
        panel = diag.panel or diag.name
        key = panel if not diag.log or panel in STANDARD_PANELS else f"{panel}/log10"
        if key not in panels:
            log = key.endswith("/log10")
            title = PANEL_TITLES.get(panel, panel.replace("_", " "))
            panels[key] = _Panel(title + (", log10 scale" if log else ""), log10=log)
        target = panels[key]
        unit = control.unit if panel in CONTROL_PANELS else diag.unit
        target.units.append(unit)
        target.minmax |= diag.chattering
        for label in diag.column_labels:
            target.names.append(f"log10 {label}" if target.log10 else label)
            target.keys.append(label)
            offset = 3 if panel in STANDARD_PANELS else 0
            target.colors.append(PALETTE[(len(target.colors) + offset) % len(PALETTE)])
        getter = _col(diag.name)
        target.getters.append(_log10(getter) if target.log10 else getter)
    specs = []
    for key, p in panels.items():
        title = p.title + (_unit_suffix(p.units) if p.unit_in_title and key not in ("tracking", "control") else "")
        specs.append(SeriesSpec(f"series/{_entity_name(key, panels)}", title, tuple(p.names), tuple(p.colors),
                                _stack(*p.getters), keys=tuple(p.keys), minmax=p.minmax, log10=p.log10))
    for i, name in enumerate(extras):
        q = extra_quantity(labels, name)
        specs.append(SeriesSpec(
            f"series/plant/{name}", (q.meaning or "plant extra") + f" {q.with_unit()}",
            (q.symbol,), (PALETTE[(9 + i) % len(PALETTE)],), _stack(_col(f"extra/{name}")), keys=(name,)))
    return specs


def _entity_name(key: str, panels: dict[str, _Panel]) -> str:
    """``norms/log10`` -> ``norms`` when the panel has no linear part, else ``norms_log10``."""
    if not key.endswith("/log10"):
        return key
    base = key[: -len("/log10")]
    return f"{base}_log10" if base in panels else base


def series_location(name: str, order: int, extras: Sequence[str] = (),
                    prefix: str = "", diagnostics: Sequence[Diagnostic] = ()) -> tuple[str, int]:
    """``(entity, instance)`` where series ``name`` (``"x1"``, ``"u"``, ``"b_hat"``) is logged.

    ``name`` is the series' key (plant-independent: ``x1``, ``e_1``, a diagnostic's label,
    an extra's name).
    """
    for spec in series_specs(order, extras, diagnostics):
        if name in spec.lookup:
            return join_path(prefix, spec.entity), spec.lookup.index(name)
    raise KeyError(f"no logged series named {name!r}")
