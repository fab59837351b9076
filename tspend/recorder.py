"""Rerun recorder: a :class:`~tspend.sinks.Sink` that streams a closed-loop run to Rerun.

What is logged (entity paths relative to the sink's ``prefix``):

=============================  ============================================================
``info/scenario``               static: the scenario's TOML text (markdown code block)
``info/run``                    static: seed, package version, plant kind, order, dt, ...
``info/status``, ``info/metrics``  static, at :meth:`RerunSink.finish`: run status, metrics
``events``                      TextLog at the end time when a run does not complete
``series/<group>``              multi-instance ``Scalars`` per block, see :func:`series_specs`
``world/cart``, ``world/pole``  cart-pole geometry (static) and ``Transform3D`` at ~50 Hz
``fuzzy/model/in<j>``           BMF curves (``LineStrips2D``) + operating point (``Points2D``)
``fuzzy/compensator/in<j>``     same for the compensator inputs
``fuzzy/firing``, ...           firing strengths (``BarChart``), consequents (``Tensor``)
=============================  ============================================================

Everything time-dependent lives on the ``sim_time`` duration timeline and is sent with
``send_columns``: one Rerun chunk per entity and per block.  Each chunk costs a fixed
~0.1 ms in the SDK whatever its size, so series that share a plot share an entity
(multi-instance ``Scalars``), and inner snapshots are buffered and sent once per block
instead of row by row (a row-wise ``BarChart`` log alone costs ~0.7 ms).

Rerun's 2D views draw y downwards (rerun-io/rerun#1387), so membership curves are
logged with ``y = -mu``: peaks point up on screen.
"""

from __future__ import annotations

import functools
import json
import math
import os
import shutil
import socket
import sys
import uuid
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, NamedTuple, Sequence
from urllib.parse import urlparse

import numpy as np
import pyarrow as pa
import rerun as rr
import rerun.blueprint as rrb

from .sinks import Block, FuzzyInputInfo, InnerSnapshot, RunEnd, RunInfo

TIMELINE = "sim_time"
#: rate of the 3D cart-pole frames (Hz of simulated time)
FRAME_HZ = 50.0
#: default cart box (x, y, z) in metres
CART_SIZE = (1.0, 0.6, 0.4)
POLE_RADIUS = 0.05
#: pole half-length used when the plant metadata does not give one
DEFAULT_POLE_HALF_LENGTH = 3.0
DEFAULT_VIEWER_PORT = 9876

Color = tuple[int, int, int]

_PALETTE: tuple[Color, ...] = (
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
    (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207),
)


# --------------------------------------------------------------------------- paths


def join_path(prefix: str, path: str) -> str:
    """Entity path ``prefix/path`` with exactly one separator, no leading slash."""
    prefix = prefix.strip("/")
    return f"{prefix}/{path}" if prefix else path


def prefix_label(prefix: str) -> str:
    """Human label of a prefix: ``"mujoco/"`` -> ``"mujoco"``."""
    return prefix.strip("/")


# --------------------------------------------------------------------------- series layout


@dataclass(frozen=True)
class SeriesSpec:
    """One plotted entity: several series packed as instances of one ``Scalars``."""

    entity: str                         # relative to the sink prefix
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
    uses it to send, :func:`series_location` to find a series again.
    """
    n = order
    e_names = tuple(f"e_{i + 1}" for i in range(n))
    p_names = tuple(f"p_{i + 1}" for i in range(n)) + ("b_hat",)
    specs = [
        SeriesSpec("series/tracking", ("r", "x1"), ((150, 150, 150), (31, 119, 180)),
                   _stack(_col("ref", 0), _col("x", 0))),
        SeriesSpec("series/error", e_names + ("e_delta",),
                   _PALETTE[:n] + ((0, 0, 0),), _stack(_col("e"), _col("e_delta"))),
        SeriesSpec("series/control", ("u", "u_s"), ((214, 39, 40), (255, 127, 14)),
                   _stack(_col("u"), _col("u_s"))),
        SeriesSpec("series/compensation", ("d_hat", "d"), ((44, 160, 44), (127, 127, 127)),
                   _stack(_col("d_hat"), _col("d"))),
        SeriesSpec("series/params", p_names,
                   tuple(_PALETTE[i % len(_PALETTE)] for i in range(n)) + ((214, 39, 40),),
                   _stack(_col("p"))),
        SeriesSpec("series/lyapunov", ("V",), ((148, 103, 189),), _stack(_col("V"))),
        SeriesSpec("series/norms", ("norm_P", "norm_q", "min_b"),
                   ((140, 86, 75), (227, 119, 194), (188, 189, 34)),
                   _stack(_col("norm_P"), _col("norm_q"), _col("min_b"))),
    ]
    if extras:
        specs.append(SeriesSpec(
            "series/plant", tuple(extras),
            tuple(_PALETTE[(9 + i) % len(_PALETTE)] for i in range(len(extras))),
            _stack(*[_col(f"extra/{name}") for name in extras])))
    return specs


def series_location(name: str, order: int, extras: Sequence[str] = (),
                    prefix: str = "") -> tuple[str, int]:
    """``(entity, instance)`` where series ``name`` (``"x1"``, ``"u"``, ``"b_hat"``) is logged."""
    for spec in series_specs(order, extras):
        if name in spec.names:
            return join_path(prefix, spec.entity), spec.names.index(name)
    raise KeyError(f"no logged series named {name!r}")


# --------------------------------------------------------------------------- cart-pole geometry


class CartPolePoses(NamedTuple):
    """World poses (z up) of the cart box centre and of the pole's centre of mass."""

    cart_translation: np.ndarray   # (N, 3)
    pole_translation: np.ndarray   # (N, 3), the pole's COM
    pole_quaternion: np.ndarray    # (N, 4), xyzw; rotates local +z onto the pole axis


def cartpole_poses(cart_pos: np.ndarray | float, theta: np.ndarray | float, l: float,
                   cart_height: float = CART_SIZE[2]) -> CartPolePoses:
    """Poses of cart and pole for cart positions ``cart_pos`` and pole angles ``theta``.

    x points right (the cart's rail), z up.  The cart box sits on z = 0; the pole's
    pivot is the centre of the box's top face; the pole (length ``2 l``) points along
    ``(-sin theta, 0, cos theta)``, so ``theta > 0`` leans it toward -x, and its centre
    of mass is ``l`` from the pivot.  Draw the pole as a capsule from local
    ``(0, 0, -l)`` to ``(0, 0, l)``.
    """
    xc = np.atleast_1d(np.asarray(cart_pos, dtype=np.float64))
    th = np.atleast_1d(np.asarray(theta, dtype=np.float64))
    xc, th = np.broadcast_arrays(xc, th)
    zeros = np.zeros_like(th)
    cart = np.column_stack([xc, zeros, np.full_like(th, 0.5 * cart_height)])
    pole = np.column_stack([xc - l * np.sin(th), zeros, cart_height + l * np.cos(th)])
    # rotation by -theta about +y maps +z onto (-sin theta, 0, cos theta)
    half = -0.5 * th
    quat = np.column_stack([zeros, np.sin(half), zeros, np.cos(half)])
    return CartPolePoses(cart, pole, quat)


@dataclass(frozen=True)
class CartPoleGeometry:
    """Sizes and colours of the drawn cart-pole."""

    l: float = DEFAULT_POLE_HALF_LENGTH
    cart_half_sizes: tuple[float, float, float] = (0.5 * CART_SIZE[0], 0.5 * CART_SIZE[1], 0.5 * CART_SIZE[2])
    cart_color: Color = (70, 110, 170)
    pole_radius: float = POLE_RADIUS
    pole_color: Color = (220, 140, 40)


def is_cartpole(info: RunInfo) -> bool:
    """Whether the run's plant is a cart-pole worth drawing in 3D."""
    kind = info.plant_kind.lower().replace("-", "").replace("_", "")
    return info.order == 2 and ("cartpole" in kind or "cart_pos" in info.extras)


def cartpole_geometry(plant_meta: dict) -> CartPoleGeometry:
    """Geometry from the plant metadata; box/capsule sizes from the MJCF when given.

    Reading the MJCF is best effort: any failure keeps the default drawing.
    """
    geom = CartPoleGeometry(l=float(plant_meta.get("l", DEFAULT_POLE_HALF_LENGTH)))
    mjcf = plant_meta.get("mjcf")
    if mjcf:
        geom = _geometry_from_mjcf(str(mjcf), geom)
    return geom


def _geometry_from_mjcf(path: str, base: CartPoleGeometry) -> CartPoleGeometry:
    """First box geom -> cart, first capsule/cylinder geom -> pole radius and colours."""
    try:
        import mujoco

        model = mujoco.MjModel.from_xml_path(path)
    except Exception:  # noqa: BLE001 - drawing must never stop a run
        return base
    cart_half, cart_color = base.cart_half_sizes, base.cart_color
    radius, pole_color = base.pole_radius, base.pole_color
    found_box = found_pole = False
    for g in range(model.ngeom):
        gtype, size, rgba = int(model.geom_type[g]), model.geom_size[g], model.geom_rgba[g]
        color = tuple(int(round(255 * c)) for c in rgba[:3])
        if gtype == mujoco.mjtGeom.mjGEOM_BOX and not found_box:
            cart_half, cart_color, found_box = (float(size[0]), float(size[1]), float(size[2])), color, True
        elif gtype in (mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER) and not found_pole:
            radius, pole_color, found_pole = float(size[0]), color, True
    return CartPoleGeometry(base.l, cart_half, cart_color, radius, pole_color)  # type: ignore[arg-type]


# --------------------------------------------------------------------------- column builders


def _durations(t: np.ndarray | Sequence[float]) -> np.ndarray:
    """Seconds -> ``timedelta64[ns]``, rounded (Rerun's float path truncates 0.003 s to 2999999 ns)."""
    return np.rint(np.asarray(t, dtype=np.float64) * 1e9).astype(np.int64).astype("timedelta64[ns]")


def _time_column(t: np.ndarray | Sequence[float]) -> rr.TimeColumn:
    return rr.TimeColumn(TIMELINE, duration=_durations(t))


def _scalar_column(values: np.ndarray) -> rr.ComponentColumn:
    """A ``Scalars`` column of ``values`` (k, m): k rows of m instances."""
    v = np.ascontiguousarray(values, dtype=np.float64)
    if v.ndim == 1:
        v = v[:, None]
    rows, m = v.shape
    return rr.ComponentColumn(rr.Scalars.descriptor_scalars(), rr.components.ScalarBatch(v.reshape(-1)),
                              offsets=np.arange(0, rows * m + 1, m, dtype=np.int32))


class _ArrowBatch:
    """A ready-made arrow array posing as a component batch (for :class:`rr.ComponentColumn`)."""

    def __init__(self, array: pa.Array, descriptor: rr.ComponentDescriptor) -> None:
        self._array, self._descriptor = array, descriptor

    def as_arrow_array(self) -> pa.Array:
        return self._array

    def component_descriptor(self) -> rr.ComponentDescriptor:
        return self._descriptor


def _arrow_type(batch_cls: type, prototype: object) -> pa.DataType:
    """The SDK's own arrow type of a component batch (generated attribute, else a prototype)."""
    dtype = getattr(batch_cls, "_ARROW_DATATYPE", None)
    return dtype if dtype is not None else batch_cls(prototype).as_arrow_array().type


_EMPTY_UNION_CHILDREN: dict[pa.DataType, list[pa.Array]] = {}


def _union_children(union_type: pa.UnionType) -> list[pa.Array]:
    """Empty arrays for every variant of ``union_type`` (cached: they never change)."""
    if union_type not in _EMPTY_UNION_CHILDREN:
        _EMPTY_UNION_CHILDREN[union_type] = [pa.array([], type=union_type.field(i).type)
                                             for i in range(union_type.num_fields)]
    return _EMPTY_UNION_CHILDREN[union_type]


@functools.lru_cache(maxsize=64)
def _tensor_frame(count: int, shape: tuple[int, ...], names: tuple[str, ...] | None) -> tuple[pa.Array, pa.Array, pa.Buffer, pa.Buffer, pa.Array]:
    """Everything of a ``TensorData`` column but the values: shapes, names, union ids/offsets.

    Cached: a run sends the same count and shape block after block.
    """
    ttype = _arrow_type(rr.components.TensorDataBatch, np.zeros(1))
    ndim, size = len(shape), int(np.prod(shape))
    row_offsets = pa.array(np.arange(0, count * ndim + 1, ndim, dtype=np.int32))
    shape_arr = pa.ListArray.from_arrays(row_offsets, pa.array(np.tile(np.asarray(shape, dtype=np.uint64), count)),
                                         type=ttype.field("shape").type)
    names_type = ttype.field("names").type
    names_arr = pa.nulls(count, type=names_type) if names is None else pa.ListArray.from_arrays(
        row_offsets, pa.array(list(names) * count, type=pa.string()), type=names_type)
    union_type: pa.UnionType = ttype.field("buffer").type
    f64 = [union_type.field(i).name for i in range(union_type.num_fields)].index("F64")
    type_ids = pa.array(np.full(count, union_type.type_codes[f64], dtype=np.int8)).buffers()[1]
    value_offsets = pa.array(np.arange(count, dtype=np.int32)).buffers()[1]
    f64_offsets = pa.array(np.arange(0, count * size + 1, size, dtype=np.int32))
    return shape_arr, names_arr, type_ids, value_offsets, f64_offsets


def _tensor_column(rows: np.ndarray, descriptor: rr.ComponentDescriptor,
                   names: Sequence[str] | None = None) -> rr.ComponentColumn:
    """A column of one f64 tensor per row from ``rows`` (S, *shape).

    Built directly in arrow: the SDK converts each ``TensorData`` in Python
    (~0.4 ms per tensor), which at 50 snapshots per second cost more than the run.
    """
    ttype = _arrow_type(rr.components.TensorDataBatch, np.zeros(1))
    data = np.ascontiguousarray(rows, dtype=np.float64)
    count = data.shape[0]
    shape_arr, names_arr, type_ids, value_offsets, f64_offsets = _tensor_frame(
        count, tuple(int(d) for d in data.shape[1:]), None if names is None else tuple(names))
    union_type: pa.UnionType = ttype.field("buffer").type
    f64 = [union_type.field(i).name for i in range(union_type.num_fields)].index("F64")
    children = list(_union_children(union_type))
    children[f64] = pa.ListArray.from_arrays(f64_offsets, pa.array(data.reshape(-1)), type=union_type.field(f64).type)
    # from_buffers keeps the union's non-nullable child fields (from_dense would drop them)
    buffer_arr = pa.Array.from_buffers(union_type, count, [None, type_ids, value_offsets], children=children)
    struct = pa.StructArray.from_arrays([shape_arr, names_arr, buffer_arr], fields=list(ttype))
    return _column(struct, descriptor, np.arange(count + 1, dtype=np.int32))


def _column(array: pa.Array, descriptor: rr.ComponentDescriptor, offsets: np.ndarray) -> rr.ComponentColumn:
    return rr.ComponentColumn(descriptor, _ArrowBatch(array, descriptor), offsets=offsets)


def _strips_column(strips: np.ndarray, per_row: int) -> rr.ComponentColumn:
    """``LineStrips2D:strips`` from ``strips`` (R, G, 2): ``per_row`` strips per row.

    Built directly in arrow; the SDK's converter loops over strips in Python.
    """
    ltype = _arrow_type(rr.components.LineStrip2DBatch, [[0.0, 0.0]])
    count, points = strips.shape[:2]
    flat = pa.array(np.ascontiguousarray(strips, dtype=np.float32).reshape(-1))
    arr = pa.ListArray.from_arrays(pa.array(np.arange(0, count * points + 1, points, dtype=np.int32)),
                                   pa.FixedSizeListArray.from_arrays(flat, type=ltype.value_type), type=ltype)
    return _column(arr, rr.LineStrips2D.descriptor_strips(),
                   np.arange(0, count + 1, per_row, dtype=np.int32))


def _points_column(points: np.ndarray, per_row: int) -> rr.ComponentColumn:
    """``Points2D:positions`` from ``points`` (R, 2): ``per_row`` points per row."""
    ptype = _arrow_type(rr.components.Position2DBatch, [0.0, 0.0])
    flat = pa.array(np.ascontiguousarray(points, dtype=np.float32).reshape(-1))
    return _column(pa.FixedSizeListArray.from_arrays(flat, type=ptype), rr.Points2D.descriptor_positions(),
                   np.arange(0, points.shape[0] + 1, per_row, dtype=np.int32))


def _snapshot_values(snap: InnerSnapshot) -> list[object]:
    """The snapshot's fields in the fixed order of :meth:`_SnapshotBuffer.keys`."""
    values: list[object] = [snap.t]
    for sets in (snap.model_sets, snap.compensator_sets):
        for grid, curves, z, mu in sets:
            values += (grid, curves, z, mu)
    values += (snap.firing, snap.compensator_firing, snap.consequents, snap.q)
    return values


def _fixed_column(values: np.ndarray, descriptor: rr.ComponentDescriptor, batch_cls: type) -> rr.ComponentColumn:
    """One fixed-size float32 vector per row (translations, quaternions), built directly in arrow."""
    vtype = _arrow_type(batch_cls, np.zeros(values.shape[1]))
    flat = pa.array(np.ascontiguousarray(values, dtype=np.float32).reshape(-1))
    return _column(pa.FixedSizeListArray.from_arrays(flat, type=vtype), descriptor,
                   np.arange(values.shape[0] + 1, dtype=np.int32))


def _pose_columns(translation: np.ndarray, quaternion: np.ndarray | None = None) -> list[rr.ComponentColumn]:
    """``Transform3D`` translation (and rotation) columns; ``Transform3D.columns`` costs ~0.1 ms more."""
    columns = [_fixed_column(translation, rr.Transform3D.descriptor_translation(), rr.components.Translation3DBatch)]
    if quaternion is not None:
        columns.append(_fixed_column(quaternion, rr.Transform3D.descriptor_quaternion(),
                                     rr.components.RotationQuatBatch))
    return columns


class _SnapshotBuffer:
    """Preallocated rows for the snapshots of one block, reused block after block.

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


# --------------------------------------------------------------------------- documents


def _json_default(obj: object) -> object:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return str(obj)


def _fmt(value: object) -> str:
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.6g}"
    if isinstance(value, (dict, list, tuple, np.ndarray)):
        return "`" + json.dumps(value, default=_json_default) + "`"
    return str(value)


def _md_table(rows: Sequence[tuple[str, object]], header: tuple[str, str] = ("key", "value")) -> str:
    lines = [f"| {header[0]} | {header[1]} |", "| --- | --- |"]
    lines += ["| " + str(k) + " | " + _fmt(v).replace("|", r"\|") + " |" for k, v in rows]
    return "\n".join(lines)


def run_markdown(info: RunInfo) -> str:
    """Markdown summary of the run's identity."""
    rows: list[tuple[str, object]] = [
        ("scenario", info.scenario_name), ("scenario file", info.scenario_path),
        ("seed", info.seed), ("tspend version", info.version), ("plant kind", info.plant_kind),
        ("order n", info.order), ("dt (s)", info.dt), ("duration (s)", info.duration),
        ("steps", info.steps),
        ("model inputs", ", ".join(i.name for i in info.model_inputs)),
        ("compensator inputs", ", ".join(i.name for i in info.compensator_inputs)),
        ("plant extras", ", ".join(info.extras)),
    ]
    rows += [(f"plant: {k}", v) for k, v in info.plant_meta.items()]
    return f"# Run: {info.scenario_name}\n\n" + _md_table(rows)


def scenario_markdown(info: RunInfo) -> str:
    return f"# Scenario `{info.scenario_name}`\n\n`{info.scenario_path}`\n\n```toml\n{info.scenario_text}\n```\n"


def status_markdown(end: RunEnd) -> str:
    return (f"# Run {end.status}\n\n"
            + _md_table([("status", end.status), ("message", end.message), ("steps done", end.steps_done)]))


def metrics_markdown(metrics: dict) -> str:
    """Metrics as a markdown table plus the exact JSON."""
    body = json.dumps(metrics, indent=2, sort_keys=True, default=_json_default)
    return (f"# Metrics\n\n{_md_table(sorted(metrics.items()), ('metric', 'value'))}\n\n"
            f"```json\n{body}\n```\n")


# --------------------------------------------------------------------------- blueprint


def _abs(prefix: str, path: str) -> str:
    return "/" + join_path(prefix, path)


_TIME_SERIES_VIEWS: tuple[tuple[str, str], ...] = (
    ("reference and output", "series/tracking"),
    ("error and e_delta", "series/error"),
    ("control u and u_s", "series/control"),
    ("d_hat and disturbance d", "series/compensation"),
    ("estimated p_k and b_hat", "series/params"),
    ("Lyapunov V", "series/lyapunov"),
    ("parameter norms", "series/norms"),
)


def _fuzzy_views(info: RunInfo, prefix: str, suffix: str) -> tuple[list[rrb.View], list[rrb.View]]:
    """(membership-curve views, firing/consequent views) of one run."""
    bmf: list[rrb.View] = []
    for group, inputs in (("model", info.model_inputs), ("compensator", info.compensator_inputs)):
        for j, inp in enumerate(inputs):
            pad = 0.05 * (inp.hi - inp.lo)
            bmf.append(rrb.Spatial2DView(
                origin=_abs(prefix, f"fuzzy/{group}/in{j}"), name=f"BMF {group} {inp.name}{suffix}",
                visual_bounds=rrb.VisualBounds2D(x_range=[inp.lo - pad, inp.hi + pad], y_range=[-1.1, 0.1])))
    firing: list[rrb.View] = [
        rrb.BarChartView(origin=_abs(prefix, "fuzzy/firing"), name=f"rule firing w{suffix}"),
        rrb.BarChartView(origin=_abs(prefix, "fuzzy/compensator_firing"), name=f"compensator firing tau{suffix}"),
        rrb.TensorView(origin=_abs(prefix, "fuzzy/consequents"), name=f"consequents p_k^i{suffix}"),
        rrb.BarChartView(origin=_abs(prefix, "fuzzy/q"), name=f"compensator consequents q{suffix}"),
    ]
    return bmf, firing


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
        rrb.TimeSeriesView(origin="/", contents=[_abs(p, path) for p in prefixes], name=name)
        for name, path in _TIME_SERIES_VIEWS
    ]
    if info.extras:
        series_views.append(rrb.TimeSeriesView(
            origin="/", contents=[_abs(p, "series/plant") for p in prefixes], name="plant extras"))
    bmf_views: list[rrb.View] = []
    firing_views: list[rrb.View] = []
    doc_views: list[rrb.View] = []
    for p, sfx in zip(prefixes, suffixes):
        bmf, firing = _fuzzy_views(info, p, sfx)
        bmf_views += bmf
        firing_views += firing
        doc_views += [rrb.TextDocumentView(origin=_abs(p, f"info/{doc}"), name=f"{doc}{sfx}")
                      for doc in ("status", "metrics", "run", "scenario")]
    tabs = rrb.Tabs(
        rrb.Grid(*bmf_views, name="membership functions"),
        rrb.Grid(*firing_views, name="firing and consequents"),
        rrb.Tabs(*doc_views, name="run info"),
    )
    left: list[rrb.Container | rrb.View] = []
    if is_cartpole(info) if cartpole is None else cartpole:
        views3d = [rrb.Spatial3DView(origin=_abs(p, "world"), name=f"cart-pole{sfx}")
                   for p, sfx in zip(prefixes, suffixes)]
        left.append(rrb.Horizontal(*views3d) if multi else views3d[0])
    left.append(tabs)
    root = rrb.Horizontal(
        rrb.Vertical(*left),
        rrb.Grid(*series_views, grid_columns=2),
        column_shares=[2, 3],
    )
    return rrb.Blueprint(root, collapse_panels=False)


# --------------------------------------------------------------------------- the sink


def _lighten(color: Color, amount: float) -> Color:
    return tuple(int(round(c + (255 - c) * amount)) for c in color)  # type: ignore[return-value]


class RerunSink:
    """Streams a run into a caller-created :class:`rerun.RecordingStream`.

    ``prefix`` puts every entity under ``prefix/`` so several runs can share one
    recording; ``label`` (default: the prefix) is appended to series names and
    ``variant`` 1 lightens the colours, so overlaid runs stay distinguishable.
    ``curves_every`` decimates the per-step series (1 = every step, exact);
    ``frame_hz`` is the rate of 3D frames.  With ``send_blueprint`` the sink sends
    :func:`build_blueprint` for its own run at :meth:`start` (turn it off when several
    sinks share a recording and send ``build_blueprint(info, prefixes)`` yourself).

    Nothing accumulates across blocks: each block is sent as it comes, and inner
    snapshots are buffered only until the next block (or :meth:`finish`).
    """

    def __init__(self, rec: rr.RecordingStream, *, prefix: str = "", label: str | None = None,
                 curves_every: int = 1, frame_hz: float = FRAME_HZ, send_blueprint: bool = True,
                 variant: int = 0) -> None:
        if curves_every < 1:
            raise ValueError("curves_every must be >= 1")
        self.rec = rec
        self.prefix = prefix.strip("/")
        self.label = prefix_label(prefix) if label is None else label
        self.curves_every = int(curves_every)
        self.frame_hz = float(frame_hz)
        self.send_blueprint = send_blueprint
        self.variant = int(variant)
        self.info: RunInfo | None = None
        self._specs: list[SeriesSpec] = []
        self._frame_every = 1
        self._geometry: CartPoleGeometry | None = None
        self._snaps = _SnapshotBuffer()
        self._sent_curves: dict[str, np.ndarray] = {}
        self._last_t = 0.0
        self._finished = False

    # -- helpers

    def _path(self, path: str) -> str:
        return join_path(self.prefix, path)

    def _color(self, color: Color) -> Color:
        return _lighten(color, 0.45) if self.variant else color

    def _series_name(self, name: str) -> str:
        return f"{name} [{self.label}]" if self.label else name

    def _send(self, path: str, times: rr.TimeColumn, columns: Sequence[rr.ComponentColumn] | rr.ComponentColumnList) -> None:
        self.rec.send_columns(self._path(path), indexes=[times], columns=columns)

    # -- Sink protocol

    def start(self, info: RunInfo) -> None:
        """Static documents, series styles, static geometry and the blueprint."""
        self.info = info
        self._finished = False
        self._snaps = _SnapshotBuffer()
        self._sent_curves = {}
        self._specs = series_specs(info.order, info.extras)
        self._frame_every = max(1, int(round(1.0 / (self.frame_hz * info.dt)))) if info.dt > 0 else 1
        self._log_documents(info)
        for spec in self._specs:
            self.rec.log(self._path(spec.entity), rr.SeriesLines(
                names=[self._series_name(n) for n in spec.names],
                colors=[self._color(c) for c in spec.colors]), static=True)
        self._log_fuzzy_styles(info)
        if is_cartpole(info):
            self._geometry = cartpole_geometry(info.plant_meta)
            self._log_cartpole_geometry(self._geometry)
        else:
            self._geometry = None
        if self.send_blueprint:
            self.rec.send_blueprint(build_blueprint(info, [self.prefix]))
        if not self.prefix:
            self.rec.send_recording_name(info.scenario_name)

    def block(self, block: Block) -> None:
        """Send one block: series, 3D frames, and the snapshots buffered so far."""
        data = block.data
        t = np.asarray(data["t"], dtype=np.float64)
        if t.size:
            self._last_t = float(t[-1])
            self._send_series(block.start, data, t)
            if self._geometry is not None:
                self._send_frames(block.start, data, t)
        self._flush_snapshots()

    def inner(self, snap: InnerSnapshot) -> None:
        """Buffer a snapshot (copied: the runner may reuse its arrays)."""
        self._snaps.append(snap)
        self._last_t = max(self._last_t, float(snap.t))

    def finish(self, end: RunEnd) -> None:
        """Send what is pending, the status and metrics documents, and flush to the sink."""
        self._flush_snapshots()
        self.rec.log(self._path("info/status"), rr.TextDocument(status_markdown(end), media_type=rr.MediaType.MARKDOWN),
                     static=True)
        self.rec.log(self._path("info/metrics"),
                     rr.TextDocument(metrics_markdown(end.metrics), media_type=rr.MediaType.MARKDOWN), static=True)
        if end.status != "completed":
            level = "WARN" if end.status == "interrupted" else "ERROR"
            self.rec.send_columns(self._path("events"), indexes=[_time_column([self._last_t])],
                                  columns=rr.TextLog.columns(text=[f"{end.status}: {end.message}"], level=[level]))
        self._finished = True
        self.rec.flush()

    def close(self) -> None:
        """Flush and close the recording's sinks (finalises the ``.rrd`` footer).

        Call once, after every sink sharing the recording has finished.
        """
        close_recording(self.rec)

    # -- block parts

    def _send_series(self, start: int, data: dict[str, np.ndarray], t: np.ndarray) -> None:
        rows = slice((-start) % self.curves_every, None, self.curves_every)
        times = _time_column(t[rows])
        for spec in self._specs:
            try:
                values = spec.extract(data)
            except KeyError:
                continue  # e.g. an extra the plant did not report in this block
            self._send(spec.entity, times, [_scalar_column(values[rows])])

    def _send_frames(self, start: int, data: dict[str, np.ndarray], t: np.ndarray) -> None:
        assert self._geometry is not None
        rows = slice((-start) % self._frame_every, None, self._frame_every)
        theta = np.asarray(data["x"])[rows, 0]
        if theta.size == 0:
            return
        cart = data.get("extra/cart_pos")
        cart_pos = np.zeros_like(theta) if cart is None else np.asarray(cart)[rows]
        poses = cartpole_poses(cart_pos, theta, self._geometry.l, 2.0 * self._geometry.cart_half_sizes[2])
        times = _time_column(t[rows])
        self._send("world/cart", times, _pose_columns(poses.cart_translation))
        self._send("world/pole", times, _pose_columns(poses.pole_translation, poses.pole_quaternion))

    def _flush_snapshots(self) -> None:
        buf = self._snaps
        if not buf.count:
            return
        times = _time_column(buf.get("t"))
        for group in ("model", "compensator"):
            for key in buf.inputs(group):
                self._send_membership(key, buf, times)
        bar = rr.BarChart.descriptor_values()
        for name in ("firing", "compensator_firing", "q"):
            self._send(f"fuzzy/{name}", times, [_tensor_column(buf.get(name), bar)])
        self._send("fuzzy/consequents", times,
                   [_tensor_column(buf.get("consequents"), rr.Tensor.descriptor_data(), names=("rule", "k"))])
        buf.clear()

    def _send_membership(self, key: str, buf: _SnapshotBuffer, times: rr.TimeColumn) -> None:
        """Operating points at every snapshot; curves only when they changed since last sent.

        Fixed membership functions are then sent once, which keeps the file small.
        """
        grid, curves = buf.get(f"{key}/grid"), buf.get(f"{key}/curves")
        count, terms, points = curves.shape
        marks = np.empty((count, terms, 2))
        marks[..., 0] = buf.get(f"{key}/z")[:, None]
        marks[..., 1] = -buf.get(f"{key}/mu")                # y down on screen: log -mu
        self._send(f"fuzzy/{key}", times, [_points_column(marks.reshape(-1, 2), terms)])
        shape = np.concatenate([curves, grid[:, None, :]], axis=1)   # (S, T+1, G): what is drawn
        previous = self._sent_curves.get(key)
        changed = np.empty(count, dtype=bool)
        changed[0] = previous is None or previous.shape != shape[0].shape or not np.array_equal(previous, shape[0])
        changed[1:] = np.any(shape[1:] != shape[:-1], axis=(1, 2))
        if not changed.any():
            return
        self._sent_curves[key] = shape[-1].copy()
        rows = np.flatnonzero(changed)
        strips = np.empty((rows.size, terms, points, 2))
        strips[..., 0] = grid[rows][:, None, :]
        strips[..., 1] = -curves[rows]
        self._send(f"fuzzy/{key}", _time_column(buf.get("t")[rows]),
                   [_strips_column(strips.reshape(-1, points, 2), terms)])

    # -- static parts

    def _log_documents(self, info: RunInfo) -> None:
        md = rr.MediaType.MARKDOWN
        self.rec.log(self._path("info/scenario"), rr.TextDocument(scenario_markdown(info), media_type=md), static=True)
        self.rec.log(self._path("info/run"), rr.TextDocument(run_markdown(info), media_type=md), static=True)

    def _log_fuzzy_styles(self, info: RunInfo) -> None:
        for group, inputs in (("model", info.model_inputs), ("compensator", info.compensator_inputs)):
            for j, inp in enumerate(inputs):
                colors = [self._color(_PALETTE[k % len(_PALETTE)]) for k in range(len(inp.terms))]
                self.rec.log(self._path(f"fuzzy/{group}/in{j}"),
                             rr.LineStrips2D.from_fields(colors=colors, labels=list(inp.terms), radii=[-1.5]),
                             rr.Points2D.from_fields(colors=colors, radii=[-5.0]), static=True)
        for path, color in (("fuzzy/firing", (31, 119, 180)), ("fuzzy/compensator_firing", (44, 160, 44)),
                            ("fuzzy/q", (255, 127, 14))):
            # BarChart.from_fields(color=...) trips over its own values converter in 0.41
            self.rec.log(self._path(path), [rr.components.ColorBatch([self._color(color)]).described(
                rr.BarChart.descriptor_color())], static=True)

    def _log_cartpole_geometry(self, geom: CartPoleGeometry) -> None:
        self.rec.log(self._path("world"), rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self.rec.log(self._path("world/cart"), rr.Boxes3D(
            half_sizes=[geom.cart_half_sizes], colors=[self._color(geom.cart_color)],
            fill_mode=rr.components.FillMode.Solid), static=True)
        self.rec.log(self._path("world/pole"), rr.Capsules3D(
            lengths=[2.0 * geom.l], radii=[geom.pole_radius], translations=[[0.0, 0.0, -geom.l]],
            colors=[self._color(geom.pole_color)]), static=True)
        # initial pose so the scene is drawn before the first block arrives
        poses = cartpole_poses(0.0, 0.0, geom.l, 2.0 * geom.cart_half_sizes[2])
        times = _time_column([0.0])
        self._send("world/cart", times, _pose_columns(poses.cart_translation))
        self._send("world/pole", times, _pose_columns(poses.pole_translation, poses.pole_quaternion))


# --------------------------------------------------------------------------- recordings


def _warn(message: str) -> None:
    print(f"tspend: warning: {message}", file=sys.stderr)


def _viewer_executable() -> str | None:
    """``rerun`` on PATH, else the one installed beside this interpreter (an unactivated venv)."""
    found = shutil.which("rerun")
    if found:
        return found
    sibling = Path(sys.executable).parent / ("rerun.exe" if os.name == "nt" else "rerun")
    return str(sibling) if sibling.exists() else None


def _port_open(host: str, port: int, timeout: float = 1.0) -> bool:
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return True
    except OSError:
        return False


def _grpc_endpoint(url: str | None) -> tuple[str, int]:
    parsed = urlparse(url or f"rerun+http://127.0.0.1:{DEFAULT_VIEWER_PORT}/proxy")
    default = 443 if parsed.scheme.endswith("https") else DEFAULT_VIEWER_PORT
    return parsed.hostname or "127.0.0.1", parsed.port or default


def _fallback(rec: rr.RecordingStream, path: str | os.PathLike[str] | None, why: str) -> rr.RecordingStream | None:
    """After a viewer failure: save to ``path`` if given, else record nothing."""
    if path is not None:
        _warn(f"{why}; saving the recording to {path} instead")
        _save(rec, path)
        return rec
    _warn(f"{why}; recording nothing")
    return None


def _save(rec: rr.RecordingStream, path: str | os.PathLike[str]) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    rec.save(path)


def open_recording(app_id: str, mode: str, path: str | os.PathLike[str] | None = None,
                   url: str | None = None, *, recording_id: str | None = None,
                   port: int = DEFAULT_VIEWER_PORT) -> rr.RecordingStream | None:
    """A new recording stream (never the global one) with its sink attached.

    ``mode``: ``"save"`` streams to the ``.rrd`` at ``path`` (memory stays flat);
    ``"spawn"`` starts a viewer on ``port``; ``"connect"`` connects to ``url``
    (default ``rerun+http://127.0.0.1:9876/proxy``); ``"none"`` returns ``None`` (record
    nothing: don't add a sink).  When no viewer can be reached, a one-line warning goes
    to stderr and the recording is saved to ``path`` if given, else ``None`` is returned.
    """
    if mode == "none":
        return None
    rec = rr.RecordingStream(app_id, recording_id=recording_id or uuid.uuid4())
    if mode == "save":
        if path is None:
            raise ValueError("mode 'save' needs a path")
        _save(rec, path)
        return rec
    if mode == "spawn":
        return _spawn(rec, path, port)
    if mode == "connect":
        host, grpc_port = _grpc_endpoint(url)
        if not _port_open(host, grpc_port):
            return _fallback(rec, path, f"no Rerun viewer at {url or f'{host}:{grpc_port}'}")
        rec.connect_grpc(url)
        return rec
    raise ValueError(f"unknown recording mode {mode!r} (save, spawn, connect, none)")


def _spawn(rec: rr.RecordingStream, path: str | os.PathLike[str] | None, port: int) -> rr.RecordingStream | None:
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        # the viewer would start, fail to open a window, and leave us waiting ~10 s
        return _fallback(rec, path, "no display for the Rerun viewer")
    exe = _viewer_executable()
    if exe is None:
        return _fallback(rec, path, "Rerun viewer executable not found")
    try:
        rr.spawn(port=port, connect=False, executable_path=exe, recording=rec)
    except Exception as exc:  # noqa: BLE001 - any failure means: no viewer
        return _fallback(rec, path, f"cannot start the Rerun viewer ({str(exc).splitlines()[0]})")
    if not _port_open("127.0.0.1", port, timeout=2.0):
        return _fallback(rec, path, f"the Rerun viewer did not come up on port {port}")
    rec.connect_grpc(f"rerun+http://127.0.0.1:{port}/proxy")
    return rec


def close_recording(rec: rr.RecordingStream) -> None:
    """Flush and close every sink of ``rec`` (writes the ``.rrd`` footer)."""
    rec.flush()
    rec.disconnect()


# --------------------------------------------------------------------------- reading back


def read_scalar_series(path: str | os.PathLike[str], entity: str,
                       instance: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(t, values)`` of the ``Scalars`` logged at ``entity`` in the ``.rrd`` at ``path``.

    ``t`` is ``sim_time`` in seconds (sorted); ``values`` is (N,) for single-instance
    entities or when ``instance`` is given, else (N, m).  Works on files without a
    footer (a crashed writer), since it streams the chunks.
    """
    from rerun.chunk import RrdReader

    target = "/" + entity.strip("/")
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*no footer.*")
        reader = RrdReader(path)
        chunks = reader.stream().filter(content=target, is_static=False,
                                        components="Scalars:scalars").to_chunks()
    times: list[np.ndarray] = []
    rows: list[np.ndarray] = []
    width: int | None = None
    for chunk in chunks:
        if chunk.entity_path != target or TIMELINE not in chunk.timeline_names:
            continue
        batch = chunk.to_record_batch()
        col = batch.column(batch.schema.get_field_index("Scalars:scalars"))
        offsets = np.asarray(col.offsets)
        lengths = np.diff(offsets)
        if lengths.size == 0:
            continue
        if width is None:
            width = int(lengths[0])
        if np.any(lengths != width):
            raise ValueError(f"{entity}: rows with differing instance counts")
        flat = np.asarray(col.values.to_numpy(zero_copy_only=False), dtype=np.float64)
        rows.append(flat[offsets[0]:offsets[-1]].reshape(-1, width))
        tcol = batch.column(batch.schema.get_field_index(TIMELINE))
        times.append(np.asarray(tcol.cast(pa.int64()).to_numpy(), dtype=np.int64))
    if width is None:
        raise KeyError(f"no scalar series at {entity!r} in {path}")
    t_ns = np.concatenate(times)
    values = np.concatenate(rows)
    order = np.argsort(t_ns, kind="stable")
    t_s, values = t_ns[order] * 1e-9, values[order]
    if instance is not None:
        return t_s, values[:, instance]
    return t_s, (values[:, 0] if width == 1 else values)
