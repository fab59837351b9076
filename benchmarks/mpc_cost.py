"""What one MPC sample costs: IPOPT's solve against the full-state LQR's step, same states.

    python benchmarks/mpc_cost.py [--samples 100] [--horizon 30]

Runs ``pendulum_mujoco`` under ``mpc`` for ``samples`` control periods (20 ms each), then
times the LQR's step on the very observations the MPC saw.  Prints the median and max
solve (ms), IPOPT's iterations, and the ratio median(MPC) / median(LQR) measured in the
same process.  MPC is excepted from the compiled loops: its cost is the solver's.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tspend import load_scenario, override, run  # noqa: E402
from tspend.controllers import build  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=int, default=100)
    ap.add_argument("--horizon", type=int, default=30)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    s = override(load_scenario("pendulum_mujoco"),
                 **{"run.duration": 0.02 * args.samples, "controllers.mpc.horizon": args.horizon})
    r = run(s, controller="mpc")
    h = r.history
    held = np.arange(0, h["t"].size, 20)
    solve_ms = h["solve_ms"][held]
    lqr = build(s, "lqr")
    ref = s.reference.derivatives(h["t"][held], 2)
    lqr_s = []
    for k, i in enumerate(held):
        t0 = time.perf_counter()
        lqr.act(h["state"][i], ref[k])
        lqr_s.append(time.perf_counter() - t0)
    lqr_ms = 1e3 * np.median(lqr_s)
    print(f"mpc horizon {args.horizon}: solve median {np.median(solve_ms):.2f} ms, max "
          f"{solve_ms.max():.2f} ms, iterations median {np.median(h['iterations'][held]):.0f}; "
          f"lqr step median {lqr_ms * 1e3:.1f} us; ratio {np.median(solve_ms) / lqr_ms:.0f}x; "
          f"failures {r.metrics['counters']['solve_failures']:.0f}, overruns "
          f"{r.metrics['counters']['solve_overruns']:.0f} of {held.size}")


if __name__ == "__main__":
    main()
