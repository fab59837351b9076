"""``tspend export FILE.rrd --to PATH.parquet|PATH.csv``: a recording's time series as a
table, one column per series, indexed by ``t`` (see :mod:`tspend.studies.timeseries`)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from tspend.errors import ScenarioError

FORMATS = (".parquet", ".csv")


def add_parser(sub) -> None:
    p = sub.add_parser("export", help="write a recording's time series as Parquet or CSV",
                       description="Write every scalar series of a recording as one table "
                                   "indexed by time t, one column per series.")
    p.add_argument("recording", metavar="FILE.rrd", help="a recording made by tspend")
    p.add_argument("--to", required=True, metavar="PATH.parquet|PATH.csv",
                   help="the table to write (the suffix picks the format; never overwritten)")
    p.add_argument("--debug", action="store_true", help="show tracebacks")


def cmd(args: argparse.Namespace) -> int:
    from tspend.studies.timeseries import recording_frame

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
        table = recording_frame(source)
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

    if target.suffix.lower() == ".csv":
        # floats as the shortest text that reads back exactly
        write_atomic(target, table.to_csv, replace=False, what="--to")
    else:
        write_atomic(target, table.to_parquet, replace=False, what="--to")
    print(f"{target}: {len(table)} samples x {table.shape[1]} series "
          f"({', '.join(table.columns[:8])}{', ...' if table.shape[1] > 8 else ''})")
    return 0
