""":class:`RerunSink`, the :class:`~tspend.loop.sinks.Sink` that streams a run, and its snapshot buffer."""

from __future__ import annotations

import math
import time
import weakref
from typing import Literal, Sequence

import numpy as np
import rerun as rr

from tspend.loop.sinks import Block, InnerSnapshot, RunEnd, RunInfo
from tspend.plants.drawing.base import Drawing
from tspend.recorder.arrow import (check_tensor_type, points_column, strips_column, tensor_column,
    time_column)
from tspend.recorder.blueprint import build_blueprint
from tspend.recorder.common import BMF_WIDTH, PALETTE, Color, join_path, prefix_label
from tspend.recorder.documents import (metrics_markdown, run_markdown, scenario_markdown,
    status_markdown)
from tspend.recorder.fuzzy_axes import axis_parts, term_label_positions
from tspend.recorder.series import (END_ENTITY, STEADY_FROM, SeriesSpec, compact_specs,
    export_columns, specs_of)
from tspend.recorder.stream import close_recording, flush


#: rate of the 3D cart-pole frames (Hz of simulated time)
FRAME_HZ = 50.0
#: a compact recording's rate of the views and diagnostics (Hz of simulated time); the
#: state, the reference, the applied input and the disturbance keep every sample in their
#: own entity (series.compact_specs, docs/recordings.md). The sink's default, 0, records
#: every series at every sample; tspend run records compactly unless told otherwise.
DIAGNOSTICS_HZ = 50.0
#: a compact recording's rate of the controller's inner snapshots (membership functions,
#: firing, consequents: they adapt over seconds), Hz of simulated time
SNAPSHOT_HZ = 2.0
#: 3D frames and inner snapshots are sent in batches of this many rows (2 s at 50 Hz) ...
DECIMATED_ROWS = 100
#: ... or after this much wall time, so a live viewer stays current
MAX_LATENCY_S = 0.5


def _snapshot_values(snap: InnerSnapshot) -> list[object]:
    """The snapshot's fields in the fixed order of :meth:`_SnapshotBuffer.keys`."""
    values: list[object] = [snap.t]
    for sets in (snap.model_sets, snap.compensator_sets):
        for grid, curves, z, mu in sets:
            values += (grid, curves, z, mu)
    values += (snap.firing, snap.compensator_firing, snap.consequents, snap.q)
    return values


class _SnapshotBuffer:
    """Preallocated rows for the snapshots awaiting a flush, reused flush after flush.

    Values are copied in (the controller may hand out its live consequent arrays)
    with one numpy assignment per field and no per-row allocation.
    """

    def __init__(self) -> None:
        self.count = 0
        self.keys: list[str] = []
        self._layout: tuple[int, int] | None = None
        self._bufs: list[np.ndarray] = []
        self._index: dict[str, int] = {}

    def append(self, snap: InnerSnapshot) -> None:
        values = _snapshot_values(snap)
        if self.count == 0:
            self._ensure_layout(snap, values)
        elif self.count == self._bufs[0].shape[0]:
            self._bufs = [np.concatenate([b, np.empty_like(b)]) for b in self._bufs]
        i = self.count
        for buf, value in zip(self._bufs, values):
            buf[i] = value
        self.count += 1

    def _ensure_layout(self, snap: InnerSnapshot, values: list[object]) -> None:
        """(Re)allocate when the snapshot's structure differs from the buffers'."""
        layout = (len(snap.model_sets), len(snap.compensator_sets))
        shapes = [np.shape(v) for v in values]
        if layout == self._layout and shapes == [b.shape[1:] for b in self._bufs]:
            return
        self._layout = layout
        self.keys = ["t"]
        for group, count in zip(("model", "compensator"), layout):
            for j in range(count):
                self.keys += [f"{group}/in{j}/{f}" for f in ("grid", "curves", "z", "mu")]
        self.keys += ["firing", "compensator_firing", "consequents", "q"]
        self._index = {k: i for i, k in enumerate(self.keys)}
        self._bufs = [np.empty((64,) + shape) for shape in shapes]

    def clear(self) -> None:
        """Forget the rows, keep the storage (so memory stays flat)."""
        self.count = 0

    def get(self, key: str) -> np.ndarray:
        """The ``count`` rows of ``key`` (a view, valid until the next append)."""
        return self._bufs[self._index[key]][: self.count]

    def inputs(self, group: str) -> list[str]:
        """``"model/in0"``, ... for the buffered snapshots."""
        count = self._layout[0 if group == "model" else 1] if self._layout else 0
        return [f"{group}/in{j}" for j in range(count)]


_SINKS_PER_RECORDING: weakref.WeakKeyDictionary[rr.RecordingStream, int] = weakref.WeakKeyDictionary()


def _next_variant(rec: rr.RecordingStream | None) -> int:
    """0 for the first sink made on ``rec``, 1 for the second, ...: overlaid runs differ in shade."""
    if rec is None:
        return 0
    count = _SINKS_PER_RECORDING.get(rec, 0)
    _SINKS_PER_RECORDING[rec] = count + 1
    return count


def _lighten(color: Color, amount: float) -> Color:
    return tuple(int(round(c + (255 - c) * amount)) for c in color)  # type: ignore[return-value]


class RerunSink:
    """Streams a run into a caller-created :class:`rerun.RecordingStream`.

    ``prefix`` puts every entity under ``prefix/`` so several runs can share one
    recording; ``label`` (default: the prefix) is appended to series names and
    ``variant`` 1 lightens the colours, so overlaid runs stay distinguishable.
    ``curves_every`` decimates the per-step series (1 = every step, exact);
    ``diagnostics_hz`` > 0 makes the recording compact (:func:`~tspend.recorder.series.compact_specs`:
    the state, r, the applied input and d at every recorded step in one entity, every view and
    diagnostic at this rate of simulated time); ``frame_hz`` is the rate of 3D frames; ``decimated_rows`` and ``max_latency_s``
    bound how long 3D frames and snapshots wait before they are sent.  At :meth:`start`
    the sink sends :func:`build_blueprint` for ``blueprint_prefixes``: ``"own"`` (its own
    prefix), a list (e.g. all runs of a shared recording, from one of its sinks), or
    ``None`` (no blueprint).  ``variant`` defaults to 0, 1, ... in the order sinks are
    made on one recording.  With ``rec=None`` the sink records nothing.

    Memory stays flat: each block's series are sent as the block comes; the decimated
    data (3D frames, inner snapshots) wait in small reused buffers until ``decimated_rows``
    rows or ``max_latency_s`` of wall time have gathered, and :meth:`finish` sends the rest.
    Everything handed to Rerun is a fresh array (never a view of the runner's block or
    of a reused buffer), since Rerun encodes it later on its own thread.
    """

    #: the runner delivers inner snapshots (membership curves, firing) only to sinks that ask
    wants_inner = True

    def __init__(self, rec: rr.RecordingStream | None, *, prefix: str = "", label: str | None = None,
                 curves_every: int = 1, frame_hz: float = FRAME_HZ,
                 diagnostics_hz: float = 0.0,
                 blueprint_prefixes: Sequence[str] | Literal["own"] | None = "own",
                 variant: int | None = None, decimated_rows: int = DECIMATED_ROWS,
                 max_latency_s: float = MAX_LATENCY_S) -> None:
        if curves_every < 1:
            raise ValueError("curves_every must be >= 1")
        if not frame_hz > 0:
            raise ValueError(f"frame_hz must be > 0, got {frame_hz}")
        if not diagnostics_hz >= 0:
            raise ValueError(f"diagnostics_hz must be >= 0, got {diagnostics_hz}")
        self.diagnostics_hz = float(diagnostics_hz)
        #: the diagnostics' stride in samples, a multiple of curves_every (set by start)
        self._diagnostics_every = int(curves_every)
        #: a compact recording's time of the next snapshot kept (None: the first comes)
        self._next_snapshot_t: float | None = None
        self.rec = rec
        self.prefix = prefix.strip("/")
        self.label = prefix_label(prefix) if label is None else label
        self.curves_every = int(curves_every)
        self.frame_hz = float(frame_hz)
        self.blueprint_prefixes: list[str] | None = (
            [self.prefix] if blueprint_prefixes == "own" else None if blueprint_prefixes is None
            else list(blueprint_prefixes))
        self.variant = _next_variant(rec) if variant is None else int(variant)
        self.decimated_rows = max(1, int(decimated_rows))
        self.max_latency_s = float(max_latency_s)
        self.info: RunInfo | None = None
        self._specs: list[SeriesSpec] = []
        self._frame_every = 1
        self._drawing: Drawing | None = None
        self._snaps = _SnapshotBuffer()
        self._sent_curves: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._frames: list[tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]] = []  # (t, x, extras)
        self._frame_rows = 0
        self._last_flush = time.monotonic()
        self._last_t = 0.0
        self._last_output: float | None = None
        #: each series entity's finite data range so far (the views' y ranges at the end)
        self._extent: dict[str, tuple[float, float]] = {}

    # -- helpers

    def _path(self, path: str) -> str:
        return join_path(self.prefix, path)

    def _color(self, color: Color) -> Color:
        return _lighten(color, min(0.7, 0.45 * self.variant)) if self.variant else color

    def _series_name(self, name: str) -> str:
        return f"{name} [{self.label}]" if self.label else name

    # -- Sink protocol

    def start(self, info: RunInfo) -> None:
        """Static documents, series styles, static geometry and the blueprint."""
        self.info = info
        if self.rec is None:
            return
        self._snaps = _SnapshotBuffer()
        self._sent_curves = {}
        self._extent = {}
        self._intervals = {f"{group}/in{j}": (inp.lo, inp.hi)
                           for group, inputs in (("model", info.model_inputs),
                                                 ("compensator", info.compensator_inputs))
                           for j, inp in enumerate(inputs)}
        self._frames, self._frame_rows = [], 0
        self._last_flush, self._last_t = time.monotonic(), 0.0
        self._specs = compact_specs(specs_of(info)) if self.diagnostics_hz > 0 else specs_of(info)
        self._next_snapshot_t = None
        self._frame_every = max(1, int(round(1.0 / (self.frame_hz * info.dt)))) if info.dt > 0 else 1
        if self.diagnostics_hz > 0 and info.dt > 0:
            wanted = max(1, int(round(1.0 / (self.diagnostics_hz * info.dt))))
            self._diagnostics_every = self.curves_every * max(1, -(-wanted // self.curves_every))
        if info.model_inputs or info.compensator_inputs:
            check_tensor_type()  # before anything is written: a newer SDK may have changed TensorData
        self._log_documents(info)
        for spec in self._specs:
            policy = rr.components.AggregationPolicy.MinMax if spec.minmax else None
            self.rec.log(self._path(spec.entity), rr.SeriesLines(
                names=[self._series_name(n) for n in spec.names], colors=[self._color(c) for c in spec.colors],
                aggregation_policy=policy), static=True)
            # the stable names of the columns (x1, e_1, b_hat ...), so an export of the
            # recording names its columns as RunResult.to_pandas() does
            self.rec.log(self._path(spec.entity), rr.AnyValues(series_keys=[
                f"log10 {k}" if spec.log10 else k for k in spec.lookup]), static=True)
        # what `tspend export` writes: each column's name (unit at the end) and where it is
        columns = export_columns(self._specs, info.view)
        self.rec.log(self._path("info/columns"), rr.AnyValues(
            columns=[c for c, _, _ in columns], entities=[self._path(e) for _, e, _ in columns],
            instances=[j for _, _, j in columns]), static=True)
        self._log_fuzzy_styles(info)
        self._drawing = info.drawing
        if self._drawing is not None:
            self._drawing.log_static(self.rec, self._path("world"), self._color)
            self._drawing.log_bounds(self.rec, self._path("world"), info.bounds, self._color)
            # drawn before the first block arrives
            self._drawing.log_frames(self.rec, self._path("world"), time_column([0.0]),
                                     np.zeros((1, info.order)), {})
        if self.blueprint_prefixes is not None:
            self.rec.send_blueprint(build_blueprint(info, self.blueprint_prefixes))
        if not self.prefix:
            self.rec.send_recording_name(f"{info.scenario_name} ({info.controller_kind or 'run'}, "
                                         f"seed {info.seed})")

    def block(self, block: Block) -> None:
        """Send the block's series; buffer its 3D frames; send decimated data when due."""
        if self.rec is None or self.info is None:
            return
        data = block.data
        t = np.asarray(data["t"], dtype=np.float64)
        if t.size:
            self._last_t = float(t[-1])
            self._last_output = float(data["x"][-1, 0]) if data["x"].shape[1] else None
            self._send_series(block.start, data, t)
            if self._drawing is not None:
                self._buffer_frames(block.start, data, t)
        if self._decimated_due():
            self._flush_decimated()

    def inner(self, snap: InnerSnapshot) -> None:
        """Buffer a snapshot (copied: the runner may reuse its arrays); a compact recording
        keeps one per 1 / SNAPSHOT_HZ s of simulated time (the first one always)."""
        if self.rec is None:
            return
        if self.diagnostics_hz > 0:
            due = self._next_snapshot_t
            if due is not None and float(snap.t) < due:
                return
            self._next_snapshot_t = float(snap.t) + 1.0 / SNAPSHOT_HZ - 1e-9
        self._snaps.append(snap)
        self._last_t = max(self._last_t, float(snap.t))

    def finish(self, end: RunEnd) -> None:
        """Send what is pending, the status and metrics documents, and flush to the sink."""
        if self.rec is None:
            return
        self._flush_decimated()
        md = rr.MediaType.MARKDOWN
        self.rec.log(self._path("info/status"), rr.TextDocument(status_markdown(end), media_type=md), static=True)
        self.rec.log(self._path("info/metrics"), rr.TextDocument(metrics_markdown(end.metrics), media_type=md),
                     static=True)
        if end.status != "completed":
            self._mark_end(end)
        if self.blueprint_prefixes == [self.prefix] and self.info is not None:
            # the layout again, each view's y range set from the data so that it keeps its
            # tick labels (labelled_range); the last blueprint sent is the one shown
            self.rec.send_blueprint(build_blueprint(self.info, self.blueprint_prefixes,
                                                    y_ranges=dict(self._extent)))
        flush(self.rec)

    def _mark_end(self, end: RunEnd) -> None:
        """A run that did not complete, marked where it ended: a ``TextLog`` on ``events``,
        a cross on the tracking view at the last sample (``series/end``, named with the
        reason) and the reason in the 3D view from that time on."""
        level = "WARN" if end.status == "interrupted" else "ERROR"
        when = time_column([self._last_t])
        self.rec.send_columns(self._path("events"), indexes=[when],
                              columns=rr.TextLog.columns(text=[f"{end.status}: {end.message}"], level=[level]))
        if self._last_output is not None:
            self.rec.log(self._path(END_ENTITY), rr.SeriesPoints(
                names=[self._series_name(f"{end.status} at t = {self._last_t:.2f} s")], colors=[(214, 39, 40)],
                markers=["cross"], marker_sizes=[8.0]), static=True)
            self.rec.send_columns(self._path(END_ENTITY), indexes=[when],
                                  columns=rr.Scalars.columns(scalars=[self._last_output]))
        if self._drawing is not None:
            self._drawing.log_end(self.rec, self._path("world"), when, end.message or end.status)

    def close(self) -> None:
        """Flush and close the recording's sinks (finalises the ``.rrd`` footer).

        Call once, after every sink sharing the recording has finished.
        """
        if self.rec is not None:
            close_recording(self.rec)

    # -- block parts

    def _send_series(self, start: int, data: dict[str, np.ndarray], t: np.ndarray) -> None:
        rows = np.arange((-start) % self.curves_every, t.size, self.curves_every)
        times = time_column(t[rows])
        every = self._diagnostics_every
        thin = np.arange((-start) % every, t.size, every)
        thin_times = time_column(t[thin])
        assert self.info is not None
        steady_from = STEADY_FROM * self.info.duration - 0.5 * self.info.dt
        steady_rows = thin[t[thin] >= steady_from]
        for spec in self._specs:
            picked, index = ((steady_rows, None) if spec.steady else (rows, times)
                             if spec.every_sample else (thin, thin_times))
            if picked.size == 0:
                continue
            try:
                values = spec.extract(data)
            except KeyError:
                continue  # e.g. an extra the plant did not report in this block
            values = np.ascontiguousarray(values[picked])
            finite = values[np.isfinite(values)]
            if finite.size:
                lo, hi = self._extent.get(spec.entity, (math.inf, -math.inf))
                self._extent[spec.entity] = (min(lo, float(finite.min())), max(hi, float(finite.max())))
            self.rec.send_columns(self._path(spec.entity), indexes=[index if index is not None else time_column(t[picked])],
                                  columns=rr.Scalars.columns(scalars=values[:, 0] if values.shape[1] == 1 else values))

    def _buffer_frames(self, start: int, data: dict[str, np.ndarray], t: np.ndarray) -> None:
        """Keep the block's frame rows (every ``1 / frame_hz`` s of sim time) until the next flush."""
        rows = slice((-start) % self._frame_every, None, self._frame_every)
        x = np.array(data["x"][rows], dtype=np.float64)
        if x.shape[0] == 0:
            return
        extras = {key.removeprefix("extra/"): np.array(v[rows], dtype=np.float64)
                  for key, v in data.items() if key.startswith("extra/")}
        self._frames.append((t[rows].copy(), x, extras))
        self._frame_rows += x.shape[0]

    def _decimated_due(self) -> bool:
        """Frames and snapshots go out in batches of ``decimated_rows`` rows (chunks have a fixed
        cost of ~50 us each), or after ``max_latency_s`` of wall time for a live viewer."""
        rows = max(self._frame_rows, self._snaps.count)
        return rows >= self.decimated_rows or (rows > 0 and time.monotonic() - self._last_flush >= self.max_latency_s)

    def _flush_decimated(self) -> None:
        if self._frames and self._drawing is not None:
            t = np.concatenate([f[0] for f in self._frames])
            x = np.concatenate([f[1] for f in self._frames])
            names = set.intersection(*(set(f[2]) for f in self._frames))
            extras = {k: np.concatenate([f[2][k] for f in self._frames]) for k in names}
            self._frames, self._frame_rows = [], 0
            self._drawing.log_frames(self.rec, self._path("world"), time_column(t), x, extras)
        self._flush_snapshots()
        self._last_flush = time.monotonic()

    def _flush_snapshots(self) -> None:
        buf = self._snaps
        if not buf.count:
            return
        times = time_column(buf.get("t"))
        for group in ("model", "compensator"):
            for key in buf.inputs(group):
                points = self._operating_points(key, buf)
                if not self._send_changed_curves(key, buf, points):
                    self.rec.send_columns(self._path(f"fuzzy/{key}"), indexes=[times], columns=points)
        bar = rr.BarChart.descriptor_values()
        for name in ("firing", "compensator_firing", "q"):
            self.rec.send_columns(self._path(f"fuzzy/{name}"), indexes=[times],
                                  columns=[tensor_column(buf.get(name), bar)])
        # (k, rule): the whole matrix, for reading back; drawn as one bar chart per output k,
        # each with its own axis (p_1, p_2 and b differ in scale)
        consequents = np.swapaxes(buf.get("consequents"), 1, 2)
        self.rec.send_columns(self._path("fuzzy/consequents"), indexes=[times],
                              columns=[tensor_column(consequents, rr.Tensor.descriptor_data(), names=("k", "rule"))])
        for k in range(consequents.shape[1]):
            self.rec.send_columns(self._path(f"fuzzy/consequent_{k + 1}"), indexes=[times],
                                  columns=[tensor_column(consequents[:, k, :], bar)])
        buf.clear()

    def _display_x(self, key: str, z: np.ndarray) -> np.ndarray:
        """Input values drawn on [0, BMF_WIDTH] whatever the interval.

        A 2D view keeps a 1:1 aspect: membership (0..1) against u_o on [-1000, 1000]
        would be a flat line.  The view's name gives the real interval.
        """
        lo, hi = self._intervals[key]
        return (np.asarray(z, dtype=np.float64) - lo) * (BMF_WIDTH / (hi - lo))

    def _operating_points(self, key: str, buf: _SnapshotBuffer) -> list[rr.ComponentColumn]:
        """The operating point on every curve of input ``key``, one row per snapshot."""
        mu = buf.get(f"{key}/mu")
        count, terms = mu.shape
        marks = np.empty((count, terms, 2))
        marks[..., 0] = self._display_x(key, buf.get(f"{key}/z"))[:, None]
        marks[..., 1] = -mu                                   # y down on screen: log -mu
        return [points_column(marks.reshape(-1, 2), terms)]

    def _send_changed_curves(self, key: str, buf: _SnapshotBuffer, op_points: list[rr.ComponentColumn]) -> bool:
        """Curves of input ``key`` at the snapshots where they differ from the last ones sent.

        Fixed membership functions are thus sent once, which keeps the file small; curves
        that change at every snapshot go out with the operating points ``op_points`` in one chunk, and
        then the call returns True (the points are sent).
        """
        grid, curves = buf.get(f"{key}/grid"), buf.get(f"{key}/curves")
        count, terms, points = curves.shape
        previous = self._sent_curves.get(key)
        if (previous is not None and previous[0].shape == grid.shape[1:] and previous[1].shape == curves.shape[1:]
                and (grid == previous[0]).all() and (curves == previous[1]).all()):
            return False  # the common case: fixed membership functions, one pass over the block
        changed = np.empty(count, dtype=bool)
        changed[0] = previous is None or not (np.array_equal(previous[0], grid[0])
                                              and np.array_equal(previous[1], curves[0]))
        changed[1:] = np.any(curves[1:] != curves[:-1], axis=(1, 2)) | np.any(grid[1:] != grid[:-1], axis=1)
        if not changed.any():
            return False
        self._sent_curves[key] = (grid[-1].copy(), curves[-1].copy())
        rows = np.flatnonzero(changed)
        strips = np.empty((rows.size, terms, points, 2))
        strips[..., 0] = self._display_x(key, grid[rows])[:, None, :]
        strips[..., 1] = -curves[rows]
        if previous is None:
            self._log_initial_curves(key, strips[0])
        times = time_column(buf.get("t")[rows])
        curves_column = [strips_column(strips.reshape(-1, points, 2), terms)]
        every_row = rows.size == count
        self.rec.send_columns(self._path(f"fuzzy/{key}"), indexes=[times],
                              columns=[*curves_column, *op_points] if every_row else curves_column)
        # each term's name above its peak, wherever adaptation moved it
        self.rec.send_columns(self._path(f"fuzzy/{key}/terms"), indexes=[times],
                              columns=[points_column(term_label_positions(strips), terms)])
        return every_row

    def _log_initial_curves(self, key: str, strips: np.ndarray) -> None:
        """The first membership functions, faint and behind, so adaptation shows as the
        distance between them and the current ones (Rerun draws no dashed lines)."""
        terms = strips.shape[0]
        colors = [_lighten(self._color(PALETTE[k % len(PALETTE)]), 0.55) for k in range(terms)]
        self.rec.log(self._path(f"fuzzy/{key}/initial"),
                     rr.LineStrips2D([s.copy() for s in strips], colors=colors, radii=[-1.0], draw_order=-10.0),
                     static=True)

    # -- static parts

    def _log_documents(self, info: RunInfo) -> None:
        md = rr.MediaType.MARKDOWN
        self.rec.log(self._path("info/scenario"), rr.TextDocument(scenario_markdown(info), media_type=md),
                     static=True)
        self.rec.log(self._path("info/run"), rr.TextDocument(run_markdown(info), media_type=md), static=True)
        # the run's identity, for tools reading the recording (tspend export's metadata)
        self.rec.log(self._path("info/run"), rr.AnyValues(
            scenario=info.scenario_name, seed=int(info.seed), controller=info.controller_kind,
            plant_kind=info.plant_kind, version=info.version, dt_s=float(info.dt),
            duration_s=float(info.duration), u_unit=info.input_unit,
            # the force the actuator applies per unit of u at rest, where u is not it
            force_unit=info.force_unit, force_per_u=float(info.force_per_unit)), static=True)

    def _log_fuzzy_styles(self, info: RunInfo) -> None:
        for group, inputs in (("model", info.model_inputs), ("compensator", info.compensator_inputs)):
            for j, inp in enumerate(inputs):
                colors = [self._color(PALETTE[k % len(PALETTE)]) for k in range(len(inp.terms))]
                path = self._path(f"fuzzy/{group}/in{j}")
                self.rec.log(path, rr.LineStrips2D.from_fields(colors=colors, radii=[-1.5]),
                             rr.Points2D.from_fields(colors=colors, radii=[-5.0]), static=True)
                self.rec.log(f"{path}/terms", rr.Points2D.from_fields(colors=colors, labels=list(inp.terms),
                                                                      radii=[-0.5], show_labels=True), static=True)
                for name, part in axis_parts(inp.lo, inp.hi, BMF_WIDTH).items():
                    self.rec.log(f"{path}/axis/{name}", part, static=True)
        outputs = [(f"fuzzy/consequent_{k + 1}", PALETTE[(4 + k) % len(PALETTE)]) for k in range(info.order + 1)]
        for path, color in (("fuzzy/firing", (31, 119, 180)), ("fuzzy/compensator_firing", (44, 160, 44)),
                            ("fuzzy/q", (255, 127, 14)), *outputs):
            # BarChart.from_fields(color=...) trips over its own values converter in 0.41
            self.rec.log(self._path(path), [rr.components.ColorBatch([self._color(color)]).described(
                rr.BarChart.descriptor_color())], static=True)
