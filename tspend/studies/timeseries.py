"""A run's time series as a pandas table, one column per series, indexed by time ``t`` (s).

Three readers: :func:`recording_table` for an ``.rrd`` file as ``tspend export`` writes
it (the domain's names with the unit at the end: ``t_s``, ``theta_rad``,
``theta_dot_rad_s``, ``ref_rad``, ``u_N``, ``cart_x_m`` ...), and, with one naming,
:func:`history_frame` for a run kept in memory (``RunResult.to_pandas()``) and
:func:`recording_frame` for every scalar series of an ``.rrd`` by its stable key.  A column is named as the recording names the series (``r``,
``x1``, ``e_1``, ``u``, ``d``, each diagnostic's labels such as ``u_s``, ``b_hat``), so
a run and its recording give the same columns where both have them.  The history has
more: every state (``x1 .. xn``) and the reference's derivatives (``r_d1 .. r_dn``).
"""

from __future__ import annotations

import os
import warnings
from typing import Sequence

import numpy as np

from tspend.controllers.base import Diagnostic


def _unique(names: list[str], qualifiers: list[str]) -> list[str]:
    """Names as they are where unique, else prefixed by their qualifier."""
    counts: dict[str, int] = {}
    for n in names:
        counts[n] = counts.get(n, 0) + 1
    return [n if counts[n] == 1 else f"{q}/{n}" for n, q in zip(names, qualifiers)]


def history_frame(history: dict[str, np.ndarray], diagnostics: Sequence[Diagnostic] = ()):
    """The in-memory history of a run (:attr:`tspend.loop.simulation.RunResult.history`)."""
    import pandas as pd

    if not history:
        return pd.DataFrame(index=pd.Index([], name="t", dtype=float))
    columns: list[np.ndarray] = []
    names: list[str] = []
    sources: list[str] = []

    def add(key: str, labels: Sequence[str]) -> None:
        values = np.asarray(history[key], dtype=float)
        values = values[:, None] if values.ndim == 1 else values
        for j, label in enumerate(labels):
            columns.append(values[:, j])
            names.append(label)
            sources.append(key)

    n = history["x"].shape[1]
    add("x", [f"x{i + 1}" for i in range(n)])
    add("ref", ["r"] + [f"r_d{i}" for i in range(1, history["ref"].shape[1])])
    add("e", [f"e_{i + 1}" for i in range(n)])
    add("u", ["u"])
    add("d", ["d"])
    for diag in diagnostics:
        if diag.name in history:
            add(diag.name, list(diag.column_labels))
    for key in history:
        if key.startswith("extra/"):
            add(key, [key.removeprefix("extra/")])
    index = pd.Index(np.asarray(history["t"], dtype=float), name="t")
    return pd.DataFrame(dict(zip(_unique(names, sources), columns)), index=index)


def _derivative_unit(unit: str, k: int) -> str:
    if not unit or k == 0:
        return unit
    return f"{unit}/s" if k == 1 else f"{unit}/s^{k}"


def with_units(frame, state_units: Sequence[str], control_unit: str,
               diagnostics: Sequence[Diagnostic] = ()):
    """``frame`` (of :func:`history_frame`) with ``[unit]`` after every column name that has
    one, and the index named ``t [s]``.  The reference's derivative ``r_dk`` has the unit
    of the k-th state (``r`` of the first), ``d`` that of the last state's derivative."""
    n = len(state_units)
    units: dict[str, str] = {"u": control_unit, "r": state_units[0] if n else "",
                             "d": _derivative_unit(state_units[0], n) if n else ""}
    for i, unit in enumerate(state_units):
        units[f"x{i + 1}"] = units[f"e_{i + 1}"] = unit
    for k in range(1, n + 1):
        units[f"r_d{k}"] = _derivative_unit(state_units[0], k) if state_units else ""
    for diag in diagnostics:
        for label in diag.column_labels:
            units.setdefault(label, diag.unit)
    out = frame.rename(columns=lambda c: f"{c} [{units[c]}]" if units.get(c) else c)
    out.index = out.index.rename("t [s]")
    return out


def _static_values(path: str | os.PathLike[str], suffix: str,
                   names: Sequence[str]) -> dict[str, dict[str, list]]:
    """The static ``AnyValues`` ``names`` logged at every entity ending in ``suffix``, by
    the entity's prefix ("" for a single run, "mujoco" ...)."""
    from rerun.chunk import RrdReader

    found: dict[str, dict[str, list]] = {}
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*no footer.*")
        for chunk in RrdReader(path).stream().filter(is_static=True, components=list(names)).to_chunks():
            entity = chunk.entity_path.strip("/")
            if not (entity == suffix or entity.endswith("/" + suffix)):
                continue
            batch = chunk.to_record_batch()
            values = found.setdefault(entity[: -len(suffix)].strip("/"), {})
            for name in names:
                if name in batch.schema.names:
                    rows = batch.column(batch.schema.get_field_index(name)).to_pylist()
                    if rows:
                        values[name] = rows[-1]
    return found


#: the run's identity a recording holds (``info/run``), copied into an export's metadata
RUN_KEYS = ("scenario", "seed", "controller", "plant_kind", "version", "dt_s", "duration_s")


def _first(value):
    return value[0] if isinstance(value, list) and len(value) == 1 else value


def recording_table(path: str | os.PathLike[str]):
    """``(table, metadata)`` of the recording at ``path``, as ``tspend export`` writes it.

    ``table`` has the column ``t_s`` then one column per series the recorder listed in
    ``info/columns`` (:func:`tspend.recorder.series.export_columns`): named by the
    plant's domain with the unit at the end (``theta_rad``, ``theta_dot_rad_s``,
    ``ref_rad``, ``u_N``, ``cart_x_m``), each value as recorded; a time a series lacks
    is NaN.  With several runs in one recording (a cross-check) each column starts with
    its run's prefix (``mujoco_theta_rad``).  ``metadata``: each run's scenario, seed,
    controller, plant kind, version, dt and duration (by prefix, "" for a single run).
    Raises ValueError for a recording that lists no columns (made before they were
    listed: :func:`recording_frame` reads those).
    """
    import pandas as pd

    from tspend.recorder.readback import read_scalar_series

    listed = _static_values(path, "info/columns", ("columns", "entities", "instances"))
    runs = _static_values(path, "info/run", RUN_KEYS)
    if not listed:
        raise ValueError("the recording lists no exported columns (info/columns): it was "
                         "made by an older tspend or is not a run's recording")
    cache: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    series: dict[str, "pd.Series"] = {}
    several = len(listed) > 1
    for prefix in sorted(listed):
        spec = listed[prefix]
        for column, entity, instance in zip(spec.get("columns", []), spec.get("entities", []),
                                            spec.get("instances", [])):
            if entity not in cache:
                try:
                    t, values = read_scalar_series(path, entity)
                except KeyError:  # listed but never sent (a run that stopped at once)
                    continue
                t_ns = np.rint(t * 1e9).astype(np.int64)
                cache[entity] = (t_ns, values[:, None] if values.ndim == 1 else values)
            t_ns, values = cache[entity]
            name = f"{prefix.replace('/', '_')}_{column}" if several else column
            series[name] = pd.Series(values[:, int(instance)], index=t_ns)
    if not series:
        raise ValueError("no time series in this recording")
    table = pd.concat(series, axis=1, join="outer").sort_index()
    table.insert(0, "t_s", table.index.to_numpy() * 1e-9)
    table = table.reset_index(drop=True)
    metadata = {prefix: {k: _first(v) for k, v in values.items()} for prefix, values in runs.items()}
    return table, metadata


def recording_frame(path: str | os.PathLike[str]):
    """Every scalar series of the recording at ``path`` (``series/...`` entities and any
    other ``Scalars``), joined on ``sim_time``; a time an entity lacks is NaN."""
    import pandas as pd
    from rerun.chunk import RrdReader

    from tspend.recorder.readback import read_scalar_series

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*no footer.*")
        found: dict[str, list[str] | None] = {}
        keys: dict[str, list[str]] = {}
        for chunk in RrdReader(path).stream().filter(
                components=["Scalars:scalars", "SeriesLines:names", "series_keys"]).to_chunks():
            batch = chunk.to_record_batch()
            entity = chunk.entity_path
            if "series_keys" in batch.schema.names:  # the stable names (x1, e_1, ...)
                rows = batch.column(batch.schema.get_field_index("series_keys")).to_pylist()
                if rows and rows[-1]:
                    keys[entity] = [str(n) for n in rows[-1]]
                    found.setdefault(entity, None)
            if "SeriesLines:names" in batch.schema.names:
                rows = batch.column(batch.schema.get_field_index("SeriesLines:names")).to_pylist()
                if rows and rows[-1]:
                    found[entity] = [str(n) for n in rows[-1]]
            if "Scalars:scalars" in batch.schema.names:
                found.setdefault(entity, None)
    frames, names, qualifiers = [], [], []
    for entity, labels in found.items():
        labels = keys.get(entity, labels)
        try:
            t, values = read_scalar_series(path, entity)
        except KeyError:  # names without any data (a run that stopped at once)
            continue
        values = values[:, None] if values.ndim == 1 else values
        if labels is None or len(labels) != values.shape[1]:
            leaf = entity.strip("/").split("/")[-1]
            labels = [leaf] if values.shape[1] == 1 else [f"{leaf}_{j}" for j in
                                                          range(values.shape[1])]
        frame = pd.DataFrame(values, index=pd.Index(t, name="t"))
        frames.append(frame)
        names += labels
        qualifiers += [entity.strip("/")] * len(labels)
    if not frames:
        raise ValueError(f"{path}: no scalar time series in this recording")
    table = pd.concat(frames, axis=1, join="outer").sort_index()
    table.columns = _unique(names, qualifiers)
    return table
