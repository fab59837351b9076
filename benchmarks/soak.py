"""Soak run: a long MuJoCo pendulum run with recording; memory and parameters over time.

Prints, every ``--every`` simulated seconds, the resident memory of the process and the
norms of the adapted parameters, then the peak memory.  Used for issue 4 (memory flat:
a 600 s run within 1.5x of a 20 s one) and issue 6 (parameters bounded over 600 s):

    python benchmarks/soak.py --duration 20
    python benchmarks/soak.py --duration 600
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
from pathlib import Path

import numpy as np

from tspend import load_scenario, override, run
from tspend.recorder import RerunSink, close_recording, open_recording
from short_mode import short_defaults


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[1])
    return pages * resource.getpagesize() / 2**20


class Probe:
    """A sink that samples memory and parameter norms as blocks arrive."""

    wants_inner = False

    def __init__(self, every: float) -> None:
        self.every, self.next_t, self.rows = every, 0.0, []
        self.peak_norm_P = self.peak_norm_q = self.peak_abs_e_late = 0.0

    def start(self, info):
        self.duration = info.duration

    def block(self, block):
        d = block.data
        self.peak_norm_P = max(self.peak_norm_P, float(d["norm_P"].max()))
        self.peak_norm_q = max(self.peak_norm_q, float(d["norm_q"].max()))
        late = d["t"] >= 0.5 * self.duration
        if late.any():
            self.peak_abs_e_late = max(self.peak_abs_e_late, float(np.abs(d["e"][late, 0]).max()))
        t_end = float(d["t"][-1])
        if t_end + 1e-9 >= self.next_t:
            self.rows.append((t_end, rss_mb(), float(d["norm_P"][-1]), float(d["norm_q"][-1]),
                              float(d["min_b"][-1]), float(d["d_hat"][-1])))
            self.next_t += self.every

    def inner(self, snap):
        pass

    def finish(self, end):
        pass


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--every", type=float, default=60.0)
    ap.add_argument("--scenario", default="pendulum_mujoco")
    short_defaults(ap, duration=20.0, every=5.0)
    args = ap.parse_args()
    scn = override(load_scenario(args.scenario), **{"run.duration": args.duration})
    probe = Probe(args.every)
    with tempfile.TemporaryDirectory() as d:
        rrd = Path(d) / "soak.rrd"
        rec = open_recording("tspend_soak", path=rrd)
        t0 = time.perf_counter()
        result = run(scn, sinks=[RerunSink(rec), probe], keep_history=False)
        close_recording(rec)
        wall = time.perf_counter() - t0
        size = rrd.stat().st_size
    print(f"{args.scenario}: {args.duration:g} s simulated in {wall:.1f} s wall, "
          f"status {result.status}, .rrd {size / 1e6:.1f} MB")
    print(f"{'t (s)':>8} {'RSS (MB)':>9} {'|P|':>10} {'|q|':>10} {'min b':>10} {'d_hat':>10}")
    for row in probe.rows:
        print(f"{row[0]:8.1f} {row[1]:9.1f} {row[2]:10.4g} {row[3]:10.4g} {row[4]:10.4g} "
              f"{row[5]:10.4g}")
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak RSS {peak:.1f} MB; max |P| {probe.peak_norm_P:.4g}, max |q| "
          f"{probe.peak_norm_q:.4g}; rmse_ss {result.metrics['rmse_ss']:.3g}, "
          f"max |e1| over the last half {probe.peak_abs_e_late:.3g}")


if __name__ == "__main__":
    main()
