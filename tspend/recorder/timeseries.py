"""A run's time series as a pandas table.

Two readers: :func:`recording_table` for an ``.rrd`` file as ``tspend export`` writes it,
``t_s`` then the domain's names with the unit at the end (``theta_rad``,
``theta_dot_rad_s``, ``ref_rad``, ``ref_dot_rad_s``, ``u_N``, ``d_N``, ``cart_x_m`` ...,
listed by the recorder in ``info/columns``), and :func:`history_frame` for a run kept in
memory (``RunResult.to_pandas()``), indexed by ``t`` and named by the series' stable keys
(``x1``, ``r``, ``r_d1``, ``e_1``, ``u``, ``d``, each diagnostic's labels, the extras).
"""

from __future__ import annotations

import os
import warnings
from typing import Sequence

import numpy as np

from tspend.controllers.base import Diagnostic


__all__ = ["RUN_KEYS", "history_frame", "recording_table", "run_table", "with_units"]


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


def run_table(history: dict[str, np.ndarray], info):
    """The in-memory history of a run under the names of :func:`recording_table` (one
    name per quantity: the model's, ``hinge_rad``), indexed by ``t_s``: the columns
    :func:`tspend.recorder.series.export_columns` lists for the run's layout ``info``
    (a :class:`~tspend.loop.sinks.RunInfo`), each taken by its series' own extractor."""
    import pandas as pd

    from tspend.recorder.series import export_columns, specs_of

    specs = specs_of(info)
    if not history:
        return pd.DataFrame(index=pd.Index([], name="t_s", dtype=float))
    by_entity = {spec.entity: spec for spec in specs}
    values: dict[str, np.ndarray] = {}
    for column, entity, j in export_columns(specs, info.view):
        block = np.asarray(by_entity[entity].extract(history), dtype=float)
        values[column] = block[:, j]
    return pd.DataFrame(values, index=pd.Index(np.asarray(history["t"], dtype=float), name="t_s"))


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
RUN_KEYS = ("scenario", "seed", "controller", "plant_kind", "version", "dt_s", "duration_s",
            "u_unit", "force_unit", "force_per_u")


def _first(value):
    return value[0] if isinstance(value, list) and len(value) == 1 else value


def recording_table(path: str | os.PathLike[str]):
    """``(table, metadata)`` of the recording at ``path``, as ``tspend export`` writes it.

    ``table`` has the column ``t_s`` then one column per series the recorder listed in
    ``info/columns`` (:func:`tspend.recorder.series.export_columns`): named by the
    plant's domain with the unit at the end (``theta_rad``, ``theta_dot_rad_s``,
    ``ref_rad``, ``u_N``, ``cart_x_m``), each value as recorded; a time a series lacks
    is NaN.  With several runs in one recording (a cross-check) each column starts with
    its run's prefix (``mujoco_theta_rad``), but for the run without one (a rig run's own,
    beside its ``twin/``).  ``metadata``: each run's scenario, seed,
    controller, plant kind, version, dt and duration (by prefix, "" for a single run).
    Raises ValueError for a recording that lists no columns (made before they were
    listed, or not a run's).
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
    names: list[str] = []   # every listed column, sent or not
    several = len(listed) > 1
    for prefix in sorted(listed):
        spec = listed[prefix]
        for column, entity, instance in zip(spec.get("columns", []), spec.get("entities", []),
                                            spec.get("instances", [])):
            # a run without a prefix (a rig run beside its twin/) keeps its own names
            name = f"{prefix.replace('/', '_')}_{column}" if several and prefix else column
            names.append(name)
            if entity not in cache:
                try:
                    t, values = read_scalar_series(path, entity)
                except KeyError:  # listed but never sent (a run that stopped at once)
                    continue
                t_ns = np.rint(t * 1e9).astype(np.int64)
                cache[entity] = (t_ns, values[:, None] if values.ndim == 1 else values)
            t_ns, values = cache[entity]
            series[name] = pd.Series(values[:, int(instance)], index=t_ns)
    if not names:
        raise ValueError("no time series in this recording")
    if not series:
        # a run that ended at its first sample (a controller's error there): its columns,
        # no rows; the metadata still says how it ended
        table = pd.DataFrame({"t_s": np.zeros(0), **{n: np.zeros(0) for n in names}})
        return table, {prefix: {k: _first(v) for k, v in values.items()}
                       for prefix, values in runs.items()}
    table = pd.concat(series, axis=1, join="outer").sort_index()
    table.insert(0, "t_s", table.index.to_numpy() * 1e-9)
    table = table.reset_index(drop=True)
    metadata = {prefix: {k: _first(v) for k, v in values.items()} for prefix, values in runs.items()}
    return table, metadata
