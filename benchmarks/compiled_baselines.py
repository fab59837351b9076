"""The baselines in the compiled loops: wall per 20 s run against the paper's controller,
and the tuning throughput (issue 22).

Prints, measured in one process and one run of this script:

* per kind, the median wall time of one 20 s run of ``--scenario`` (``tspend.run``, no
  history kept: what a sweep row's ``wall_s`` measures plus building the run) and its
  ratio to ``second_type``'s median measured in the same rounds (target <= 1.5).  Each
  round runs every kind once, in turn, so contention hits all kinds alike; each kind is
  run once first (numba's cache loaded, nothing timed);
* the loop each kind took (``compiled`` or ``generic``);
* throughput: ``--throughput-runs`` (default 2,000) 20 s runs of each of
  ``--throughput-kinds`` as one sweep on a pool of ``--workers`` (default 2) processes,
  started and warmed before the clock starts; total seconds (target < 180 s) and runs/s.

Run: ``python benchmarks/compiled_baselines.py``; quote three runs (docs/benchmarks.md).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

from tspend import load_scenario, override, run, sweep
from tspend.loop.simulation import prepare
from tspend.sweep.executors import LocalPool
from short_mode import short_defaults

KINDS = ("second_type", "pd", "lqr", "sliding_mode", "feedback_linearization", "wang_indirect")


def wall_of(scenario, kind: str) -> float:
    t = time.perf_counter()
    result = run(scenario, controller=kind, keep_history=False)
    elapsed = time.perf_counter() - t
    assert result.status == "completed", (kind, result.status)
    return elapsed


def loop_path(scenario, kind: str) -> str:
    """Which loop a run of ``kind`` takes (compiled or generic)."""
    from tspend.loop.runner import ClosedLoop

    taken = []
    real = ClosedLoop._loop

    def spy(self, sinks):
        try:
            return real(self, sinks)
        finally:
            taken.append(self.path)

    ClosedLoop._loop = spy
    try:
        run(override(scenario, **{"run.duration": 0.01}), controller=kind, keep_history=False)
    finally:
        ClosedLoop._loop = real
    return taken[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="ex3_pendulum_ode")
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--rounds", type=int, default=7, help="timed runs per kind (median)")
    ap.add_argument("--throughput-kinds", default="pd,wang_indirect")
    ap.add_argument("--throughput-runs", type=int, default=2000)
    ap.add_argument("--workers", type=int, default=2)
    short_defaults(ap, rounds=1, throughput_runs=10)
    args = ap.parse_args()
    scenario = override(load_scenario(args.scenario), **{"run.duration": 20.0})
    kinds = args.kinds.split(",")
    if "second_type" not in kinds:
        kinds.insert(0, "second_type")

    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at start")
    paths = {k: loop_path(scenario, k) for k in kinds}
    for k in kinds:
        prepare(scenario, controller=k)
        wall_of(scenario, k)   # numba's cache loaded, the kernels warm
    walls: dict[str, list[float]] = {k: [] for k in kinds}
    for _ in range(args.rounds):
        for k in kinds:
            walls[k].append(wall_of(scenario, k))
    base = statistics.median(walls["second_type"])
    print(f"\nwall per 20 s run of {args.scenario} (median of {args.rounds}, same rounds):")
    print(f"{'kind':<24} {'loop':<9} {'median s':>9} {'min s':>8} {'/ second_type':>14}")
    for k in kinds:
        med = statistics.median(walls[k])
        print(f"{k:<24} {paths[k]:<9} {med:9.4f} {min(walls[k]):8.4f} {med / base:14.2f}")
    baselines = [k for k in kinds if k != "second_type"]
    if baselines:
        worst = max(baselines, key=lambda k: statistics.median(walls[k]))
        print(f"slowest baseline: {worst}, {statistics.median(walls[worst]) / base:.2f}x "
              f"second_type (target <= 1.5)")

    if args.throughput_runs <= 0:
        return
    print(f"\nthroughput: {args.throughput_runs} runs of 20 s on {args.scenario}, "
          f"{args.workers} workers (pool started and warmed before the clock):")
    with LocalPool(args.workers) as pool:
        for k in args.throughput_kinds.split(","):
            sweep(scenario, seeds=range(args.workers), controllers=k, executor=pool)  # warm
            t = time.perf_counter()
            table = sweep(scenario, seeds=range(args.throughput_runs), controllers=k,
                          executor=pool)
            elapsed = time.perf_counter() - t
            ok = int((table["status"] == "completed").sum())
            print(f"{k:<24} {elapsed:7.1f} s  ({args.throughput_runs / elapsed:6.1f} runs/s, "
                  f"{ok}/{len(table)} completed; target < 180 s)")
    print(f"load average {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()
