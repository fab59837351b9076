"""The MJX vector env's host time per step at two batch sizes, in one run.

    python benchmarks/mjx_env_host.py                 # 64 and 4096 envs, 50 steps each

Prints, per N, env-steps/s and the host's milliseconds per step (the median step's wall
time less its device call, waited for: :func:`accelerator_speed.env_host`), and the ratio
of the larger N's to the smaller's, both measured in this run: what the host does per step
should not grow with N (docs/accelerator.md).
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from accelerator_speed import env_host  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="the MJX vector env's host time per step at two "
                                            "batch sizes (docs/accelerator.md)")
    p.add_argument("--envs", default="64,4096", help="two batch sizes (default 64,4096)")
    p.add_argument("--steps", type=int, default=50,
                   help="steps timed per size, their median reported (default 50)")
    p.add_argument("--scenario", default="pendulum_mujoco", help="(default pendulum_mujoco)")
    args = p.parse_args(argv)
    try:
        small, large = (int(v) for v in args.envs.split(","))
    except ValueError:
        raise SystemExit(f"mjx_env_host: --envs {args.envs!r}: two integers, e.g. 64,4096")
    if not (1 <= small <= 1 << 20 and 1 <= large <= 1 << 20 and 1 <= args.steps <= 1000):
        raise SystemExit("mjx_env_host: --envs each from 1 to 1048576, --steps from 1 to 1000")
    host = {}
    for n in (small, large):
        rate, host[n] = env_host(args.scenario, n, args.steps, "float64")
        print(f"{args.scenario} N {n} env-steps/s {rate:.3g} host ms/step {host[n]:.3g}",
              flush=True)
    print(f"host time per step at {large} over {small}: {host[large] / host[small]:.2f} "
          f"(baseline: {host[small]:.3g} ms at {small} envs, same run)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
