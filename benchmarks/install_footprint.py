"""What the README's quick start costs: the size of a fresh environment with tspend
installed from this checkout (``pip install .``, not editable), and the warm start of
``tspend run --duration 0.01 --no-record`` from an empty folder (after one run has
compiled and cached the closed loop), three times.

    python benchmarks/install_footprint.py [--venv DIR]   # DIR: reuse an environment made before

Prints the figures the README quotes (install size, warm start) and the raw timings.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def folder_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file() and not p.is_symlink())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--venv", type=Path, default=None,
                    help="an environment with tspend installed (default: make one in a "
                         "temporary folder with pip install of this checkout)")
    ap.add_argument("--repeat", type=int, default=3, help="warm starts measured (default 3)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        venv = args.venv
        if venv is None:
            venv = Path(tmp) / "venv"
            subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
            t0 = time.perf_counter()
            subprocess.run([str(venv / "bin" / "pip"), "install", "-q", str(ROOT)], check=True)
            print(f"install: {time.perf_counter() - t0:.0f} s")
        size = folder_bytes(venv)
        work = Path(tmp) / "work"
        work.mkdir()
        command = [str(venv / "bin" / "tspend"), "run", "--duration", "0.01", "--no-record"]
        t0 = time.perf_counter()
        subprocess.run(command, cwd=work, check=True, capture_output=True)
        print(f"first run (compiles unless cached): {time.perf_counter() - t0:.1f} s")
        warm = []
        for _ in range(max(1, args.repeat)):
            t0 = time.perf_counter()
            subprocess.run(command, cwd=work, check=True, capture_output=True)
            warm.append(time.perf_counter() - t0)
    print(f"install size: {size / 1e9:.2f} GB ({size} bytes)")
    print(f"warm start: median {sorted(warm)[len(warm) // 2]:.2f} s "
          f"(runs: {', '.join(f'{w:.2f}' for w in warm)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
