"""Which per-step series go to which entity: :class:`SeriesSpec`, :func:`series_specs`,
:func:`series_location`.

Every series has a stable *key* (``r``, ``x1``, ``e_1``, ``u``, a diagnostic's column
label, an extra's name) by which code finds it again, and a display *name* with the
plant's physical symbol and unit (``theta (rad)``, ``e_theta (rad)``) shown in legends.
A view's title carries the unit too.  Diagnostics declared ``log`` are recorded as
``log10`` of their value (Rerun's plots have no logarithmic axis); the key stays the
diagnostic's label.

``series/control`` is the input the plant applied: the controller's command clipped to the
actuator's range (``RunInfo.u_lo``, ``u_hi``), what moved the machine.  When that range is
finite the command itself, before the clip, has its own view, ``series/control_command``
(key ``u_command``), in the controller's tab: a command chattering far beyond the
actuator's range no longer passes for the effort applied.

Two series are derived for the reader: ``series/error_steady``, the tracked output's
error over the steady-state window only (so its own scale, not the transient's, sets
the axis), and ``series/compensator_share``, the compensator's share ``-u_s / b_hat`` of
``u`` in ``u``'s unit (``u_s`` itself is in the unit of ``x^(n)``, not a force).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Callable, Sequence

import math

import numpy as np

from tspend.controllers.base import Diagnostic
from tspend.recorder.common import PALETTE, Color, join_path
from tspend.plants.domain import PlantLabels, name_slug
from tspend.recorder.labels import Quantity, extra_quantity, plant_labels

if TYPE_CHECKING:
    from tspend.loop.sinks import RunInfo

#: the cross on the tracking view where a run that did not complete ended
END_ENTITY = "series/end"
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
    #: the tab of the layout it goes to: "tracking", "internals" (the controller's own
    #: quantities) or "plant" (the plant's extras)
    group: str = "tracking"
    #: only the steady-state window (t >= duration / 2, the window of rmse_ss) is sent
    steady: bool = False
    #: each series' column in an exported table, unit at the end (``theta_rad``);
    #: "" leaves it out (a copy of a series exported from another entity)
    columns: tuple[str, ...] = ()
    #: recorded at every recorded sample: the state, the reference, the applied input and
    #: the disturbance (what a run is); every other series is a diagnostic (thinned by a
    #: compact recording)
    every_sample: bool = False
    #: the entity each exported column belongs with in the table's order (the samples
    #: entity of a compact recording holds columns of several); empty: this one
    origins: tuple[str, ...] = ()

    @property
    def legend(self) -> bool:
        """A legend only where several series share the view (a single one is named by the title)."""
        return len(self.names) > 1

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
PANEL_TITLES = {"compensator": "compensator output u_s", "lyapunov": "Lyapunov function V",
                "norms": "parameter norms",
                "params": "model output p and gain estimate b_hat"}
#: titles of one part of a panel (its linear or its log10 part)
KEY_TITLES = {"norms": "smallest gain consequent min_i p_(n+1)^i (projection keeps it >= b_min)",
              "norms/log10": "parameter norms ||P||, ||q||"}
#: panels whose diagnostics are parts of u, hence in u's unit unless they declare one
CONTROL_PANELS = ("control",)
#: the compensator's output u_s is in the unit of x^(n); its share of u (19) is drawn
#: from it and the model's gain estimate (the diagnostic columns of these names)
COMPENSATOR_OUTPUT, GAIN_ESTIMATE = "u_s", "b_hat"
#: key of the compensator's share of u, -u_s / b_hat
COMPENSATOR_SHARE = "u_s_share"
#: key (and exported column's label) of the controller's command before the actuator's clip
U_COMMAND = "u_command"
#: the steady-state window starts at this fraction of the run (as rmse_ss's, loop.metrics)
STEADY_FROM = 0.5


def _unit_suffix(units: Sequence[str]) -> str:
    distinct = sorted({u for u in units if u})
    return f" ({', '.join(distinct)})" if distinct else ""


def _error_name(state: Quantity, i: int) -> str:
    return f"e_{i + 1}" if state.symbol == f"x{i + 1}" else f"e_{state.symbol}"


def _named(symbol: str, unit: str) -> str:
    """A legend entry: ``"theta (rad)"``; the bare symbol for a dimensionless quantity."""
    return f"{symbol} ({unit})" if unit else symbol


def derivative_unit(unit: str) -> str:
    """The unit of a quantity's time derivative: ``rad/s`` -> ``rad/s²``, ``m`` -> ``m/s``."""
    if not unit:
        return ""
    if unit.endswith("/s"):
        return unit + "²"
    if unit.endswith("/s²"):
        return unit[:-1] + "³"
    return unit + "/s"


def _share_of_u(u_s: Extractor, b_hat: Extractor) -> Extractor:
    from tspend.controllers.paper.control_law import compensator_share

    return lambda d: compensator_share(u_s(d), b_hat(d))


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


def _ref_symbol(k: int) -> str:
    return "r" + "'" * k if k <= 3 else f"r^({k})"


def _ref_column(k: int) -> str:
    return ("ref", "ref_dot", "ref_ddot", "ref_dddot")[k] if k <= 3 else f"ref_d{k}"


def _derivative(unit: str, k: int) -> str:
    for _ in range(k):
        unit = derivative_unit(unit)
    return unit


def _column(label: str, unit: str) -> str:
    return Quantity(label, unit).column_name()


def _applied(lo: float, hi: float) -> Extractor:
    """Extractor of the input applied: the command ``u`` clipped to ``[lo, hi]``."""
    return lambda d: np.clip(d["u"], lo, hi)


def series_specs(order: int, extras: Sequence[str] = (), diagnostics: Sequence[Diagnostic] = (),
                 plant_kind: str = "", *, state_names: Sequence[str] = (),
                 state_units: Sequence[str] = (), view: Sequence[str] = (),
                 input_unit: str = "",
                 u_range: tuple[float, float] = (-math.inf, math.inf)) -> list[SeriesSpec]:
    """The time-series layout for a plant of ``plant_kind`` and order ``order`` with
    ``extras`` under a controller that declares ``diagnostics``.

    The single source of truth for where each per-step quantity is logged: the sink
    uses it to send, the blueprint to lay out its views, :func:`series_location` to
    find a series again.  The runner's own series come first; each diagnostic joins
    the view of its ``panel`` (a standard one, or one of its own); ``log`` and linear
    diagnostics of one panel get separate views; each extra gets its own view.

    With the plant's full state (``state_names``, ``state_units`` and the task's ``view``)
    every entry is a series of its own, ``series/state/<name>``, named by the domain
    (:meth:`~tspend.plants.domain.PlantLabels.of_state`), in the *plant* tab in place of
    the extras it repeats; ``series/reference`` holds ``r, r', .., r^(n)`` (no view: the
    tracking view shows r).  Every series carries its exported column (:attr:`SeriesSpec.columns`).

    ``u_range``: the actuator's range; ``series/control`` is the command clipped to it
    (what the plant applied) and, when it is finite, ``series/control_command`` the command.
    """
    labels = plant_labels(plant_kind, order, input_unit)
    s0 = labels.states[0]
    control = labels.control
    u_lo, u_hi = (float(v) for v in u_range)
    limited = math.isfinite(u_lo) or math.isfinite(u_hi)
    e_names = [_named(_error_name(s, i), s.unit) for i, s in enumerate(labels.states)]
    panels: dict[str, _Panel] = {
        "tracking": _Panel(f"{s0.meaning or 'output'} {s0.symbol} and reference r{_unit_suffix([s0.unit])}",
                           [_named("r", s0.unit), _named(s0.symbol, s0.unit)], ["r", "x1"],
                           [(150, 150, 150), (31, 119, 180)], [_col("ref", 0), _col("x", 0)]),
        "error": _Panel("tracking error e = x - r", e_names, [f"e_{i + 1}" for i in range(order)],
                        list(PALETTE[:order]), [_col("e")], unit_in_title=False),
        "control": _Panel(f"control {control.symbol}{_unit_suffix([control.unit])}"
                          + (f", {control.meaning}" if control.meaning else "")
                          + (f", applied (the command clipped to [{u_lo:g}, {u_hi:g}])"
                             if limited else ""),
                          [_named("u", control.unit)], ["u"], [(214, 39, 40)],
                          [_applied(u_lo, u_hi) if limited else _col("u")], minmax=True),
        "disturbance": _Panel("disturbance d and its estimates", [_named("d", labels.disturbance.unit)], ["d"],
                              [(127, 127, 127)], [_col("d")]),
    }
    x_n_unit = derivative_unit(labels.states[-1].unit) if labels.states else ""
    share: dict[str, Extractor] = {}
    for diag in diagnostics:
        panel = diag.panel or diag.name
        key = panel if not diag.log or panel in STANDARD_PANELS else f"{panel}/log10"
        if key not in panels:
            log = key.endswith("/log10")
            title = KEY_TITLES.get(key) or PANEL_TITLES.get(panel, panel.replace("_", " "))
            panels[key] = _Panel(title + (", log10 scale" if log else ""), log10=log)
        target = panels[key]
        unit = ((diag.unit or control.unit) if panel in CONTROL_PANELS
                else x_n_unit if diag.name == COMPENSATOR_OUTPUT else diag.unit)
        target.units.append(unit)
        target.minmax |= diag.chattering
        for j, label in enumerate(diag.column_labels):
            target.names.append(f"log10 {label}" if target.log10 else _named(label, unit))
            target.keys.append(label)
            offset = 3 if panel in STANDARD_PANELS else 0
            target.colors.append(PALETTE[(len(target.colors) + offset) % len(PALETTE)])
            if label in (COMPENSATOR_OUTPUT, GAIN_ESTIMATE):
                share[label] = _col(diag.name, None if diag.width == 1 else j)
        getter = _col(diag.name)
        target.getters.append(_log10(getter) if target.log10 else getter)
    if len(share) == 2:
        # what the compensator does to the plant: its share of u, in u's unit, beside u
        panels["compensator_share"] = _Panel(
            f"compensator share of u: -u_s / b_hat{_unit_suffix([control.unit])}",
            [_named("-u_s/b_hat", control.unit)], [COMPENSATOR_SHARE], [(44, 160, 44)],
            [_share_of_u(share[COMPENSATOR_OUTPUT], share[GAIN_ESTIMATE])], minmax=True, unit_in_title=False)
    specs = []
    for key, p in panels.items():
        title = p.title + (_unit_suffix(p.units) if p.unit_in_title and key not in ("tracking", "control") else "")
        group = "tracking" if key in STANDARD_PANELS or key == "compensator_share" else "internals"
        specs.append(SeriesSpec(f"series/{_entity_name(key, panels)}", title, tuple(p.names), tuple(p.colors),
                                _stack(*p.getters), keys=tuple(p.keys), minmax=p.minmax, log10=p.log10,
                                group=group))
        if key == "error" and labels.states:
            # the number the paper is about: the error once the transient is over, on its own scale
            specs.append(SeriesSpec(
                "series/error_steady", f"steady-state error {_error_name(s0, 0)}{_unit_suffix([s0.unit])}, "
                f"t >= {STEADY_FROM:g} T", (e_names[0],), (PALETTE[0],),
                _stack(_col("e", 0)), keys=("e_1_steady",), steady=True))
    if limited:
        # what the controller asked, beside nothing it could be mistaken for: its own view
        specs.append(SeriesSpec(
            "series/control_command", f"control {control.symbol} commanded, before the "
            f"actuator's clip to [{u_lo:g}, {u_hi:g}]{_unit_suffix([control.unit])}",
            (_named(U_COMMAND, control.unit),), ((148, 103, 189),), _stack(_col("u")),
            keys=(U_COMMAND,), minmax=True, group="internals",
            columns=(_column(U_COMMAND, control.unit),)))
    # the compensator's share of u right after u
    shares = [i for i, spec in enumerate(specs) if spec.entity == "series/compensator_share"]
    if shares:
        after = next(i for i, spec in enumerate(specs) if spec.entity == "series/control")
        specs.insert(after + 1, specs.pop(shares[0]))
    full = labels.of_state(tuple(state_names), tuple(state_units), tuple(view)) if state_names else ()
    symbols = {q.symbol for q in full}
    for i, name in enumerate(extras):
        q = extra_quantity(labels, name)
        repeated = q.symbol in symbols  # the cart's position is the slide joint's
        specs.append(SeriesSpec(
            f"series/plant/{name}", (q.meaning or "plant extra") + f" {q.with_unit()}",
            (_named(q.symbol, q.unit),), (PALETTE[(9 + i) % len(PALETTE)],), _stack(_col(f"extra/{name}")),
            keys=(name,), group="" if repeated else "plant",
            columns=("" if repeated else q.column_name(name_slug(name)),)))
    for j, (name, q) in enumerate(zip(state_names, full)):
        specs.append(SeriesSpec(
            f"series/state/{name}", f"{q.meaning or name} {q.with_unit()}", (_named(q.symbol, q.unit),),
            (PALETTE[(6 + j) % len(PALETTE)],), _stack(_col("state", j)), keys=(name,), group="plant",
            columns=(q.column_name(name_slug(name)),)))  # the model's name: hinge_rad
    unit0 = s0.unit if labels.states else ""
    specs.append(SeriesSpec(
        "series/reference", f"reference r and its derivatives{_unit_suffix([unit0])}",
        tuple(_named(_ref_symbol(k), _derivative(unit0, k)) for k in range(order + 1)),
        tuple(PALETTE[k % len(PALETTE)] for k in range(order + 1)), _stack(_col("ref")),
        keys=("r",) + tuple(f"r_d{k}" for k in range(1, order + 1)), group="",
        columns=tuple(_column(_ref_column(k), _derivative(unit0, k)) for k in range(order + 1))))
    # the view's quantities under the full state's column names (e_pendulum_rad)
    # (one name per quantity: the model's, hinge_rad, e_hinge_rad; the domain's symbol, theta,
    # only labels the views)
    viewed = (tuple(full[list(state_names).index(v)]._replace(column=name_slug(v)) for v in view)
              if full and all(v in state_names for v in view) else labels.states)
    # what drives and what is the machine: the input applied and the disturbance acting
    # (an identification fits both), the reference, the state
    exact = ("series/reference", "series/control", "series/disturbance") + (
        () if full else ("series/tracking",))
    return [_with_columns(replace(spec, every_sample=spec.entity in exact
                                  or spec.entity.startswith("series/state/")),
                          labels, viewed, bool(full), diagnostics) for spec in specs]


def _with_columns(spec: SeriesSpec, labels: PlantLabels, viewed: Sequence[Quantity], full: bool,
                  diagnostics: Sequence[Diagnostic]) -> SeriesSpec:
    """``spec`` with its exported columns: the runner's series by the domain's names, a
    diagnostic by its label and unit; a copy of another entity's series left out."""
    if spec.columns:
        return spec
    units = {label: diag.unit for diag in diagnostics for label in diag.column_labels}
    x_n_unit = derivative_unit(labels.states[-1].unit) if labels.states else ""
    views = {f"x{i + 1}": q for i, q in enumerate(viewed)}
    columns = []
    for key, name in zip(spec.lookup, spec.names):
        if key == "r" or key.endswith("_steady"):
            columns.append("")          # series/reference and series/error hold them
        elif key in views:
            # the state's own entity holds it when the full state is recorded
            columns.append("" if full else views[key].column_name())
        elif key.startswith("e_") and key[2:].isdigit() and int(key[2:]) <= len(viewed):
            q = viewed[int(key[2:]) - 1]
            columns.append(q.column_name("e_" + (q.column or name_slug(q.symbol))))
        elif key == "u":
            columns.append(labels.control.column_name())
        elif key == "d":
            columns.append(labels.disturbance.column_name())
        elif key == COMPENSATOR_SHARE:
            columns.append(_column("u_s_share", labels.control.unit))
        elif spec.log10:
            columns.append(name_slug(f"log10 {key}"))
        else:
            unit = x_n_unit if key == COMPENSATOR_OUTPUT else units.get(key, "")
            unit = (units.get(key) or labels.control.unit) if spec.entity == "series/control" else unit
            columns.append(_column(key, unit))
    return replace(spec, columns=tuple(columns))


def specs_of(info: "RunInfo") -> list[SeriesSpec]:
    """:func:`series_specs` of a run (its plant, full state, view and diagnostics)."""
    return series_specs(info.order, info.extras, info.diagnostics, info.plant_kind,
                        state_names=info.state_names, state_units=info.state_units, view=info.view,
                        input_unit=info.input_unit, u_range=(info.u_lo, info.u_hi))


def export_columns(specs: Sequence[SeriesSpec], view: Sequence[str] = ()) -> list[tuple[str, str, int]]:
    """``(column, entity, instance)`` of every exported series, in the table's order: the
    view's states, the reference and its derivatives, u, d, the rest of the full state,
    then the errors, the controller's series and the extras."""
    first = [f"series/state/{name}" for name in view] + ["series/reference", "series/control",
                                                           "series/disturbance"]
    rank = {entity: i for i, entity in enumerate(first)}
    order = {spec.entity: i for i, spec in enumerate(specs)}

    def place(origin: str, index: int) -> tuple[int, int, int]:
        return (rank.get(origin, len(first) + (0 if origin.startswith("series/state/") else 1)),
                order.get(origin, len(specs)), index)

    found = []
    for spec in specs:
        taken: dict[str, int] = {}  # the samples' columns: their place in their origin
        for j, column in enumerate(spec.columns):
            origin = spec.origins[j] if spec.origins else spec.entity
            index = taken.get(origin, 0) if spec.origins else j
            taken[origin] = index + 1
            if column:
                found.append((place(origin, index), column, spec.entity, j))
    found.sort(key=lambda item: item[0])
    return [(column, entity, j) for _, column, entity, j in found]


#: a compact recording's entity of every sample of the state, the reference r, the applied
#: input and the disturbance, the columns an export takes them from (no view draws it)
SAMPLES_ENTITY = "series/samples"


def compact_specs(specs: Sequence[SeriesSpec]) -> list[SeriesSpec]:
    """The specs of a compact recording (docs/recordings.md): the state, r, the applied
    input and the disturbance go at every sample into one entity, :data:`SAMPLES_ENTITY` (a row of Rerun costs
    ~28 bytes besides its values, so one row for all of them instead of one per series
    cuts a default run's recording by two thirds); every view, theirs too, becomes a
    diagnostic the sink thins, and exports its columns only where the samples do not hold
    them (r's derivatives)."""
    getters: list[Extractor] = []
    names: list[str] = []
    keys: list[str] = []
    colors: list[Color] = []
    columns: list[str] = []
    origins: list[str] = []
    out: list[SeriesSpec] = []
    for spec in specs:
        if not spec.every_sample:
            if spec.group or any(spec.columns):
                out.append(spec)  # a view, or exported: kept (thinned)
            continue  # in no view and exported from elsewhere (the cart's position again)
        # r's derivatives and the controller's estimates of d (its panel's other series)
        # stay diagnostics: r itself is what was tracked, d what acted
        take = 1 if spec.entity in ("series/reference", "series/disturbance") else len(spec.lookup)
        getters.append(lambda d, f=spec.extract, k=take: f(d)[:, :k])
        names += spec.names[:take]
        keys += spec.lookup[:take]
        colors += spec.colors[:take]
        columns += spec.columns[:take] if spec.columns else [""] * take
        origins += [spec.entity] * take
        kept = ("",) * take + tuple(spec.columns[take:]) if spec.columns else ()
        out.append(replace(spec, every_sample=False, columns=kept))
    if not getters:
        return list(specs)
    out.append(SeriesSpec(SAMPLES_ENTITY, "every sample of the state, r, the applied input and d",
                          tuple(names), tuple(colors), _stack(*getters), keys=tuple(keys),
                          group="", every_sample=True, columns=tuple(columns),
                          origins=tuple(origins)))
    return out


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
