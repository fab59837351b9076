"""The default viewer layout: :func:`build_blueprint` and the view helpers the cross-check
layout shares.

Read without clicking: every view is titled in full with its unit; legends sit at the
top right over a margin kept free after the end of the run, wide enough for their names
(never over the curves), and a view of a single series has none (its title names it);
at most six series views share a tab, so a 1280x800 viewer keeps their tick labels;
side panels are folded so the plots get the room; the fuzzy views appear only for a
controller with rule bases.
"""

from __future__ import annotations

import math
from typing import Sequence

import rerun as rr
import rerun.blueprint as rrb

from tspend.loop.sinks import FuzzyInputInfo, RunInfo
from tspend.recorder.common import BMF_WIDTH, TIMELINE, join_path, prefix_label
from tspend.recorder.labels import plant_labels
from tspend.recorder.series import END_ENTITY, STEADY_FROM, SeriesSpec, specs_of

#: the tabs of the series views, by :attr:`SeriesSpec.group`
GROUP_TITLES = {"tracking": "tracking and control", "internals": "controller internals",
                "plant": "plant"}

#: the time axis runs past the end of the run by at least this fraction: the legend sits there
LEGEND_MARGIN = 0.22
#: what the legend's width is judged against: a plot about this wide (px), as a series
#: view's plot area is in a 1280x800 viewer (two columns in three fifths of the window) ...
PLOT_WIDTH_PX = 350.0
#: ... and the width of a legend's character and of its swatch and frame (px; measured on
#: Rerun 0.41's web viewer: "alpha (rad)" takes 93 px, "e_alpha' (rad/s)" 110 px)
LEGEND_CHAR_PX, LEGEND_FRAME_PX = 5.5, 36.0


#: a series view's plot is about this tall in a 1280x800 viewer (three rows of views) ...
PLOT_HEIGHT_PX = 190.0
#: ... and Rerun's plots (egui_plot) tick at powers of ten only, labelling a step when its
#: ticks are about this far apart (faint from 20 px, full from 30): a view of u in
#: [-65, 70] N, 190 px tall, labels only its 0 (the 10 N ticks are 14 px apart, the next
#: step's +/-100 lie outside)
Y_LABEL_SPACING_PX = 25.0
#: the range runs this fraction past its ends (multiples of the step), so that their
#: labels are inside the plot, not cut off at its edges
Y_PAD = 0.08


def labelled_range(lo: float, hi: float, height_px: float = PLOT_HEIGHT_PX) -> tuple[float, float] | None:
    """A y range around the data's ``[lo, hi]`` in which a plot ``height_px`` tall labels at
    least two ticks: its ends are multiples of a power of ten ``step`` (or of half of it)
    with two multiples of ``step`` inside, ``Y_LABEL_SPACING_PX`` apart or more, padded by
    ``Y_PAD`` (u in [-65, 70] -> [-116, 116], labelled -100, 0, 100).  None when the data
    give no range."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return None
    base = 10.0 ** math.floor(math.log10(hi - lo))
    best: tuple[float, float] | None = None
    for step in (base, 10.0 * base, 100.0 * base):
        for unit in (0.5 * step, step):   # ends at half steps if that holds two ticks
            a, b = math.floor(lo / unit) * unit, math.ceil(hi / unit) * unit
            ticks = math.floor(b / step + 1e-9) - math.ceil(a / step - 1e-9) + 1
            pad = Y_PAD * (b - a)          # a label on the plot's edge is cut off
            if ticks >= 2 and height_px * step / (b - a + 2 * pad) >= Y_LABEL_SPACING_PX:
                if best is None or b - a + 2 * pad < best[1] - best[0]:
                    best = (a - pad, b + pad)   # the tightest: the data fill the view
    return best


def _abs(prefix: str, path: str) -> str:
    return "/" + join_path(prefix, path)


def legend_margin(names: Sequence[str]) -> float:
    """How far past the run's end the time axis must go for a legend of ``names`` in the
    top right corner to sit beside the curves rather than over them."""
    if not names:
        return 0.02
    legend = LEGEND_FRAME_PX + LEGEND_CHAR_PX * max(len(n) for n in names)
    share = min(0.45, legend / PLOT_WIDTH_PX)       # of the plot's width
    return max(LEGEND_MARGIN, share / (1.0 - share))


def time_axis(duration: float, margin: float = LEGEND_MARGIN, start: float = 0.0) -> rrb.TimeAxis:
    """``start`` .. duration plus ``margin`` of the shown span for the legend."""
    end = max(duration, 1e-3)
    end += (end - start) * margin
    return rrb.TimeAxis(view_range=rr.TimeRange(start=rr.TimeRangeBoundary.absolute(seconds=start),
                                                end=rr.TimeRangeBoundary.absolute(seconds=end)))


def series_view(name: str, contents: Sequence[str], duration: float, legend: Sequence[str] | None = (),
                *, start: float = 0.0, y_range: tuple[float, float] | None = None,
                lock: bool = True) -> rrb.TimeSeriesView:
    """A time-series view titled ``name``; ``legend`` the names it shows (``None``: no legend,
    ``()``: a legend of unknown names, given the default margin); ``y_range`` fixed (zoom
    locked unless ``lock`` is False)."""
    shown = legend is not None
    margin = legend_margin(legend) if legend else LEGEND_MARGIN if shown else 0.02
    return rrb.TimeSeriesView(origin="/", contents=list(contents), name=name,
                              axis_x=time_axis(duration, margin, start),
                              axis_y=rrb.ScalarAxis(range=y_range, zoom_lock=lock) if y_range else None,
                              plot_legend=rrb.PlotLegend(rrb.components.Corner2D.RightTop, visible=shown))


def _input_title(info: RunInfo, group: str, inp: FuzzyInputInfo) -> str:
    """``"x_o1 = theta (rad)"`` (the model's), ``"comp.: e_delta"`` (the compensator's):
    short enough for a view a fifth of the screen wide (the axis under the curves gives
    the interval; the tab's name says faint curves are the initial ones)."""
    labels = plant_labels(info.plant_kind, info.order, info.input_unit)
    quantity = None
    if inp.name.startswith("x_o") and inp.name[3:].isdigit() and int(inp.name[3:]) <= len(labels.states):
        quantity = labels.states[int(inp.name[3:]) - 1]
    elif inp.name == "u_o":
        quantity = labels.control
    meaning = f" = {quantity.with_unit()}" if quantity is not None and quantity.symbol != inp.name else ""
    return f"{inp.name}{meaning}" if group == "model" else f"comp.: {inp.name}{meaning}"


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
    """The plant in 3D as its domain draws it (:meth:`tspend.plants.drawing.base.Drawing.view`)."""
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
                    draw: bool | None = None,
                    y_ranges: dict[str, tuple[float, float]] | None = None) -> rrb.Blueprint:
    """The default layout: the plant in 3D and fuzzy internals beside the time series.

    With several ``prefixes`` (side-by-side runs in one recording) every time-series
    view overlays all runs; 3D and fuzzy views are per run.  ``draw`` defaults to whether
    the plant's domain draws it (``info.drawing``).  ``y_ranges``: each series entity's
    data range (the sink's, at the end of the run), shown as :func:`labelled_range` so the
    view keeps its tick labels; without it the views fit the data as it comes.
    """
    prefixes = list(prefixes) or [""]
    multi = len(prefixes) > 1
    suffixes = [f" [{prefix_label(p)}]" if multi else "" for p in prefixes]
    specs: list[SeriesSpec] = specs_of(info)
    series_tabs: dict[str, list[rrb.View]] = {}
    for spec in specs:
        if not spec.group:
            continue  # recorded for export, shown elsewhere (r in the tracking view)
        names = [n + sfx for n in spec.names for sfx in suffixes]
        start = STEADY_FROM * info.duration if spec.steady else 0.0
        contents = [_abs(p, spec.entity) for p in prefixes]
        if spec.entity == "series/tracking":
            # where a run that did not complete ended (RerunSink._mark_end)
            contents += [_abs(p, END_ENTITY) for p in prefixes]
        extent = (y_ranges or {}).get(spec.entity)
        series_tabs.setdefault(spec.group, []).append(series_view(
            spec.title, contents, info.duration, names if spec.legend or multi else None, start=start,
            y_range=labelled_range(*extent) if extent else None, lock=False))
    bmf_views: list[rrb.View] = []
    firing_views: list[rrb.View] = []
    doc_views: list[rrb.View] = []
    for p, sfx in zip(prefixes, suffixes):
        bmf, firing = fuzzy_views(info, p, sfx)
        bmf_views += bmf
        firing_views += firing
        doc_views += document_views(p, sfx)
    fuzzy_tabs = [rrb.Grid(*bmf_views, grid_columns=2, name="membership functions (faint: initial)"),
                  rrb.Grid(*firing_views, grid_columns=2, name="firing and consequents")] if bmf_views else []
    tabs = rrb.Tabs(*fuzzy_tabs, rrb.Tabs(*doc_views, name="run info"))
    left: list[rrb.Container | rrb.View] = []
    if info.drawing is not None and (draw is None or draw):
        views3d = [plant_view(info, p, sfx) for p, sfx in zip(prefixes, suffixes)]
        left.append(rrb.Horizontal(*views3d) if multi else views3d[0])
    left.append(tabs)
    # at most six series views at once (three rows of two): each keeps its tick labels in
    # a 1280x800 viewer; the controller's internals and the plant's extras in their own tabs
    right = rrb.Tabs(*(rrb.Grid(*views, grid_columns=2, name=GROUP_TITLES.get(group, group))
                       for group, views in series_tabs.items()))
    root = rrb.Horizontal(
        rrb.Vertical(*left, row_shares=[2, 3]) if len(left) > 1 else left[0],
        right,
        column_shares=[2, 3],
    )
    return rrb.Blueprint(root, *panels(), collapse_panels=False)
