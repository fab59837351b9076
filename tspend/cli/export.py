"""``tspend export FILE.rrd --to PATH.parquet|PATH.csv``: a recording's time series as a
table, one column per series, indexed by ``t`` (see :mod:`tspend.studies.timeseries`)."""

from __future__ import annotations

import argparse
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
    if target.exists():
        raise ScenarioError(f"--to {target}: exists; choose another path (nothing is "
                            f"overwritten)")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ScenarioError(f"--to {target}: cannot create directory {target.parent}: "
                            f"{exc.strerror or exc}") from None
    try:
        table = recording_frame(source)
    except (ValueError, OSError) as exc:
        raise ScenarioError(f"{source}: {exc}") from None
    tmp = target.with_name(f".{target.name}.tmp")
    if target.suffix.lower() == ".csv":
        table.to_csv(tmp)  # floats as the shortest text that reads back exactly
    else:
        table.to_parquet(tmp)
    tmp.replace(target)
    print(f"{target}: {len(table)} samples x {table.shape[1]} series "
          f"({', '.join(table.columns[:8])}{', ...' if table.shape[1] > 8 else ''})")
    return 0
