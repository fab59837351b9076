"""What one certificate rollout of ``--safety mpsc`` costs, called back to back and paced.

    python benchmarks/mpsc_rollout_cost.py                # 2000 calls each way
    python benchmarks/mpsc_rollout_cost.py --pause-ms 0.7 --calls 1000

The filter of the randomised cart-pole on a 1 m rail (seed 1, pd inside: 17 models, the
plan the saturated LQR's tail from the upright) rolls the same plan out ``--calls`` times
in a row, then ``--calls`` times with a sleep of ``--pause-ms`` before each call, as a
loop paced at 1 kHz leaves the filter between samples.  Each call's time is this thread's
CPU time (``time.thread_time``), so a wait for a core is not in it.  Prints the median,
95th and 99th percentiles and the largest of each way, and the paced median over the
back-to-back median (the baseline, measured in the same run), with the load average
before and after.  The filter's budget per sample (0.8 ms at 1 kHz) is printed beside:
what is left of it after a rollout is what the estimate of (P9) must fit in.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from short_mode import short_defaults  # noqa: E402


def cart_pole_filter(seed: int):
    """The mpsc filter (pd inside) of benchmarks/safety_filter.py's randomised cart-pole."""
    from safety_filter import MACHINES
    from tspend import load_scenario, override
    from tspend.loop.simulation import prepare

    name, changes = MACHINES["cartpole_rail"]
    scn = override(load_scenario(name), **changes,
                   **{"safety.filter": "mpsc", "run.seed": seed})
    return prepare(scn, controller="pd").controller


def rollout_times(f, calls: int, pause_s: float) -> np.ndarray:
    """CPU ms of ``calls`` rollouts of the LQR's tail from the upright, a sleep of
    ``pause_s`` before each (none: 0)."""
    s = np.zeros(f.cert.model.size)
    U, R = f.lqr_tail(s)
    out = np.empty(calls)
    for i in range(calls):
        if pause_s:
            time.sleep(pause_s)
        c = time.thread_time()
        f.roll.run(s, U, R)
        out[i] = time.thread_time() - c
    return 1e3 * out


def line(label: str, ms: np.ndarray) -> str:
    p50, p95, p99 = np.percentile(ms, [50, 95, 99])
    return (f"{label}: median {p50:.3f} ms, p95 {p95:.3f}, p99 {p99:.3f}, "
            f"max {ms.max():.3f} ({ms.size} calls)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="the cost of one mpsc certificate rollout, "
                                             "back to back and paced (docs/safety.md)")
    ap.add_argument("--calls", type=int, default=2000,
                    help="rollouts each way, 10 to 100000 (default 2000)")
    ap.add_argument("--pause-ms", type=float, default=0.7,
                    help="sleep before each paced call, 0.01 to 100 ms (default 0.7: a 1 kHz "
                         "loop's time between the filter's samples)")
    ap.add_argument("--seed", type=int, default=1, help="the machine drawn (default 1)")
    short_defaults(ap, calls=20)
    args = ap.parse_args(argv)
    if not (10 <= args.calls <= 100_000 and 0.01 <= args.pause_ms <= 100.0
            and 0 <= args.seed <= 10 ** 6):
        print("mpsc_rollout_cost: --calls 10..100000, --pause-ms 0.01..100, --seed "
              "0..1000000", file=sys.stderr)
        return 2
    warnings.simplefilter("ignore")
    print(f"load average (1 min) before: {os.getloadavg()[0]:.2f}", flush=True)
    f = cart_pole_filter(args.seed)
    print(f"models {f.roll.models}, plan intervals {f.cert.N}, RK4 steps per interval "
          f"{f.cert.substeps}, budget per sample {1e3 * f.cert.budget_s:.2f} ms")
    rollout_times(f, 10, 0.0)                          # the first calls load the code
    back = rollout_times(f, args.calls, 0.0)
    paced = rollout_times(f, args.calls, 1e-3 * args.pause_ms)
    print(line("back to back", back))
    print(line(f"paced ({args.pause_ms:g} ms sleep before each)", paced))
    print(f"paced median over back-to-back median: {np.median(paced) / np.median(back):.2f}")
    print(f"load average (1 min) after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
