"""Rerun recorder: a :class:`~tspend.sinks.Sink` that streams a closed-loop run to Rerun.

What is logged (entity paths relative to the sink's ``prefix``):

- ``info/scenario``, ``info/run``: static markdown at start: the scenario's TOML, seed,
  package version, plant kind, order, dt, ...
- ``info/status``, ``info/metrics``: static markdown at :meth:`RerunSink.finish`
- ``events``: a ``TextLog`` at the last time when a run does not complete
- ``series/<group>``: multi-instance ``Scalars``, see :func:`series_specs`
- ``world/cart``, ``world/pole``: static ``Boxes3D`` / ``Capsules3D`` and a
  ``Transform3D`` per body at ~50 Hz (cart-poles only)
- ``fuzzy/model/in<j>``, ``fuzzy/compensator/in<j>``: membership curves
  (``LineStrips2D``, one strip per term) and the operating point (``Points2D``)
- ``fuzzy/firing``, ``fuzzy/compensator_firing``, ``fuzzy/q``: ``BarChart``;
  ``fuzzy/consequents``: ``Tensor`` (rule x k)

Everything time-dependent lives on the ``sim_time`` duration timeline and is sent in
columns, never row by row.  Rerun turns each entity's columns into a chunk, and a chunk
costs a fixed ~50 us to convert plus ~50 us of Python around ``send_columns``, whatever
its size.  So: series that share a plot share an entity (multi-instance ``Scalars``);
all entities of a block go out as one arrow record batch (``send_record_batch``, ~20-40 us
per chunk); 3D frames and inner snapshots (50 Hz) are batched ``DECIMATED_ROWS`` at a
time; membership curves are only re-sent when they change; ``TensorData`` columns are
built directly in arrow (the SDK converts each tensor in Python, ~0.4 ms apiece).

Rerun's 2D views draw y downwards (rerun-io/rerun#1387), so membership curves are
logged with ``y = -mu``: peaks point up on screen.
"""

from __future__ import annotations

import functools
import json
import os
import shutil
import socket
import sys
import time
import uuid
import warnings
import weakref
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Iterable, Literal, NamedTuple, Sequence
from urllib.parse import urlparse

import numpy as np
import pyarrow as pa
import rerun as rr
import rerun.blueprint as rrb

from .sinks import Block, InnerSnapshot, RunEnd, RunInfo

TIMELINE = "sim_time"
#: rate of the 3D cart-pole frames (Hz of simulated time)
FRAME_HZ = 50.0
#: default cart box (x, y, z) in metres
CART_SIZE = (1.0, 0.6, 0.4)
POLE_RADIUS = 0.05
#: pole half-length used when the plant metadata does not give one
DEFAULT_POLE_HALF_LENGTH = 3.0
DEFAULT_VIEWER_PORT = 9876
#: 3D frames and inner snapshots are sent in batches of this many rows (2 s at 50 Hz) ...
DECIMATED_ROWS = 100
#: ... or after this much wall time, so a live viewer stays current
MAX_LATENCY_S = 0.5
#: longest wait for data to reach the sink at finish/close
FLUSH_TIMEOUT_S = 30.0

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
    """Cart = the box on the slider's body; pole = the longest capsule/cylinder on the hinge's body.

    Colours as MuJoCo renders them (the material's when the geom keeps the default rgba).
    """
    try:
        import mujoco

        model = mujoco.MjModel.from_xml_path(path)
    except Exception:  # noqa: BLE001 - drawing must never stop a run
        return base

    def body_of(joint_type: int) -> int | None:
        found = [int(model.jnt_bodyid[j]) for j in range(model.njnt) if int(model.jnt_type[j]) == joint_type]
        return found[0] if found else None

    def color(g: int) -> Color:
        rgba = model.geom_rgba[g]
        if int(model.geom_matid[g]) >= 0 and np.allclose(rgba, (0.5, 0.5, 0.5, 1.0)):
            rgba = model.mat_rgba[int(model.geom_matid[g])]
        return tuple(int(round(255 * c)) for c in rgba[:3])  # type: ignore[return-value]

    cart_body, pole_body = body_of(mujoco.mjtJoint.mjJNT_SLIDE), body_of(mujoco.mjtJoint.mjJNT_HINGE)
    geoms = range(model.ngeom)
    boxes = [g for g in geoms if int(model.geom_bodyid[g]) == cart_body
             and int(model.geom_type[g]) == mujoco.mjtGeom.mjGEOM_BOX]
    rods = [g for g in geoms if int(model.geom_bodyid[g]) == pole_body
            and int(model.geom_type[g]) in (mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER)]
    geom = base
    if boxes:
        size = model.geom_size[boxes[0]]
        geom = replace(geom, cart_half_sizes=(float(size[0]), float(size[1]), float(size[2])),
                       cart_color=color(boxes[0]))
    if rods:
        rod = max(rods, key=lambda g: float(model.geom_size[g][1]))
        geom = replace(geom, pole_radius=float(model.geom_size[rod][0]), pole_color=color(rod))
    return geom


# --------------------------------------------------------------------------- column builders


def _durations(t: np.ndarray | Sequence[float]) -> np.ndarray:
    """Seconds -> ``timedelta64[ns]``, rounded (Rerun's float path truncates 0.003 s to 2999999 ns)."""
    return np.rint(np.asarray(t, dtype=np.float64) * 1e9).astype(np.int64).astype("timedelta64[ns]")


def _time_column(t: np.ndarray | Sequence[float]) -> rr.TimeColumn:
    return rr.TimeColumn(TIMELINE, duration=_durations(t))


_SCALARS = rr.Scalars.descriptor_scalars()


_FIELDS: dict[tuple[str, str], pa.Field] = {}


def _component_field(entity: str, desc: rr.ComponentDescriptor, dtype: pa.DataType) -> pa.Field:
    """The arrow field of a component column, tagged with Rerun's metadata.

    Cached by (entity, component): the same few fields recur block after block, and a
    component's arrow type never changes.
    """
    key = (entity, desc.component)
    found = _FIELDS.get(key)
    if found is None:
        path = "/" + entity.strip("/")
        meta = {"rerun:kind": "data", "rerun:entity_path": path, "rerun:component": desc.component}
        if desc.archetype:
            meta["rerun:archetype"] = desc.archetype
        if desc.component_type:
            meta["rerun:component_type"] = desc.component_type
        found = _FIELDS[key] = pa.field(f"{path}:{desc.component}", dtype, metadata=meta)
    return found


class _RowBatch:
    """Columns of several entities over the same ``sim_time`` rows, sent as one arrow record batch.

    Rerun splits it into one chunk per entity.  Converting one record batch costs ~20 us
    per chunk against ~100 us per ``send_columns`` call, and a block has ~20 chunks.
    """

    def __init__(self, t: np.ndarray | Sequence[float]) -> None:
        times = pa.array(_durations(t))
        self._fields = [pa.field(TIMELINE, times.type, nullable=False)]
        self._arrays: list[pa.Array] = [times]

    def add(self, entity: str, columns: Iterable[rr.ComponentColumn]) -> None:
        """Add ``columns`` (one row per time) of ``entity`` (absolute, no leading slash needed)."""
        for column in columns:
            self.add_array(entity, column.component_descriptor(), column.as_arrow_array())

    def add_array(self, entity: str, desc: rr.ComponentDescriptor, array: pa.Array) -> None:
        """Add a list array (one component batch per row) of ``entity``."""
        self._fields.append(_component_field(entity, desc, array.type))
        self._arrays.append(array)

    def add_scalars(self, entity: str, values: np.ndarray) -> None:
        """``Scalars`` of ``entity`` from ``values`` (rows, m): m instances per row."""
        v = np.ascontiguousarray(values, dtype=np.float64)
        rows, m = v.shape
        self.add_array(entity, _SCALARS, pa.ListArray.from_arrays(
            pa.array(np.arange(0, rows * m + 1, m, dtype=np.int32)), pa.array(v.reshape(-1))))

    def send(self, rec: rr.RecordingStream) -> None:
        if len(self._arrays) > 1:
            rec.send_record_batch(pa.RecordBatch.from_arrays(self._arrays, schema=pa.schema(self._fields)),
                                  index=TIMELINE)


class _StaticBatch:
    """Static archetypes of several entities, sent as one record batch of one row.

    One call instead of ~25 ``log(..., static=True)`` calls at ~0.15 ms each.
    """

    def __init__(self) -> None:
        self._fields: list[pa.Field] = []
        self._arrays: list[pa.Array] = []

    def add(self, entity: str, *parts: object) -> None:
        """Add archetypes (or lists of described component batches) of ``entity``."""
        for part in parts:
            batches = part.as_component_batches() if hasattr(part, "as_component_batches") else part
            for batch in batches:  # type: ignore[union-attr]
                values = batch.as_arrow_array()
                array = pa.ListArray.from_arrays(pa.array([0, len(values)], type=pa.int32()), values)
                self._fields.append(_component_field(entity, batch.component_descriptor(), array.type))
                self._arrays.append(array)

    def send(self, rec: rr.RecordingStream) -> None:
        if self._arrays:
            rec.send_record_batch(pa.RecordBatch.from_arrays(self._arrays, schema=pa.schema(self._fields)),
                                  index=None)


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


class _TensorLayout(NamedTuple):
    """What every ``TensorData`` column shares; computed once (hashing arrow types is slow)."""

    type: pa.StructType
    union: pa.UnionType
    variant: int                    # index of the F32 variant: tensors are only drawn
    empty_children: list[pa.Array]  # an empty array per variant


@functools.cache
def _tensor_layout() -> _TensorLayout:
    ttype = _arrow_type(rr.components.TensorDataBatch, np.zeros(1))
    union: pa.UnionType = ttype.field("buffer").type
    names = [union.field(i).name for i in range(union.num_fields)]
    return _TensorLayout(ttype, union, names.index("F32"),
                         [pa.array([], type=union.field(i).type) for i in range(union.num_fields)])


@functools.lru_cache(maxsize=64)
def _tensor_frame(count: int, shape: tuple[int, ...],
                  names: tuple[str, ...] | None) -> tuple[pa.Array, pa.Array, pa.Buffer, pa.Buffer, pa.Array]:
    """Everything of a ``TensorData`` column but the values: shapes, names, union ids/offsets.

    Cached: a run sends the same count and shape batch after batch.
    """
    layout = _tensor_layout()
    ndim, size = len(shape), int(np.prod(shape))
    row_offsets = pa.array(np.arange(0, count * ndim + 1, ndim, dtype=np.int32))
    shape_arr = pa.ListArray.from_arrays(row_offsets, pa.array(np.tile(np.asarray(shape, dtype=np.uint64), count)),
                                         type=layout.type.field("shape").type)
    names_type = layout.type.field("names").type
    names_arr = pa.nulls(count, type=names_type) if names is None else pa.ListArray.from_arrays(
        row_offsets, pa.array(list(names) * count, type=pa.string()), type=names_type)
    type_ids = pa.array(np.full(count, layout.union.type_codes[layout.variant], dtype=np.int8)).buffers()[1]
    value_offsets = pa.array(np.arange(count, dtype=np.int32)).buffers()[1]
    data_offsets = pa.array(np.arange(0, count * size + 1, size, dtype=np.int32))
    return shape_arr, names_arr, type_ids, value_offsets, data_offsets


def _tensor_column(rows: np.ndarray, descriptor: rr.ComponentDescriptor,
                   names: Sequence[str] | None = None) -> rr.ComponentColumn:
    """A column of one float32 tensor per row from ``rows`` (S, *shape).

    Built directly in arrow: the SDK converts each ``TensorData`` in Python
    (~0.4 ms per tensor), which at 50 snapshots per second cost more than the run.
    float32 halves the largest part of the file; these tensors are for looking at.
    """
    layout = _tensor_layout()
    data = np.ascontiguousarray(rows, dtype=np.float32)
    count = data.shape[0]
    shape_arr, names_arr, type_ids, value_offsets, data_offsets = _tensor_frame(
        count, tuple(int(d) for d in data.shape[1:]), None if names is None else tuple(names))
    children = list(layout.empty_children)
    children[layout.variant] = pa.ListArray.from_arrays(data_offsets, pa.array(data.reshape(-1)),
                                                        type=layout.union.field(layout.variant).type)
    # from_buffers keeps the union's non-nullable child fields (from_dense would drop them)
    buffer_arr = pa.Array.from_buffers(layout.union, count, [None, type_ids, value_offsets], children=children)
    struct = pa.StructArray.from_arrays([shape_arr, names_arr, buffer_arr], fields=list(layout.type))
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
        doc_views.append(rrb.TextLogView(origin=_abs(p, "events"), name=f"events{sfx}"))
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
    ``frame_hz`` is the rate of 3D frames; ``decimated_rows`` and ``max_latency_s``
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
                 blueprint_prefixes: Sequence[str] | Literal["own"] | None = "own",
                 variant: int | None = None, decimated_rows: int = DECIMATED_ROWS,
                 max_latency_s: float = MAX_LATENCY_S) -> None:
        if curves_every < 1:
            raise ValueError("curves_every must be >= 1")
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
        self._geometry: CartPoleGeometry | None = None
        self._snaps = _SnapshotBuffer()
        self._sent_curves: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._frames: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []   # (t, cart_pos, theta)
        self._frame_rows = 0
        self._last_flush = time.monotonic()
        self._last_t = 0.0

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
        self._frames, self._frame_rows = [], 0
        self._last_flush, self._last_t = time.monotonic(), 0.0
        self._specs = series_specs(info.order, info.extras)
        self._frame_every = max(1, int(round(1.0 / (self.frame_hz * info.dt)))) if info.dt > 0 else 1
        statics = _StaticBatch()
        self._log_documents(statics, info)
        for spec in self._specs:
            statics.add(self._path(spec.entity), rr.SeriesLines(
                names=[self._series_name(n) for n in spec.names], colors=[self._color(c) for c in spec.colors]))
        self._log_fuzzy_styles(statics, info)
        self._geometry = cartpole_geometry(info.plant_meta) if is_cartpole(info) else None
        if self._geometry is not None:
            self._log_cartpole_geometry(statics, self._geometry)
        statics.send(self.rec)
        if self._geometry is not None:
            self._send_poses([0.0], np.zeros(1), np.zeros(1))  # drawn before the first block arrives
        if self.blueprint_prefixes is not None:
            self.rec.send_blueprint(build_blueprint(info, self.blueprint_prefixes))
        if not self.prefix:
            self.rec.send_recording_name(info.scenario_name)

    def block(self, block: Block) -> None:
        """Send the block's series; buffer its 3D frames; send decimated data when due."""
        if self.rec is None or self.info is None:
            return
        data = block.data
        t = np.asarray(data["t"], dtype=np.float64)
        if t.size:
            self._last_t = float(t[-1])
            self._send_series(block.start, data, t)
            if self._geometry is not None:
                self._buffer_frames(block.start, data, t)
        if self._decimated_due():
            self._flush_decimated()

    def inner(self, snap: InnerSnapshot) -> None:
        """Buffer a snapshot (copied: the runner may reuse its arrays)."""
        if self.rec is None:
            return
        self._snaps.append(snap)
        self._last_t = max(self._last_t, float(snap.t))

    def finish(self, end: RunEnd) -> None:
        """Send what is pending, the status and metrics documents, and flush to the sink."""
        if self.rec is None:
            return
        self._flush_decimated()
        md = rr.MediaType.MARKDOWN
        statics = _StaticBatch()
        statics.add(self._path("info/status"), rr.TextDocument(status_markdown(end), media_type=md))
        statics.add(self._path("info/metrics"), rr.TextDocument(metrics_markdown(end.metrics), media_type=md))
        statics.send(self.rec)
        if end.status != "completed":
            level = "WARN" if end.status == "interrupted" else "ERROR"
            self.rec.send_columns(self._path("events"), indexes=[_time_column([self._last_t])],
                                  columns=rr.TextLog.columns(text=[f"{end.status}: {end.message}"], level=[level]))
        _flush(self.rec)

    def close(self) -> None:
        """Flush and close the recording's sinks (finalises the ``.rrd`` footer).

        Call once, after every sink sharing the recording has finished.
        """
        if self.rec is not None:
            close_recording(self.rec)

    # -- block parts

    def _send_series(self, start: int, data: dict[str, np.ndarray], t: np.ndarray) -> None:
        rows = slice((-start) % self.curves_every, None, self.curves_every)
        batch = _RowBatch(t[rows])
        for spec in self._specs:
            try:
                values = spec.extract(data)
            except KeyError:
                continue  # e.g. an extra the plant did not report in this block
            batch.add_scalars(self._path(spec.entity), values[rows])
        batch.send(self.rec)

    def _buffer_frames(self, start: int, data: dict[str, np.ndarray], t: np.ndarray) -> None:
        """Keep the block's frame rows (every ``1 / frame_hz`` s of sim time) until the next flush."""
        rows = slice((-start) % self._frame_every, None, self._frame_every)
        theta = np.array(data["x"][rows, 0], dtype=np.float64)
        if theta.size == 0:
            return
        cart = data.get("extra/cart_pos")
        cart_pos = np.zeros_like(theta) if cart is None else np.array(cart[rows], dtype=np.float64)
        self._frames.append((t[rows].copy(), cart_pos, theta))
        self._frame_rows += theta.size

    def _decimated_due(self) -> bool:
        """Frames and snapshots go out in batches of ``decimated_rows`` rows (chunks have a fixed
        cost of ~50 us each), or after ``max_latency_s`` of wall time for a live viewer."""
        rows = max(self._frame_rows, self._snaps.count)
        return rows >= self.decimated_rows or (rows > 0 and time.monotonic() - self._last_flush >= self.max_latency_s)

    def _flush_decimated(self) -> None:
        if self._frames:
            t, cart_pos, theta = (np.concatenate(parts) for parts in zip(*self._frames))
            self._frames, self._frame_rows = [], 0
            self._send_poses(t, cart_pos, theta)
        self._flush_snapshots()
        self._last_flush = time.monotonic()

    def _send_poses(self, t: np.ndarray | Sequence[float], cart_pos: np.ndarray, theta: np.ndarray) -> None:
        assert self._geometry is not None
        poses = cartpole_poses(cart_pos, theta, self._geometry.l, 2.0 * self._geometry.cart_half_sizes[2])
        batch = _RowBatch(t)
        batch.add(self._path("world/cart"), _pose_columns(poses.cart_translation))
        batch.add(self._path("world/pole"), _pose_columns(poses.pole_translation, poses.pole_quaternion))
        batch.send(self.rec)

    def _flush_snapshots(self) -> None:
        buf = self._snaps
        if not buf.count:
            return
        t = buf.get("t")
        batch = _RowBatch(t)
        for group in ("model", "compensator"):
            for key in buf.inputs(group):
                batch.add(self._path(f"fuzzy/{key}"), [self._operating_points(key, buf)])
                self._send_changed_curves(key, buf, batch)
        bar = rr.BarChart.descriptor_values()
        for name in ("firing", "compensator_firing", "q"):
            batch.add(self._path(f"fuzzy/{name}"), [_tensor_column(buf.get(name), bar)])
        batch.add(self._path("fuzzy/consequents"),
                  [_tensor_column(buf.get("consequents"), rr.Tensor.descriptor_data(), names=("rule", "k"))])
        batch.send(self.rec)
        buf.clear()

    @staticmethod
    def _operating_points(key: str, buf: _SnapshotBuffer) -> rr.ComponentColumn:
        """The operating point on every curve of input ``key``, one row per snapshot."""
        mu = buf.get(f"{key}/mu")
        count, terms = mu.shape
        marks = np.empty((count, terms, 2))
        marks[..., 0] = buf.get(f"{key}/z")[:, None]
        marks[..., 1] = -mu                                   # y down on screen: log -mu
        return _points_column(marks.reshape(-1, 2), terms)

    def _send_changed_curves(self, key: str, buf: _SnapshotBuffer, batch: _RowBatch) -> None:
        """Curves of input ``key`` at the snapshots where they differ from the last ones sent.

        Fixed membership functions are thus sent once, which keeps the file small; curves
        that change at every snapshot ride along in ``batch`` (the snapshots' own rows).
        """
        grid, curves = buf.get(f"{key}/grid"), buf.get(f"{key}/curves")
        count, terms, points = curves.shape
        previous = self._sent_curves.get(key)
        if (previous is not None and previous[0].shape == grid.shape[1:] and previous[1].shape == curves.shape[1:]
                and (grid == previous[0]).all() and (curves == previous[1]).all()):
            return  # the common case: fixed membership functions, one pass over the block
        changed = np.empty(count, dtype=bool)
        changed[0] = previous is None or not (np.array_equal(previous[0], grid[0])
                                              and np.array_equal(previous[1], curves[0]))
        changed[1:] = np.any(curves[1:] != curves[:-1], axis=(1, 2)) | np.any(grid[1:] != grid[:-1], axis=1)
        if not changed.any():
            return
        self._sent_curves[key] = (grid[-1].copy(), curves[-1].copy())
        rows = np.flatnonzero(changed)
        strips = np.empty((rows.size, terms, points, 2))
        strips[..., 0] = grid[rows][:, None, :]
        strips[..., 1] = -curves[rows]
        column = _strips_column(strips.reshape(-1, points, 2), terms)
        if rows.size == count:
            batch.add(self._path(f"fuzzy/{key}"), [column])
            return
        own = _RowBatch(buf.get("t")[rows])
        own.add(self._path(f"fuzzy/{key}"), [column])
        own.send(self.rec)

    # -- static parts

    def _log_documents(self, statics: _StaticBatch, info: RunInfo) -> None:
        md = rr.MediaType.MARKDOWN
        statics.add(self._path("info/scenario"), rr.TextDocument(scenario_markdown(info), media_type=md))
        statics.add(self._path("info/run"), rr.TextDocument(run_markdown(info), media_type=md))

    def _log_fuzzy_styles(self, statics: _StaticBatch, info: RunInfo) -> None:
        for group, inputs in (("model", info.model_inputs), ("compensator", info.compensator_inputs)):
            for j, inp in enumerate(inputs):
                colors = [self._color(_PALETTE[k % len(_PALETTE)]) for k in range(len(inp.terms))]
                statics.add(self._path(f"fuzzy/{group}/in{j}"),
                            rr.LineStrips2D.from_fields(colors=colors, labels=list(inp.terms), radii=[-1.5]),
                            rr.Points2D.from_fields(colors=colors, radii=[-5.0]))
        for path, color in (("fuzzy/firing", (31, 119, 180)), ("fuzzy/compensator_firing", (44, 160, 44)),
                            ("fuzzy/q", (255, 127, 14))):
            # BarChart.from_fields(color=...) trips over its own values converter in 0.41
            statics.add(self._path(path), [rr.components.ColorBatch([self._color(color)]).described(
                rr.BarChart.descriptor_color())])

    def _log_cartpole_geometry(self, statics: _StaticBatch, geom: CartPoleGeometry) -> None:
        statics.add(self._path("world"), rr.ViewCoordinates.RIGHT_HAND_Z_UP)
        statics.add(self._path("world/cart"), rr.Boxes3D(
            half_sizes=[geom.cart_half_sizes], colors=[self._color(geom.cart_color)],
            fill_mode=rr.components.FillMode.Solid))
        statics.add(self._path("world/pole"), rr.Capsules3D(
            lengths=[2.0 * geom.l], radii=[geom.pole_radius], translations=[[0.0, 0.0, -geom.l]],
            colors=[self._color(geom.pole_color)]))


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


PathLike = str | os.PathLike[str]


def _file_sink(path: PathLike, write_footer: bool) -> rr.FileSink:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    return rr.FileSink(str(path), write_footer=write_footer)


def _viewer_sink(rec: rr.RecordingStream, kind: str, url: str | None, port: int) -> tuple[rr.GrpcSink | None, str]:
    """A gRPC sink to a viewer (``kind`` "spawn": start one; "connect": reach ``url``), or why not."""
    if kind == "connect":
        host, grpc_port = _grpc_endpoint(url)
        if not _port_open(host, grpc_port):
            return None, f"no Rerun viewer at {url or f'{host}:{grpc_port}'}"
        return rr.GrpcSink(url), ""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        # the viewer would start, fail to open a window, and leave us waiting ~10 s
        return None, "no display for the Rerun viewer"
    exe = _viewer_executable()
    if exe is None:
        return None, "Rerun viewer executable not found"
    try:
        rr.spawn(port=port, connect=False, executable_path=exe, recording=rec)
    except Exception as exc:  # noqa: BLE001 - any failure means: no viewer
        return None, f"cannot start the Rerun viewer ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})"
    if not _port_open("127.0.0.1", port, timeout=2.0):
        return None, f"the Rerun viewer did not come up on port {port}"
    return rr.GrpcSink(f"rerun+http://127.0.0.1:{port}/proxy"), ""


def open_recording(app_id: str, mode: str | None = None, path: PathLike | None = None, url: str | None = None, *,
                   spawn: bool = False, connect: str | bool | None = None, recording_id: str | None = None,
                   port: int = DEFAULT_VIEWER_PORT, write_footer: bool = True) -> rr.RecordingStream | None:
    """A new recording stream (never the global one) with its sinks attached, or ``None``.

    With ``mode``: ``"save"`` streams to the ``.rrd`` at ``path`` as data comes;
    ``"spawn"`` starts a viewer on ``port``; ``"connect"`` connects to ``url`` (default
    ``rerun+http://127.0.0.1:9876/proxy``); ``"none"`` returns ``None`` (record nothing:
    don't add a sink).  When the viewer cannot be reached, a one-line warning goes to
    stderr and the recording is saved to ``path`` if given, else ``None`` is returned.

    Without ``mode`` (the CLI's form): save to ``path`` if given and *also* stream to a
    spawned viewer (``spawn``) and/or the viewer at ``connect`` (a URL, or True for the
    default one); viewers that cannot be reached are dropped with a one-line warning.

    ``write_footer``: the ``.rrd`` footer (a chunk index, needed by
    ``RrdReader.store()``; ``stream()`` works without it) is kept in memory until the
    file is closed, ~3 kB per chunk, i.e. ~20-40 kB per 1000-step block here.  Pass
    ``False`` for very long runs to keep memory strictly flat.
    """
    if mode == "none":
        return None
    if mode not in (None, "save", "spawn", "connect"):
        raise ValueError(f"unknown recording mode {mode!r} (save, spawn, connect, none)")
    if mode == "save" and path is None:
        raise ValueError("mode 'save' needs a path")
    rec = rr.RecordingStream(app_id, recording_id=recording_id or uuid.uuid4())
    viewers: list[rr.GrpcSink] = []
    if mode in ("spawn", "connect"):
        viewer, why = _viewer_sink(rec, mode, url, port)
        if viewer is not None:
            path = None  # the file is only the fallback of these modes
            viewers.append(viewer)
        elif path is not None:
            _warn(f"{why}; saving the recording to {path} instead")
        else:
            _warn(f"{why}; recording nothing")
            return None
    elif mode is None:
        wanted = ([("spawn", None)] if spawn else []) + \
                 ([("connect", None if connect is True else str(connect))] if connect else [])
        for kind, viewer_url in wanted:
            viewer, why = _viewer_sink(rec, kind, viewer_url, port)
            if viewer is not None:
                viewers.append(viewer)
            else:
                _warn(f"{why}; " + (f"recording to {path} only" if path is not None else "not streaming to it"))
    if viewers:
        rec.set_sinks(*viewers, *([_file_sink(path, write_footer)] if path is not None else []))
    elif path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        rec.save(path, write_footer=write_footer)  # streams to disk as data comes
    else:
        return None
    return rec


def _flush(rec: rr.RecordingStream, timeout_s: float = FLUSH_TIMEOUT_S) -> None:
    """Flush, bounded in time: a vanished viewer must not hang the end of a run."""
    try:
        rec.flush(timeout_sec=timeout_s)
    except Exception as exc:  # noqa: BLE001 - the run's own outcome matters more
        _warn(f"Rerun flush did not complete ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})")


def close_recording(rec: rr.RecordingStream) -> None:
    """Flush and close every sink of ``rec`` (writes the ``.rrd`` footer)."""
    _flush(rec)
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
