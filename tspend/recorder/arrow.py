"""Columns built directly in Arrow: ``TensorData`` (bar charts, the consequents) and the
membership curves (``LineStrips2D``/``Points2D`` at every snapshot while they adapt).

Everything else goes through Rerun's public API (``send_columns`` with the archetypes'
``.columns()``, ``log(..., static=True)``).  Tensors have no batched path in the SDK: it
converts each ``TensorData`` in Python (~0.4 ms apiece, 50 per simulated second), which
cost more than the simulation; its strip converter loops over strips in Python, which
for adapting membership functions doubled the recording's cost.  So :func:`tensor_column` assembles the SDK's own Arrow
type (read from the SDK at run time), and :func:`check_tensor_type` verifies at start-up
that the layout it assumes still holds, with a clear error if a newer SDK changed it."""

from __future__ import annotations

import functools
from typing import NamedTuple, Sequence

import numpy as np
import pyarrow as pa
import rerun as rr

from tspend.runtime.errors import TspendError
from tspend.recorder.common import TIMELINE


def _durations(t: np.ndarray | Sequence[float]) -> np.ndarray:
    """Seconds -> ``timedelta64[ns]``, rounded (Rerun's float path truncates 0.003 s to 2999999 ns)."""
    return np.rint(np.asarray(t, dtype=np.float64) * 1e9).astype(np.int64).astype("timedelta64[ns]")


def time_column(t: np.ndarray | Sequence[float]) -> rr.TimeColumn:
    return rr.TimeColumn(TIMELINE, duration=_durations(t))


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
    struct = _tensor_struct(rows, names)
    return _column(struct, descriptor, np.arange(len(struct) + 1, dtype=np.int32))


def _tensor_struct(rows: np.ndarray, names: Sequence[str] | None) -> pa.StructArray:
    """The ``TensorData`` struct array of ``rows`` (S, *shape), one tensor per row."""
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
    return struct


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


class RerunVersionError(TspendError):
    """The installed rerun-sdk encodes tensors differently from what tspend builds."""


@functools.cache
def check_tensor_type() -> None:
    """Compare :func:`tensor_column` with the SDK's own encoding of the same tensor.

    Raises :class:`RerunVersionError` naming the installed version when the Arrow type
    or the encoded values differ (a newer rerun-sdk changed ``TensorData``).
    """
    sample = np.arange(6, dtype=np.float32).reshape(1, 2, 3)
    try:
        ours = _tensor_struct(sample, ("a", "b"))
        tensor = rr.Tensor(sample[0], dim_names=("a", "b"))
        sdk = next(b for b in tensor.as_component_batches()
                   if b.component_descriptor() == rr.Tensor.descriptor_data()).as_arrow_array()
        same = ours.type == sdk.type and ours.to_pylist() == sdk.to_pylist()
        strips = np.arange(8, dtype=np.float32).reshape(2, 2, 2)
        sdk_strips = next(iter(rr.LineStrips2D.columns(strips=strips))).as_arrow_array()
        same = same and strips_column(strips, 1).as_arrow_array().to_pylist() == sdk_strips.to_pylist()
    except Exception as exc:  # noqa: BLE001 - any mismatch is the same problem for the user
        raise RerunVersionError(f"rerun-sdk {rr.__version__}: cannot build TensorData or LineStrips2D columns "
                                f"({type(exc).__name__}: {exc}); tspend/recorder/arrow.py needs updating "
                                f"for this version (known to work: 0.41)") from exc
    if not same:
        raise RerunVersionError(f"rerun-sdk {rr.__version__} changed the Arrow type of TensorData; "
                                f"tspend/recorder/arrow.py needs updating for this version "
                                f"(known to work: 0.41)")
