"""Arrow columns and record batches built directly, bypassing the SDK's per-row converters.

:class:`RowBatch` sends the time-indexed columns of several entities as one record
batch, :class:`StaticBatch` the static archetypes; the ``*_column`` builders make
``TensorData``, ``LineStrips2D``, ``Points2D`` and ``Transform3D`` columns in arrow."""

from __future__ import annotations

import functools
from typing import Iterable, NamedTuple, Sequence

import numpy as np
import pyarrow as pa
import rerun as rr

from .common import TIMELINE


def _durations(t: np.ndarray | Sequence[float]) -> np.ndarray:
    """Seconds -> ``timedelta64[ns]``, rounded (Rerun's float path truncates 0.003 s to 2999999 ns)."""
    return np.rint(np.asarray(t, dtype=np.float64) * 1e9).astype(np.int64).astype("timedelta64[ns]")


def time_column(t: np.ndarray | Sequence[float]) -> rr.TimeColumn:
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


class RowBatch:
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


class StaticBatch:
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


def tensor_column(rows: np.ndarray, descriptor: rr.ComponentDescriptor,
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


def strips_column(strips: np.ndarray, per_row: int) -> rr.ComponentColumn:
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


def points_column(points: np.ndarray, per_row: int) -> rr.ComponentColumn:
    """``Points2D:positions`` from ``points`` (R, 2): ``per_row`` points per row."""
    ptype = _arrow_type(rr.components.Position2DBatch, [0.0, 0.0])
    flat = pa.array(np.ascontiguousarray(points, dtype=np.float32).reshape(-1))
    return _column(pa.FixedSizeListArray.from_arrays(flat, type=ptype), rr.Points2D.descriptor_positions(),
                   np.arange(0, points.shape[0] + 1, per_row, dtype=np.int32))


def _fixed_column(values: np.ndarray, descriptor: rr.ComponentDescriptor, batch_cls: type) -> rr.ComponentColumn:
    """One fixed-size float32 vector per row (translations, quaternions), built directly in arrow."""
    vtype = _arrow_type(batch_cls, np.zeros(values.shape[1]))
    flat = pa.array(np.ascontiguousarray(values, dtype=np.float32).reshape(-1))
    return _column(pa.FixedSizeListArray.from_arrays(flat, type=vtype), descriptor,
                   np.arange(values.shape[0] + 1, dtype=np.int32))


def pose_columns(translation: np.ndarray, quaternion: np.ndarray | None = None) -> list[rr.ComponentColumn]:
    """``Transform3D`` translation (and rotation) columns; ``Transform3D.columns`` costs ~0.1 ms more."""
    columns = [_fixed_column(translation, rr.Transform3D.descriptor_translation(), rr.components.Translation3DBatch)]
    if quaternion is not None:
        columns.append(_fixed_column(quaternion, rr.Transform3D.descriptor_quaternion(),
                                     rr.components.RotationQuatBatch))
    return columns
