"""The cross-check (MuJoCo against the cart-pole ODE) as a recording of its own.

:func:`crosscheck_sinks` wraps the two runs' :class:`RerunSink` so that, besides each
run, the recording holds the difference MuJoCo minus ODE of every state and of the cart
position (``crosscheck/diff/<key>``, sample by sample, from the same values the runs
report), a name, and a layout that puts each state's overlay beside its difference.
:func:`record_verdict` adds the verdict document (``crosscheck/verdict``): the figures
of the report, the tolerance and pass/fail, with the report as JSON.
"""

from __future__ import annotations

import json
from typing import Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from tspend.loop.sinks import Block, InnerSnapshot, RunEnd, RunInfo
from tspend.recorder.arrow import time_column
from tspend.recorder.blueprint import document_views, panels, plant_view, series_view
from tspend.recorder.common import PALETTE, join_path
from tspend.recorder.labels import Quantity, extra_quantity, plant_labels
from tspend.recorder.series import COMPENSATOR_SHARE, series_location, series_specs
from tspend.recorder.sink import RerunSink

VERDICT = "crosscheck/verdict"
DIFF = "crosscheck/diff"
LOG10_DIFF = "crosscheck/log10_abs_diff"
#: |difference| is floored here before its log10: an exact 0 is drawn at log10 = -16
DIFF_FLOOR = 1e-16
#: the fixed y range of the log10 |difference| views: from the floor to 10 (1e-16 .. 1e1),
#: so 1e-14 (round-off) and 1e-3 (a modelling difference) sit at plainly different heights
LOG10_RANGE = (-16.5, 1.0)


def diff_entity(key: str) -> str:
    """Entity of the difference series of ``key`` (``x1``, ``x2``, ``cart_pos``)."""
    return f"{DIFF}/{key}"


def log10_diff_entity(key: str) -> str:
    """Entity of ``log10(max(|difference|, DIFF_FLOOR))`` of ``key``: what the layout draws."""
    return f"{LOG10_DIFF}/{key}"


def log10_abs(diff: np.ndarray) -> np.ndarray:
    """``log10 |diff|`` floored at :data:`DIFF_FLOOR`."""
    return np.log10(np.maximum(np.abs(np.asarray(diff, dtype=np.float64)), DIFF_FLOOR))


def _diff_name(q: Quantity) -> str:
    return f"log10 |{q.symbol} MuJoCo - ODE|" + (f" ({q.unit})" if q.unit else "")


class _MujocoSide:
    """Records the MuJoCo run and keeps its states for the difference."""

    wants_inner = True

    def __init__(self, sink: RerunSink, pair: "_Pair") -> None:
        self.sink, self.pair = sink, pair

    def start(self, info: RunInfo) -> None:
        self.pair.start(info)
        self.sink.start(info)

    def block(self, block: Block) -> None:
        self.pair.keep(block)
        self.sink.block(block)

    def inner(self, snap: InnerSnapshot) -> None:
        self.sink.inner(snap)

    def finish(self, end: RunEnd) -> None:
        self.sink.finish(end)


class _OdeSide(_MujocoSide):
    """Records the ODE run and the difference MuJoCo minus ODE as its blocks come."""

    def start(self, info: RunInfo) -> None:
        self.sink.start(info)

    def block(self, block: Block) -> None:
        self.sink.block(block)
        self.pair.send_difference(block)


class _Pair:
    """What the two sides share: the MuJoCo states by step, and the recording."""

    def __init__(self, mujoco: RerunSink, ode: RerunSink) -> None:
        self.mujoco, self.ode = mujoco, ode
        self.rec = mujoco.rec
        self.every = mujoco.curves_every
        self._kept: dict[str, list[np.ndarray]] = {}
        self._columns: dict[str, np.ndarray] | None = None
        self.keys: list[tuple[str, Quantity]] = []

    def start(self, info: RunInfo) -> None:
        labels = plant_labels(info.plant_kind, info.order)
        self.keys = [(f"x{i + 1}", q) for i, q in enumerate(labels.states)]
        self.keys += [(name, extra_quantity(labels, name)) for name in info.extras
                      if name in labels.extras]
        if self.rec is None:
            return
        for i, (key, q) in enumerate(self.keys):
            color = PALETTE[(4 + i) % len(PALETTE)]
            self.rec.log(diff_entity(key), rr.SeriesLines(
                names=[f"{q.symbol}: MuJoCo - ODE" + (f" ({q.unit})" if q.unit else "")], colors=[color],
                aggregation_policy=rr.components.AggregationPolicy.MinMax), static=True)
            # the largest difference must survive thinning: max aggregation of the log
            self.rec.log(log10_diff_entity(key), rr.SeriesLines(
                names=[_diff_name(q)], colors=[color],
                aggregation_policy=rr.components.AggregationPolicy.Max), static=True)
        self.rec.send_blueprint(crosscheck_blueprint(info, self.keys))
        self.rec.send_recording_name(f"{info.scenario_name}: cross-check MuJoCo vs ODE (seed {info.seed})")

    def _values(self, data: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        out = {}
        for key, _ in self.keys:
            if key.startswith("x") and key[1:].isdigit():
                out[key] = np.asarray(data["x"][:, int(key[1:]) - 1], dtype=np.float64)
            elif f"extra/{key}" in data:
                out[key] = np.asarray(data[f"extra/{key}"], dtype=np.float64)
        return out

    def keep(self, block: Block) -> None:
        for key, values in self._values(block.data).items():
            self._kept.setdefault(key, []).append(values.copy())

    def send_difference(self, block: Block) -> None:
        if self.rec is None:
            return
        if self._columns is None:
            self._columns = {k: np.concatenate(v) for k, v in self._kept.items()}
            self._kept = {}
        t = np.asarray(block.data["t"], dtype=np.float64)
        start = block.start
        for key, ode in self._values(block.data).items():
            mujoco = self._columns.get(key)
            if mujoco is None:
                continue
            count = max(0, min(ode.size, mujoco.size - start))
            rows = np.arange((-start) % self.every, count, self.every)
            if rows.size == 0:
                continue
            diff = mujoco[start + rows] - ode[rows]
            times = time_column(t[rows])
            self.rec.send_columns(diff_entity(key), indexes=[times], columns=rr.Scalars.columns(scalars=diff))
            self.rec.send_columns(log10_diff_entity(key), indexes=[times],
                                  columns=rr.Scalars.columns(scalars=log10_abs(diff)))


def crosscheck_sinks(sinks: Sequence[RerunSink]) -> list:
    """The two sinks of a cross-check (MuJoCo first, then the ODE), wrapped so the
    recording also holds the differences, a name and the cross-check layout."""
    if len(sinks) != 2:
        return list(sinks)
    mujoco, ode = sinks
    mujoco.blueprint_prefixes = ode.blueprint_prefixes = None  # the pair sends its own layout
    pair = _Pair(mujoco, ode)
    return [_MujocoSide(mujoco, pair), _OdeSide(ode, pair)]


def _fmt(value: object) -> str:
    if isinstance(value, bool):
        return "pass" if value else "FAIL"
    if isinstance(value, float):
        return f"{value:.3g}"
    return str(value)


def verdict_markdown(report: dict) -> str:
    """The verdict: pass/fail against the tolerance, then every figure of the report."""
    tol = report.get("tolerance")
    ok = report.get("open_loop_ok")
    head = "PASS" if ok else "FAIL" if ok is not None else "no verdict (no tolerance given)"
    lines = [f"# Cross-check {report.get('scenario', '')}: {head}", ""]
    if report.get("verdict"):
        lines += [str(report["verdict"]), ""]
    if tol is not None:
        tracked = report.get("open_loop_tracked", "x1")
        closed = ", ".join(f"max |d {k.removeprefix('closed_loop_max_d')}| = {_fmt(v)}"
                           for k, v in report.items() if k.startswith("closed_loop_max_d"))
        lines += [f"Open loop (same chirp input and disturbance on both backends for "
                  f"{_fmt(report.get('open_loop_duration'))} s): max |{tracked}_MuJoCo - "
                  f"{tracked}_ODE| = {_fmt(report.get('open_loop_max_tracked'))} against the "
                  f"tolerance {_fmt(tol)}: **{_fmt(bool(ok))}**.", "",
                  "Closed loop (the scenario's controller on each backend; the plots MuJoCo minus ODE "
                  f"show it sample by sample): {closed} "
                  "(reported, not judged: sign() in the compensator may amplify round-off).", "",
                  f"The views log10 |MuJoCo - ODE| draw log10 of the absolute difference, floored at "
                  f"{DIFF_FLOOR:g}, on the fixed range {LOG10_RANGE[0]:g} .. {LOG10_RANGE[1]:g}: "
                  "-16 to -13 is round-off, a real modelling difference sits far higher.", ""]
    lines += ["| figure | value |", "| --- | --- |"]
    flat = {k: v for k, v in report.items() if not isinstance(v, dict)}
    lines += [f"| {k} | {_fmt(v)} |" for k, v in flat.items()]
    body = json.dumps(flat, indent=2, default=lambda o: o.item() if isinstance(o, np.generic) else str(o),
                      allow_nan=True)
    lines += ["", "```json", body, "```", ""]
    return "\n".join(lines)


def record_verdict(sinks: Sequence[object], report: dict) -> None:
    """Log the verdict document into the recording of ``sinks`` (none: nothing)."""
    rec = next((s.sink.rec if isinstance(s, (_MujocoSide, _OdeSide)) else s.rec
                for s in sinks if isinstance(s, (_MujocoSide, _OdeSide, RerunSink))), None)
    if rec is None:
        return
    rec.log(VERDICT, rr.TextDocument(verdict_markdown(report), media_type=rr.MediaType.MARKDOWN), static=True)


def read_verdict(text: str) -> dict:
    """The report's figures back from a verdict document (its JSON block)."""
    body = text.split("```json", 1)[1].split("```", 1)[0]
    return json.loads(body)


def crosscheck_blueprint(info: RunInfo, keys: Sequence[tuple[str, Quantity]],
                         prefixes: Sequence[str] = ("mujoco/", "ode/")) -> rrb.Blueprint:
    """Each state's overlay (MuJoCo and ODE) beside its log10 |difference| on a fixed
    range; u and the compensator's share of u overlaid in a second tab; the two 3D
    scenes; the verdict first among the documents."""
    order, extras, diags = info.order, info.extras, info.diagnostics
    labels = [f" [{p.strip('/')}]" for p in prefixes]

    def both(name: str) -> list[str]:
        return ["/" + series_location(name, order, extras, p, diags)[0] for p in prefixes]

    specs = series_specs(order, extras, diags, info.plant_kind, input_unit=info.input_unit)

    def names(key: str) -> list[str]:
        """The legend of the overlay of series ``key``: each name once per backend."""
        spec = next(s for s in specs if key in s.lookup)
        return [n + label for n in spec.names for label in labels]

    states: list[rrb.View] = []
    for key, q in keys:
        if key == "x1":
            overlay = series_view(f"{q.meaning or q.symbol} {q.with_unit()}: MuJoCo and ODE",
                                  both("x1"), info.duration, names("x1"))
        elif key.startswith("x") and int(key[1:]) <= len(info.view):
            # x2.. as the plant's full state records them (series/state/<name>) on both
            entity = f"series/state/{info.view[int(key[1:]) - 1]}"
            overlay = series_view(f"{q.meaning or q.symbol} {q.with_unit()}: MuJoCo and ODE",
                                  ["/" + join_path(p, entity) for p in prefixes], info.duration,
                                  [q.with_unit() + label for label in labels])
        elif key.startswith("x"):
            # x2.. are not plotted per run; the error view holds e_2 = x_2 - r' for both
            overlay = series_view(f"tracking error (e_2 = {q.symbol} - r'): MuJoCo and ODE",
                                  both("e_1"), info.duration, names("e_1"))
        else:
            overlay = series_view(f"{q.meaning or q.symbol} {q.with_unit()}: MuJoCo and ODE", both(key),
                                  info.duration, names(key))
        states += [overlay, series_view(
            f"log10 |MuJoCo - ODE|, {q.with_unit()}",
            ["/" + log10_diff_entity(key)], info.duration, None, y_range=LOG10_RANGE)]
    u = plant_labels(info.plant_kind, order, info.input_unit).control
    control = [series_view(f"control {u.with_unit()}: MuJoCo and ODE", both("u"), info.duration, names("u"))]
    try:
        control.append(series_view(f"compensator share of u, -u_s / b_hat{' (' + u.unit + ')' if u.unit else ''}"
                                   ": MuJoCo and ODE",
                                   both(COMPENSATOR_SHARE), info.duration, names(COMPENSATOR_SHARE)))
    except KeyError:
        pass  # a controller without a compensator
    left: list = ([rrb.Horizontal(*(plant_view(info, p, f" [{p.strip('/')}]") for p in prefixes))]
                  if info.drawing is not None else [])
    docs = [rrb.TextDocumentView(origin="/" + VERDICT, name="cross-check verdict")]
    for p in prefixes:
        docs += document_views(p, f" [{p.strip('/')}]")
    left.append(rrb.Tabs(*docs, name="verdict and run info"))
    right = rrb.Tabs(rrb.Grid(*states, grid_columns=2, name="states: MuJoCo, ODE and their difference"),
                     rrb.Grid(*control, grid_columns=1, name="control: MuJoCo and ODE"))
    root = rrb.Horizontal(rrb.Vertical(*left, row_shares=[2, 3]) if len(left) > 1 else left[0], right,
                          column_shares=[2, 3])
    return rrb.Blueprint(root, *panels(), collapse_panels=False)


__all__ = ["DIFF_FLOOR", "LOG10_RANGE", "VERDICT", "crosscheck_blueprint", "crosscheck_sinks", "diff_entity",
           "log10_abs", "log10_diff_entity", "read_verdict", "record_verdict", "verdict_markdown"]
