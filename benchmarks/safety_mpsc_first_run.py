"""The first filtered run on a fresh cache (docs/safety.md, issue 54's "compiles in under 60 s").

Runs the page's first command, ``tspend run pendulum_finite_rail --controller pd --set
effects.rail=1.0 --safety mpsc``, twice in new processes: first with every cache folder
(numba's, tspend's compiled rollout and QP, matplotlib's, Python's byte code) a new empty
one, then again on the caches the first run filled.  The second run is the baseline
measured in the same session: the difference between the two wall times is what a fresh
cache costs (the rollout's and the QP's C compile, numba's compiles, imports).  Each run's
own ``wall_s`` (the simulated loop alone) is printed beside it.

    python benchmarks/safety_mpsc_first_run.py
    python benchmarks/safety_mpsc_first_run.py --json benchmarks/results/x.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

COMMAND = ("run", "pendulum_finite_rail", "--controller", "pd", "--set", "effects.rail=1.0",
           "--safety", "mpsc", "--no-record")
#: the environment variables that name the cache folders a fresh machine starts without
CACHE_VARIABLES = {"NUMBA_CACHE_DIR": "numba", "TSPEND_CACHE_DIR": "tspend",
                   "XDG_CACHE_HOME": "xdg", "MPLCONFIGDIR": "matplotlib",
                   "PYTHONPYCACHEPREFIX": "pycache"}
TIMEOUT_S = 900


def timed_run(env: dict, metrics: Path) -> dict:
    """One run of COMMAND in a new process; its wall time and its metrics' figures."""
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "tspend.cli", *COMMAND, "--metrics",
                           str(metrics)], env=env, capture_output=True, text=True,
                          timeout=TIMEOUT_S)
    wall_s = time.perf_counter() - start
    if done.returncode != 0:
        sys.exit(f"safety_mpsc_first_run: exit {done.returncode}: {done.stderr.strip()[-400:]}")
    m = json.loads(metrics.read_text())
    return {"process_wall_s": wall_s, "loop_wall_s": m["wall_s"], "status": m["status"],
            "samples_outside": m["violations"],
            "time_per_sample_ms": m["safety_filter"]["time_per_sample_ms"]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description="Time the first mpsc run on empty caches against a second run on the "
                    "caches it filled. Example: python benchmarks/safety_mpsc_first_run.py")
    parser.add_argument("--json", type=Path, default=None,
                        help="also write the figures to this JSON file (not overwritten if "
                             "it exists)")
    args = parser.parse_args(argv)
    if args.json is not None and args.json.exists():
        parser.error(f"--json: {args.json} exists; name a new file")
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, **{var: str(Path(tmp) / sub)
                                  for var, sub in CACHE_VARIABLES.items()})
        load_before = os.getloadavg()[0]
        cold = timed_run(env, Path(tmp) / "cold.json")
        warm = timed_run(env, Path(tmp) / "warm.json")
    result = {"cold": cold, "warm": warm,
              "fresh_cache_cost_s": cold["process_wall_s"] - warm["process_wall_s"],
              "load_average_1min": [load_before, os.getloadavg()[0]],
              "machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.release()}"}
    for name in ("cold", "warm"):
        r = result[name]
        print(f"{name:5s} process {r['process_wall_s']:7.2f} s   loop {r['loop_wall_s']:7.2f} s"
              f"   {r['status']}, {r['samples_outside']} samples outside")
    print(f"fresh cache cost {result['fresh_cache_cost_s']:7.2f} s   load "
          f"{result['load_average_1min'][0]:.2f}-{result['load_average_1min'][1]:.2f}")
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
