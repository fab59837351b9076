"""``mpc`` with and without the task's constraints in its OCP, paired over seeds.

    python benchmarks/mpc_constraints.py [--seeds 10] [--box 0.6] [--duration 3]

On ``pendulum_mujoco_randomized`` (masses, pole length and x0 drawn per seed) with a soft
box on the cart ``slider = {lo = -box, hi = box}``, each seed runs ``mpc`` (the default
scheme and solver) with ``controllers.mpc.constraints`` false and true.  Prints per seed
the status, the box's samples outside and largest depth, the failed solves; then over
seeds the median and range of samples outside, and exact McNemar tests (two-sided
binomial on the discordant pairs) for "left the box" and "ended early".
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tspend import load_scenario, override, run  # noqa: E402


def mcnemar(a: np.ndarray, b: np.ndarray) -> float:
    """Exact two-sided McNemar p of paired booleans ``a``, ``b``."""
    from scipy.stats import binomtest

    n01, n10 = int(np.sum(~a & b)), int(np.sum(a & ~b))
    return 1.0 if n01 + n10 == 0 else float(binomtest(n01, n01 + n10, 0.5).pvalue)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--box", type=float, default=0.6, help="the box's half-width (m)")
    ap.add_argument("--duration", type=float, default=3.0)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    box = {"task.constraints.box.slider": {"lo": -args.box, "hi": args.box}}
    print(f"# mpc_constraints: pendulum_mujoco_randomized, {args.duration:g} s, soft box "
          f"slider +/-{args.box:g} m, mpc default (rti, auto), seeds 0-{args.seeds - 1}")
    outside = {False: [], True: []}
    ended = {False: [], True: []}
    for seed in range(args.seeds):
        line = []
        for on in (False, True):
            s = override(load_scenario("pendulum_mujoco_randomized"),
                         **{"run.duration": args.duration, "run.seed": seed,
                            "controllers.mpc.constraints": on, **box})
            r = run(s, controller="mpc", keep_history=False)
            c = r.metrics["constraints"]["slider"]
            outside[on].append(c["samples_outside"])
            ended[on].append(r.status != "completed")
            line.append(f"{'with' if on else 'without'}: {r.status} outside "
                        f"{c['samples_outside']} depth {c['max_depth']:.4f} failures "
                        f"{r.metrics['counters']['solve_failures']:.0f}")
        print(f"seed {seed}: " + "; ".join(line), flush=True)
    for on in (False, True):
        o = np.asarray(outside[on])
        print(f"{'with' if on else 'without'}: samples outside median {np.median(o):g} "
              f"[{o.min()}, {o.max()}], left the box {int(np.sum(o > 0))}/{o.size}, ended "
              f"early {int(np.sum(ended[on]))}/{o.size}")
    left = [np.asarray(outside[on]) > 0 for on in (False, True)]
    early = [np.asarray(ended[on]) for on in (False, True)]
    print(f"McNemar exact p: left the box {mcnemar(*left):.3g}, ended early "
          f"{mcnemar(*early):.3g}")


if __name__ == "__main__":
    main()
