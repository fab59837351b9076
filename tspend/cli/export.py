"""``tspend export FILE.rrd --to PATH.parquet|PATH.csv``: a recording's time series as a
table: ``t_s``, then every state and its derivative, the reference and its derivatives,
the input, the disturbance and the controller's series, each named by the plant's domain
with its unit at the end (:func:`tspend.studies.timeseries.recording_table`).

The run's scenario, seed and controller go into the Parquet schema's metadata (key
``tspend``, JSON, and one key each) and into ``# key: value`` comment lines at the top of
a CSV (``pandas.read_csv(path, comment="#")`` reads it).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from tspend.errors import ScenarioError

FORMATS = (".parquet", ".csv")

__all__ = ["FORMATS", "add_parser", "cmd", "write_table"]


def add_parser(sub) -> None:
    p = sub.add_parser("export", help="write a recording's time series as Parquet or CSV",
                       description="Write a recording's time series as one table: t_s, every "
                                   "state and its derivative, the reference and its "
                                   "derivatives, u and d, named with their units at the end "
                                   "(theta_rad, theta_dot_rad_s, ref_rad, u_N, cart_x_m ...). "
                                   "Scenario, seed and controller go into the Parquet "
                                   "metadata or the CSV's '#' header lines.")
    p.add_argument("recording", metavar="FILE.rrd", help="a recording made by tspend")
    p.add_argument("--to", required=True, metavar="PATH.parquet|PATH.csv",
                   help="the table to write (the suffix picks the format; never overwritten)")
    p.add_argument("--debug", action="store_true", help="show tracebacks")


def _flat(metadata: dict[str, dict]) -> dict[str, object]:
    """One run's metadata as it is; several runs' under their prefix (``mujoco.seed``)."""
    if list(metadata) == [""]:
        return dict(metadata[""])
    return {f"{prefix}.{k}": v for prefix, values in sorted(metadata.items())
            for k, v in values.items()}


def write_table(table, metadata: dict[str, dict], target: Path, fmt: str) -> None:
    """``table`` at ``target`` as ``fmt`` (".csv" or ".parquet") with the run's ``metadata``."""
    flat = _flat(metadata)
    if fmt == ".csv":
        with open(target, "w", encoding="utf-8", newline="") as out:
            for key, value in flat.items():
                out.write(f"# {key}: {value}\n")
            table.to_csv(out, index=False)  # floats as the shortest text that reads back exactly
        return
    import pyarrow as pa
    import pyarrow.parquet as pq

    arrow = pa.Table.from_pandas(table, preserve_index=False)
    meta = dict(arrow.schema.metadata or {})
    meta[b"tspend"] = json.dumps(metadata, sort_keys=True).encode()
    meta.update({str(k).encode(): str(v).encode() for k, v in flat.items()})
    pq.write_table(arrow.replace_schema_metadata(meta), target)


def cmd(args: argparse.Namespace) -> int:
    from tspend.studies.timeseries import recording_table

    source, target = Path(args.recording), Path(args.to)
    if not source.is_file():
        raise ScenarioError(f"{source}: no such recording")
    if target.suffix.lower() not in FORMATS:
        raise ScenarioError(f"--to {target}: the suffix must be one of {', '.join(FORMATS)}")
    from tspend.runtime.outputs import OutputRequest, plan_outputs

    # the path checked (directory writable, name length) before the recording is read
    plan_outputs([OutputRequest("--to", "table", target.suffix.lower(), str(target))],
                 inputs=[source])
    if os.path.lexists(target):
        raise ScenarioError(f"--to {target}: exists; choose another path (nothing is "
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
        raise ScenarioError(f"--to {target}: cannot create directory {target.parent}: "
                            f"{exc.strerror or exc}") from None
    from tspend.runtime.outputs import write_atomic

    suffix = target.suffix.lower()
    write_atomic(target, lambda tmp: write_table(table, metadata, tmp, suffix), replace=False,
                 what="--to")
    print(f"{target}: {len(table)} samples x {table.shape[1]} columns "
          f"({', '.join(table.columns[:8])}{', ...' if table.shape[1] > 8 else ''})")
    return 0
