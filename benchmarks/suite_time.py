"""The test suite's wall time, the figure README.md states: the README's test command
(``python -m pytest -q``: every core, up to 4) run from cold caches as ``.ci/run`` runs it
(new empty NUMBA_CACHE_DIR, TSPEND_CACHE_DIR, XDG_CACHE_HOME, MPLCONFIGDIR and
PYTHONPYCACHEPREFIX), with the cores and the load average before and after: on a shared
machine the figure is only as good as the load it was measured under, so both are kept.

    python benchmarks/suite_time.py      # about 10-40 minutes; writes benchmarks/results/suite_time.json

The result: wall seconds, pytest's last line (passed, failed, skipped), the exit status.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "suite_time.json"
#: the cache folders .ci/run empties (tests/test_readme.py checks it names every one)
CACHES = ("NUMBA_CACHE_DIR", "TSPEND_CACHE_DIR", "XDG_CACHE_HOME", "MPLCONFIGDIR",
          "PYTHONPYCACHEPREFIX")


def main() -> int:
    with tempfile.TemporaryDirectory(prefix="tspend-cold-") as cold:
        env = {**os.environ, **{name: str(Path(cold) / name.lower()) for name in CACHES}}
        load_before = os.getloadavg()
        started = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "pytest", "-q"], cwd=ROOT, env=env,
                              capture_output=True, text=True)
        wall = time.perf_counter() - started
        load_after = os.getloadavg()
    last = (done.stdout.strip().splitlines() or [""])[-1]
    result = {"wall_s": round(wall, 1), "cores": os.cpu_count(), "returncode": done.returncode,
              "summary": last, "load_before": [round(x, 2) for x in load_before],
              "load_after": [round(x, 2) for x in load_after], "cold_caches": list(CACHES)}
    OUT.write_text(json.dumps(result, indent=2) + "\n")
    print(f"suite: {wall / 60:.1f} min wall on {os.cpu_count()} cores from cold caches, load "
          f"{load_before[0]:.1f} before and {load_after[0]:.1f} after: {last}")
    if done.returncode:
        print(done.stdout[-4000:])
    return done.returncode


if __name__ == "__main__":
    sys.exit(main())
