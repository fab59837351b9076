"""Reading a recording back: :func:`read_scalar_series` from an ``.rrd`` via ``RrdReader``."""

from __future__ import annotations

import os
import warnings

import numpy as np
import pyarrow as pa

from tspend.recorder.common import TIMELINE


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
