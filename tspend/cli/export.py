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
``--to`` is the deprecated spelling of ``--out`` (kept one release).
"""

from __future__ import annotations

import argparse
import json
import os
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
                                   "it (the CSV has one header row).")
    p.add_argument("recording", metavar="FILE.rrd", help="a recording made by tspend")
    p.add_argument("--out", metavar="PATH.parquet|PATH.csv",
                   help="the table to write (the suffix picks the format; never overwritten)")
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
    for path in (target, side):
        if path is not None and os.path.lexists(path):
            raise ScenarioError(f"--out {path}: exists; choose another path (nothing is "
                                f"overwritten)")
    try:
        table, metadata = recording_table(source)
    except (ValueError, OSError, RuntimeError, KeyError) as exc:
        # Rerun's reader reports a corrupt or foreign file as a RuntimeError
        raise ScenarioError(f"{source}: not a readable tspend recording "
                            f"({' '.join(str(exc).split())[:300]})") from None
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ScenarioError(f"--out {target}: cannot create directory {target.parent}: "
                            f"{exc.strerror or exc}") from None
    from tspend.runtime.outputs import write_atomic

    write_atomic(target, lambda tmp: write_table(table, metadata, tmp, suffix), replace=False,
                 what="--out")
    if side is not None:
        text = json.dumps(csv_metadata(table, metadata), indent=2, default=str) + "\n"
        write_atomic(side, lambda tmp: tmp.write_text(text, encoding="utf-8"), replace=False,
                     what="--out (metadata)")
    print(f"{target}: {len(table)} samples x {table.shape[1]} columns "
          f"({', '.join(table.columns[:8])}{', ...' if table.shape[1] > 8 else ''})"
          + (f"; run metadata in {side}" if side else ""))
    return 0
