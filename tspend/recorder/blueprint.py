"""The default viewer layout: :func:`build_blueprint` and its view helpers."""

from __future__ import annotations

from typing import Sequence

import rerun.blueprint as rrb

from ..sinks import RunInfo
from .cartpole import is_cartpole
from .common import BMF_WIDTH, join_path, prefix_label
from .series import series_specs


def _abs(prefix: str, path: str) -> str:
    return "/" + join_path(prefix, path)


def _fuzzy_views(info: RunInfo, prefix: str, suffix: str) -> tuple[list[rrb.View], list[rrb.View]]:
    """(membership-curve views, firing/consequent views) of one run."""
    bmf: list[rrb.View] = []
    if not (info.model_inputs or info.compensator_inputs):
        return [], []  # a controller without rule bases
    for group, inputs in (("model", info.model_inputs), ("compensator", info.compensator_inputs)):
        for j, inp in enumerate(inputs):
            # drawn on [0, BMF_WIDTH] (RerunSink._display_x): the name carries the interval
            bmf.append(rrb.Spatial2DView(
                origin=_abs(prefix, f"fuzzy/{group}/in{j}"),
                name=f"BMF {inp.name} on [{inp.lo:.4g}, {inp.hi:.4g}]{suffix}",
                visual_bounds=rrb.VisualBounds2D(x_range=[-0.05 * BMF_WIDTH, 1.05 * BMF_WIDTH],
                                                 y_range=[-1.1, 0.1])))
    firing: list[rrb.View] = [
        rrb.BarChartView(origin=_abs(prefix, "fuzzy/firing"), name=f"rule firing w{suffix}"),
        rrb.BarChartView(origin=_abs(prefix, "fuzzy/compensator_firing"), name=f"compensator firing tau{suffix}"),
        rrb.TensorView(origin=_abs(prefix, "fuzzy/consequents"), name=f"consequents p_k^i{suffix}"),
        rrb.BarChartView(origin=_abs(prefix, "fuzzy/q"), name=f"compensator consequents q{suffix}"),
    ]
    return bmf, firing


def _cartpole_view(info: RunInfo, prefix: str, suffix: str) -> rrb.Spatial3DView:
    """The cart-pole seen from the side, the camera following the cart.

    The cart travels tens of metres in a long run while the pole is 2 l long: a camera
    fitted to the scene bounds would lose the pole, so it tracks the cart instead.
    """
    l = info.drawing.l if info.drawing is not None else 3.0
    return rrb.Spatial3DView(
        origin=_abs(prefix, "world"), name=f"cart-pole{suffix}",
        eye_controls=rrb.EyeControls3D(
            position=[0.0, -(3.0 * l + 6.0), l + 0.5], look_target=[0.0, 0.0, l + 0.5],
            eye_up=[0.0, 0.0, 1.0], tracking_entity=_abs(prefix, "world/cart")))


def build_blueprint(info: RunInfo, prefixes: Sequence[str] = ("",), *,
                    cartpole: bool | None = None) -> rrb.Blueprint:
    """The default layout: 3D cart-pole and fuzzy internals beside the time series.

    With several ``prefixes`` (side-by-side runs in one recording, e.g. the MuJoCo/ODE
    crosscheck) every time-series view overlays all runs; 3D and fuzzy views are per run.
    ``cartpole`` defaults to :func:`is_cartpole` of ``info``.
    """
    prefixes = list(prefixes) or [""]
    multi = len(prefixes) > 1
    suffixes = [f" [{prefix_label(p)}]" if multi else "" for p in prefixes]
    series_views: list[rrb.View] = [
        rrb.TimeSeriesView(origin="/", contents=[_abs(p, spec.entity) for p in prefixes],
                           name=spec.title)
        for spec in series_specs(info.order, info.extras, info.diagnostics)
    ]
    bmf_views: list[rrb.View] = []
    firing_views: list[rrb.View] = []
    doc_views: list[rrb.View] = []
    for p, sfx in zip(prefixes, suffixes):
        bmf, firing = _fuzzy_views(info, p, sfx)
        bmf_views += bmf
        firing_views += firing
        doc_views += [rrb.TextDocumentView(origin=_abs(p, f"info/{doc}"), name=f"{doc}{sfx}")
                      for doc in ("status", "metrics", "run", "scenario")]
        doc_views.append(rrb.TextLogView(origin=_abs(p, "events"), name=f"events{sfx}"))
    fuzzy_tabs = [rrb.Grid(*bmf_views, name="membership functions"),
                  rrb.Grid(*firing_views, name="firing and consequents")] if bmf_views else []
    tabs = rrb.Tabs(*fuzzy_tabs, rrb.Tabs(*doc_views, name="run info"))
    left: list[rrb.Container | rrb.View] = []
    if is_cartpole(info) if cartpole is None else cartpole:
        views3d = [_cartpole_view(info, p, sfx) for p, sfx in zip(prefixes, suffixes)]
        left.append(rrb.Horizontal(*views3d) if multi else views3d[0])
    left.append(tabs)
    root = rrb.Horizontal(
        rrb.Vertical(*left),
        rrb.Grid(*series_views, grid_columns=2),
        column_shares=[2, 3],
    )
    return rrb.Blueprint(root, collapse_panels=False)
