"""Sweep throughput and per-run overhead, measured in one process (issue 13).

Prints, each against a baseline measured in the same run:

* throughput: runs per second of a sweep with ``W`` worker processes against the same
  sweep with one worker (target >= 0.85 W).  Both pools are started and warmed (kernel
  loaded) before the clock starts, so this is the steady rate a long sweep sees; the
  pool's start-up is printed separately;
* per-run overhead: what the sweep adds to a run (planning and validating its grid
  point, sending the job, building the result row, writing it to the journal, folding
  the journal into Parquet), as a fraction of one 20 s pendulum run made directly with
  ``tspend.run`` (target < 5%).  Measured as the time per run of a one-worker sweep of
  one-sample runs, minus the time of the same one-sample run made directly.

Each figure is the median of ``--repeat`` measurements.  Run:
``python benchmarks/sweep_throughput.py`` (``--workers`` defaults to the core count).
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

from tspend import load_scenario, override, run, sweep
from tspend.sweep.executors import LocalPool, default_jobs
from short_mode import short_defaults


def direct_run_s(scn) -> float:
    t = time.perf_counter()
    run(scn, keep_history=False)
    return time.perf_counter() - t


def sweep_s(scn, seeds: int, pool, out: Path | None) -> float:
    t = time.perf_counter()
    table = sweep(scn, seeds=range(seeds), executor=pool, out=out)
    elapsed = time.perf_counter() - t
    assert len(table) == seeds and (table["status"] == "completed").all()
    return elapsed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="ex3_pendulum_ode")
    ap.add_argument("--workers", type=int, default=default_jobs())
    ap.add_argument("--runs", type=int, default=0,
                    help="runs per throughput sweep (default: 4 per worker)")
    ap.add_argument("--duration", type=float, default=5.0,
                    help="simulated seconds per run of the throughput sweeps (default 5)")
    ap.add_argument("--overhead-runs", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=3)
    short_defaults(ap, runs=4, duration=0.5, overhead_runs=10, repeat=1)
    args = ap.parse_args()
    W = args.workers
    runs = args.runs or 4 * W
    base = load_scenario(args.scenario)
    long_run = override(base, **{"run.duration": 20.0})
    one_step = override(base, **{"run.duration": base.run.dt})
    per_run = override(base, **{"run.duration": args.duration})

    run(one_step, keep_history=False)  # load the kernel in this process too
    t20 = statistics.median(direct_run_s(long_run) for _ in range(args.repeat))
    t1 = statistics.median(direct_run_s(one_step) for _ in range(10 * args.repeat))

    t = time.perf_counter()
    one = LocalPool(1)
    start_one = time.perf_counter() - t
    t = time.perf_counter()
    many = LocalPool(W)
    start_many = time.perf_counter() - t
    with one, many, tempfile.TemporaryDirectory() as tmp:
        overheads = []
        for i in range(args.repeat):
            out = Path(tmp) / f"overhead{i}.parquet"
            overheads.append(sweep_s(one_step, args.overhead_runs, one, out)
                             / args.overhead_runs - t1)
        overhead = statistics.median(overheads)
        rate1, rateW = [], []
        for i in range(args.repeat):
            rate1.append(runs / sweep_s(per_run, runs, one, Path(tmp) / f"one{i}.parquet"))
            rateW.append(runs / sweep_s(per_run, runs, many, Path(tmp) / f"many{i}.parquet"))
    r1, rW = statistics.median(rate1), statistics.median(rateW)

    print(f"scenario {args.scenario}; {W} workers; medians of {args.repeat}")
    print(f"  20 s run made directly                 {t20:8.3f} s")
    print(f"  pool start-up (kernel loaded): 1 worker {start_one:.2f} s, {W} workers "
          f"{start_many:.2f} s (once per sweep, or once per session with executor=)")
    print(f"  throughput, {runs} runs of {args.duration:g} s: 1 worker {r1:.2f} runs/s, "
          f"{W} workers {rW:.2f} runs/s")
    print(f"  throughput ratio {W} workers / 1 worker    {rW / r1:6.2f}x   (target >= "
          f"{0.85 * W:.2f}x = 0.85 W)")
    print(f"  per-run overhead of the sweep          {overhead * 1e3:8.2f} ms "
          f"(one-sample run through the sweep {overhead * 1e3 + t1 * 1e3:.2f} ms, "
          f"directly {t1 * 1e3:.2f} ms)")
    print(f"  overhead / 20 s run                    {overhead / t20:8.2%}   (target < 5%)")
    load = os.getloadavg()[0]
    if load > 0.5 * default_jobs():
        # the workers then compete with every other program for the cores: the ratio
        # measures the machine's load more than the sweep
        print(f"  warning: load average {load:.1f} on {default_jobs()} cores; measure the "
              f"throughput ratio on a quiet machine")


if __name__ == "__main__":
    main()
