"""``tspend export FILE.rrd --out PATH.parquet|PATH.csv``: a recording's time series as a
table: ``t_s``, then every state and its derivative, the reference and its derivatives,
the input, the disturbance and the controller's series, each named by the model (the
joint's name, the unit at the end: ``hinge_rad``, ``hinge_dot_rad_s``, ``slider_m``,
``u_N``; :func:`tspend.recorder.timeseries.recording_table`), as
:meth:`tspend.loop.simulation.RunResult.to_pandas` and the metrics name them.

The run's scenario, seed and controller go into the Parquet schema's metadata (key
``tspend``, JSON, and one key each) and, for a CSV, into ``PATH.csv.json`` beside it: the
CSV itself is plain (one header row, then one row per sample), so
``pandas.read_csv(path)`` with no arguments and any spreadsheet read it.

Each rate has its own table: the series recorded at every sample go into ``PATH``; those
recorded at a lower rate (the controller's diagnostics at 50 Hz by default,
``--diagnostics-hz``) into ``PATH`` with the rate before the suffix (``run.50Hz.csv``), on
their own rows, so no column of either is mostly empty cells. ``PATH`` is replaced only by
a complete file, as every command's output. ``--to`` is the deprecated spelling of
``--out`` (kept one release).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from tspend.runtime.errors import ScenarioError

FORMATS = (".parquet", ".csv")
#: the suffix of a CSV's metadata file, beside it
CSV_METADATA = ".json"

__all__ = ["CSV_METADATA", "FORMATS", "add_parser", "cmd", "write_table"]


def add_parser(sub) -> None:
    from tspend.cli.common import add_deprecated_alias

    p = sub.add_parser("export", help="write a recording's time series as Parquet or CSV",
                       description="Write a recording's time series as one table: t_s, every "
                                   "state and its derivative, the reference and its "
                                   "derivatives, u and d, named by the model with their units "
                                   "at the end (hinge_rad, hinge_dot_rad_s, ref_rad, u_N, "
                                   "slider_m ...). Scenario, seed and controller go into the "
                                   "Parquet metadata or, for a CSV, into PATH.csv.json beside "
                                   "it (the CSV has one header row). Series recorded at a "
                                   "lower rate (diagnostics at 50 Hz by default) go into a "
                                   "table of their own beside it, the rate in its name "
                                   "(PATH.50Hz.csv), so no column is mostly empty.")
    p.add_argument("recording", metavar="FILE.rrd", help="a recording made by tspend")
    p.add_argument("--out", metavar="PATH.parquet|PATH.csv",
                   help="the table to write (the suffix picks the format; replaced only by "
                        "a complete file)")
    add_deprecated_alias(p, "--to", "--out", "PATH")
    p.add_argument("--debug", action="store_true", help="show tracebacks")


def _flat(metadata: dict[str, dict]) -> dict[str, object]:
    """One run's metadata as it is; several runs' under their prefix (``mujoco.seed``)."""
    if list(metadata) == [""]:
        return dict(metadata[""])
    return {f"{prefix}.{k}": v for prefix, values in sorted(metadata.items())
            for k, v in values.items()}


def write_table(table, metadata: dict[str, dict], target: Path, fmt: str) -> None:
    """``table`` at ``target`` as ``fmt`` (".csv" or ".parquet"); the run's ``metadata`` in
    the Parquet schema (a CSV's goes beside it, :func:`write_csv_metadata`)."""
    if fmt == ".csv":
        with open(target, "w", encoding="utf-8", newline="") as out:
            table.to_csv(out, index=False)  # floats as the shortest text that reads back exactly
        return
    import pyarrow as pa
    import pyarrow.parquet as pq

    flat = _flat(metadata)
    arrow = pa.Table.from_pandas(table, preserve_index=False)
    meta = dict(arrow.schema.metadata or {})
    meta[b"tspend"] = json.dumps(metadata, sort_keys=True).encode()
    meta.update({str(k).encode(): str(v).encode() for k, v in flat.items()})
    pq.write_table(arrow.replace_schema_metadata(meta), target)


def by_rate(table) -> list[tuple[str, object]]:
    """``table`` split by the rate its columns were recorded at: ``("", columns recorded at
    every sample)``, then one ``(".50Hz", t_s and the columns recorded at 50 Hz, on their
    own rows)`` per lower rate. A column is recorded at a lower rate when it holds a value
    in at most half the rows (a diverged run's last NaN does not move a column)."""
    import numpy as np

    recorded = table.notna()
    rows = len(table)
    thinned: dict[bytes, list[str]] = {}
    for column in table.columns:
        have = recorded[column].to_numpy()
        if 0 < have.sum() <= rows // 2:
            thinned.setdefault(have.tobytes(), []).append(column)
    full = [c for c in table.columns if not any(c in cs for cs in thinned.values())]
    out = [("", table[full])]
    for columns in thinned.values():
        part = table.loc[recorded[columns[0]], ["t_s", *columns]].reset_index(drop=True)
        step = np.median(np.diff(part["t_s"])) if len(part) > 1 else 0.0
        name = f".{1.0 / step:.4g}Hz" if step > 0 else ".thinned"
        while name in dict(out):  # two groups at one rate (never seen): kept apart
            name += "_"
        out.append((name, part))
    return out


def rate_path(target: Path, rate: str) -> Path:
    """Where the table of one lower rate goes: ``run.csv`` -> ``run.50Hz.csv``."""
    return target.with_name(target.stem + rate + target.suffix)


def csv_metadata(table, metadata: dict[str, dict]) -> dict:
    """What ``PATH.csv.json`` holds: the run's identity and every column's unit."""
    return {**_flat(metadata), "columns": list(table.columns)}


def cmd(args: argparse.Namespace) -> int:
    from tspend.recorder.timeseries import recording_table

    if args.out is None:
        raise ScenarioError("--out PATH.parquet|PATH.csv: required (the table to write)")
    source, target = Path(args.recording), Path(args.out)
    if not source.is_file():
        raise ScenarioError(f"{source}: no such recording")
    suffix = target.suffix.lower()
    if suffix not in FORMATS:
        raise ScenarioError(f"--out {target}: the suffix must be one of {', '.join(FORMATS)}")
    from tspend.runtime.outputs import OutputRequest, plan_outputs

    side = target.with_name(target.name + CSV_METADATA) if suffix == ".csv" else None
    # the paths checked (directory writable, name length) before the recording is read
    plan_outputs([OutputRequest("--out", "table", suffix, str(target))]
                 + ([OutputRequest("--out (metadata)", "metadata", ".json", str(side))]
                    if side else []), inputs=[source])
    try:
        table, metadata = recording_table(source)
    except (ValueError, OSError, RuntimeError, KeyError) as exc:
        # Rerun's reader reports a corrupt or foreign file as a RuntimeError
        raise ScenarioError(f"{source}: not a readable tspend recording "
                            f"({' '.join(str(exc).split())[:300]})") from None
    tables = by_rate(table)
    plan_outputs([OutputRequest("--out", f"table{rate}", suffix, str(rate_path(target, rate)))
                  for rate, _ in tables[1:]], inputs=[source])
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ScenarioError(f"--out {target}: cannot create directory {target.parent}: "
                            f"{exc.strerror or exc}") from None
    _write_all(tables, metadata, target, side, suffix)
    return 0


def _write_all(tables, metadata, target: Path, side: Path | None, suffix: str) -> None:
    """Each rate's table, then the CSV's metadata; each replaced only by a complete file."""
    from tspend.runtime.outputs import write_atomic

    said = []
    for rate, part in tables:
        path = rate_path(target, rate)
        write_atomic(path, lambda tmp, part=part: write_table(part, metadata, tmp, suffix),
                     replace=True, what="--out")
        said.append(f"{path}: {len(part)} samples x {part.shape[1]} columns "
                    f"({', '.join(part.columns[:8])}{', ...' if part.shape[1] > 8 else ''})"
                    + (f", recorded at {rate[1:]}" if rate else ""))
    if side is not None:
        text = json.dumps({**csv_metadata(tables[0][1], metadata),
                           "tables": {str(rate_path(target, r).name): list(t.columns)
                                      for r, t in tables}}, indent=2, default=str) + "\n"
        write_atomic(side, lambda tmp: tmp.write_text(text, encoding="utf-8"), replace=True,
                     what="--out (metadata)")
    print("\n".join(said) + (f"\nrun metadata in {side}" if side else ""))
    return 0
