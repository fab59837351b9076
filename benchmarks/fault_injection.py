"""Fault injection: a sweep whose workers are killed at random still has every row once.

Two parts, each a sweep of ``--runs`` short closed loops (``ex3_pendulum_ode``, seeds 0 to
N-1, ``--duration`` s each) written to a Parquet table:

- local: ``--jobs`` worker processes; a killer thread sends SIGKILL to a random worker
  every 0.2 to 1.0 s (``--kills`` in all) while the sweep runs;
- dask: a ``LocalCluster`` of ``--jobs`` workers; one worker process is killed with
  SIGKILL mid-sweep (``--dask-kills`` times; its nanny restarts it).  Skipped with a note
  when dask.distributed is not installed.

For each part it prints the kills made, the rows returned, the distinct runs among them,
the runs missing from the table, the rows that appear more than once in the table's file
itself (before any de-duplication on reading), the statuses, and the wall time.

    python benchmarks/fault_injection.py                 # 1000 runs, both parts
    python benchmarks/fault_injection.py --runs 200 --no-dask

Exit status 1 if a row is missing or appears twice, or a run did not complete.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path

import pandas as pd

import tspend
from tspend.sweep import read_table
from tspend.sweep.executors import LocalPool, make_executor
from tspend.sweep.table import KEY_COLUMN
from short_mode import short_defaults


class Killer(threading.Thread):
    """Sends SIGKILL to one of ``pids()`` every ``low`` to ``high`` seconds, ``limit`` times."""

    def __init__(self, pids, limit: int, low: float, high: float, first_after: float = 0.0,
                 seed: int = 0) -> None:
        super().__init__(daemon=True)
        self.pids, self.limit, self.low, self.high = pids, limit, low, high
        self.first_after = first_after
        self.rng = random.Random(seed)
        self.kills = 0
        self.finished = threading.Event()

    def run(self) -> None:
        if self.finished.wait(self.first_after):
            return
        while self.kills < self.limit and not self.finished.wait(
                self.rng.uniform(self.low, self.high)):
            try:
                candidates = sorted(self.pids())
            except Exception:  # noqa: BLE001 - the pool is being replaced: try later
                continue
            if not candidates:
                continue
            try:
                os.kill(self.rng.choice(candidates), signal.SIGKILL)
                self.kills += 1
            except ProcessLookupError:
                pass


def check(name: str, table_path: Path, frame: pd.DataFrame, runs: int, kills: int,
          wall_s: float) -> bool:
    raw = pd.read_parquet(table_path)  # the file itself, not read_table's de-duplicated view
    repeated = int((raw[KEY_COLUMN].value_counts() > 1).sum())
    table = read_table(table_path)
    seeds = set(table["seed"])
    missing = runs - len(seeds & set(range(runs)))
    statuses = frame["status"].value_counts().to_dict()
    ok = (len(frame) == runs and frame[KEY_COLUMN].is_unique and repeated == 0
          and missing == 0 and statuses.get("completed", 0) == runs)
    print(f"{name:<6} kills {kills:>3}   rows {len(frame):>5}   distinct {frame[KEY_COLUMN].nunique():>5}"
          f"   missing {missing}   repeated in the file {repeated}   statuses {statuses}"
          f"   wall {wall_s:.1f} s   {'OK' if ok else 'FAILED'}")
    for message in frame.loc[frame["status"] != "completed", "message"].head(3):
        print(f"       not completed: {message[:200]}")
    return ok


def local_part(args, scn, base: Path) -> bool:
    out = base / "local.parquet"
    pool = LocalPool(args.jobs)

    def pids():
        inner = pool._pool  # the ProcessPoolExecutor of the moment (replaced after a death)
        return [p.pid for p in list(getattr(inner, "_processes", {}).values()) if p.is_alive()]

    killer = Killer(pids, args.kills, 0.2, 1.0, first_after=0.5, seed=args.seed)
    started = time.perf_counter()
    killer.start()
    try:
        frame = tspend.sweep(scn, seeds=range(args.runs), out=out, executor=pool)
    finally:
        killer.finished.set()
        pool.close()
    return check("local", out, frame, args.runs, killer.kills, time.perf_counter() - started)


def dask_part(args, scn, base: Path) -> bool:
    try:
        import distributed  # noqa: F401
    except ImportError:
        print("dask   skipped: dask.distributed is not installed (pip install 'tspend[dask]')")
        return True
    import logging

    # the scheduler logs every lost worker and rescheduled task: the counts below say it
    logging.getLogger("distributed").setLevel(logging.CRITICAL)
    out = base / "dask.parquet"
    executor = make_executor(args.jobs, "local")

    def pids():
        return list(executor.client.run(os.getpid, wait=True).values())

    killer = Killer(pids, args.dask_kills, 1.0, 3.0, first_after=1.0, seed=args.seed)
    started = time.perf_counter()
    killer.start()
    try:
        frame = tspend.sweep(scn, seeds=range(args.runs), out=out, executor=executor)
    finally:
        killer.finished.set()
        executor.close()
    return check("dask", out, frame, args.runs, killer.kills, time.perf_counter() - started)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--duration", type=float, default=0.2, help="seconds of each run")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--kills", type=int, default=20, help="local workers killed")
    ap.add_argument("--dask-kills", type=int, default=2, help="Dask workers killed")
    ap.add_argument("--no-dask", action="store_true")
    ap.add_argument("--seed", type=int, default=0, help="seed of the killer's choices")
    short_defaults(ap, runs=60, kills=2, dask_kills=1)
    args = ap.parse_args()
    scn = tspend.override(tspend.load_scenario("ex3_pendulum_ode"),
                          **{"run.duration": args.duration})
    with tempfile.TemporaryDirectory(prefix="tspend-faults-") as tmp:
        ok = local_part(args, scn, Path(tmp))
        if not args.no_dask:
            ok = dask_part(args, scn, Path(tmp)) and ok
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
