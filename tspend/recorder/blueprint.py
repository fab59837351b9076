"""The default viewer layout: :func:`build_blueprint` and the view helpers the cross-check
layout shares.

Read without clicking: every view is titled in full with its unit; legends sit at the
top right over a margin kept free after the end of the run (never over its start);
side panels are folded so the plots get the room; the fuzzy views appear only for a
controller with rule bases.
"""

from __future__ import annotations

from typing import Sequence

import rerun as rr
import rerun.blueprint as rrb

from tspend.loop.sinks import FuzzyInputInfo, RunInfo
from tspend.recorder.common import BMF_WIDTH, TIMELINE, join_path, prefix_label
from tspend.recorder.labels import plant_labels
from tspend.recorder.series import SeriesSpec, series_specs

#: the time axis runs this fraction past the end of the run: the legends sit there
LEGEND_MARGIN = 0.22


def _abs(prefix: str, path: str) -> str:
    return "/" + join_path(prefix, path)


def time_axis(duration: float) -> rrb.TimeAxis:
    """0 .. duration plus the legend's margin."""
    end = max(duration, 1e-3) * (1.0 + LEGEND_MARGIN)
    return rrb.TimeAxis(view_range=rr.TimeRange(start=rr.TimeRangeBoundary.absolute(seconds=0.0),
                                                end=rr.TimeRangeBoundary.absolute(seconds=end)))


def series_view(name: str, contents: Sequence[str], duration: float) -> rrb.TimeSeriesView:
    return rrb.TimeSeriesView(origin="/", contents=list(contents), name=name, axis_x=time_axis(duration),
                              plot_legend=rrb.PlotLegend(rrb.components.Corner2D.RightTop, visible=True))


def _input_title(info: RunInfo, group: str, inp: FuzzyInputInfo) -> str:
    """``"model: x_o1 = theta (rad)"``: short enough for a view a third of the screen wide
    (the axis under the curves gives the interval)."""
    labels = plant_labels(info.plant_kind, info.order)
    quantity = None
    if inp.name.startswith("x_o") and inp.name[3:].isdigit() and int(inp.name[3:]) <= len(labels.states):
        quantity = labels.states[int(inp.name[3:]) - 1]
    elif inp.name == "u_o":
        quantity = labels.control
    meaning = f" = {quantity.with_unit()}" if quantity is not None and quantity.symbol != inp.name else ""
    return f"{group}: {inp.name}{meaning}"


def fuzzy_views(info: RunInfo, prefix: str = "", suffix: str = "") -> tuple[list[rrb.View], list[rrb.View]]:
    """(membership-function views, firing and consequent views) of one run; none for a
    controller without rule bases."""
    if not (info.model_inputs or info.compensator_inputs):
        return [], []
    bmf: list[rrb.View] = []
    for group, inputs in (("model", info.model_inputs), ("compensator", info.compensator_inputs)):
        for j, inp in enumerate(inputs):
            # drawn on [0, BMF_WIDTH] with y = -mu (RerunSink._display_x); the axis labels carry the values
            bmf.append(rrb.Spatial2DView(
                origin=_abs(prefix, f"fuzzy/{group}/in{j}"), name=_input_title(info, group, inp) + suffix,
                visual_bounds=rrb.VisualBounds2D(x_range=[-0.3, BMF_WIDTH + 0.1], y_range=[-1.3, 0.45])))
    rules = 1
    for inp in info.model_inputs:
        rules *= max(1, len(inp.terms))
    no_legend = rrb.PlotLegend(visible=False)
    firing: list[rrb.View] = [
        rrb.BarChartView(origin=_abs(prefix, "fuzzy/firing"), plot_legend=no_legend,
                         name=f"model rule firing w^i, {rules} rules{suffix}"),
        rrb.BarChartView(origin=_abs(prefix, "fuzzy/compensator_firing"), plot_legend=no_legend,
                         name=f"compensator rule firing tau^i{suffix}"),
    ]
    # the consequents p_k^i, one bar chart per output k (own axis each), then q^i
    symbols = [f"p_{k + 1}" for k in range(info.order)] + ["b"]  # b = p_{n+1}
    firing += [rrb.BarChartView(origin=_abs(prefix, f"fuzzy/consequent_{k + 1}"), plot_legend=no_legend,
                                name=f"consequents {symbol}^i over the rules{suffix}")
               for k, symbol in enumerate(symbols)]
    firing.append(rrb.BarChartView(origin=_abs(prefix, "fuzzy/q"), plot_legend=no_legend,
                                   name=f"compensator consequents q^i{suffix}"))
    return bmf, firing


def plant_view(info: RunInfo, prefix: str = "", suffix: str = "") -> rrb.View:
    """The plant in 3D as its domain draws it (:meth:`tspend.plants.domain.Drawing.view`)."""
    assert info.drawing is not None
    return info.drawing.view(_abs(prefix, "world"), suffix)


def document_views(prefix: str = "", suffix: str = "") -> list[rrb.View]:
    return [rrb.TextDocumentView(origin=_abs(prefix, f"info/{doc}"), name=f"{title}{suffix}")
            for doc, title in (("status", "status"), ("metrics", "metrics"), ("run", "run"),
                               ("scenario", "scenario"))]


def panels() -> list[rrb.BlueprintPart]:
    """Side panels folded (the plots need the room); the time panel keeps its controls."""
    return [rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
            rrb.TimePanel(state="collapsed", timeline=TIMELINE)]


def build_blueprint(info: RunInfo, prefixes: Sequence[str] = ("",), *,
                    draw: bool | None = None) -> rrb.Blueprint:
    """The default layout: the plant in 3D and fuzzy internals beside the time series.

    With several ``prefixes`` (side-by-side runs in one recording) every time-series
    view overlays all runs; 3D and fuzzy views are per run.  ``draw`` defaults to whether
    the plant's domain draws it (``info.drawing``).
    """
    prefixes = list(prefixes) or [""]
    multi = len(prefixes) > 1
    suffixes = [f" [{prefix_label(p)}]" if multi else "" for p in prefixes]
    specs: list[SeriesSpec] = series_specs(info.order, info.extras, info.diagnostics, info.plant_kind)
    series_views: list[rrb.View] = [
        series_view(spec.title, [_abs(p, spec.entity) for p in prefixes], info.duration) for spec in specs]
    bmf_views: list[rrb.View] = []
    firing_views: list[rrb.View] = []
    doc_views: list[rrb.View] = []
    for p, sfx in zip(prefixes, suffixes):
        bmf, firing = fuzzy_views(info, p, sfx)
        bmf_views += bmf
        firing_views += firing
        doc_views += document_views(p, sfx)
    fuzzy_tabs = [rrb.Grid(*bmf_views, grid_columns=2, name="membership functions"),
                  rrb.Grid(*firing_views, grid_columns=2, name="firing and consequents")] if bmf_views else []
    tabs = rrb.Tabs(*fuzzy_tabs, rrb.Tabs(*doc_views, name="run info"))
    left: list[rrb.Container | rrb.View] = []
    if info.drawing is not None and (draw is None or draw):
        views3d = [plant_view(info, p, sfx) for p, sfx in zip(prefixes, suffixes)]
        left.append(rrb.Horizontal(*views3d) if multi else views3d[0])
    left.append(tabs)
    root = rrb.Horizontal(
        rrb.Vertical(*left, row_shares=[2, 3]) if len(left) > 1 else left[0],
        rrb.Grid(*series_views, grid_columns=2),
        column_shares=[2, 3],
    )
    return rrb.Blueprint(root, *panels(), collapse_panels=False)
