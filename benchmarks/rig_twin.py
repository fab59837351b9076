"""Sim against rig, and the rig's clock (docs/rig.md): LQR on pendulum_mujoco through the UDP
double (``tspend rig serve``), each run with ``--twin``, on

- the exact double (the scenario's own machine) and one whose pole is 20 % heavier
  (``--set plant.m=1.2``): the twin's gap per state and for u (the metrics' ``twin_gap``);
- doubles whose clock runs off the host's by ``--clock-ppm`` (a crystal's 50 ppm slow, and
  300 ppm fast): the drift the runner measured (the timing block's ``clock``), the
  re-alignments, and the stale cycles beside those of the exact double in the same run.

    python benchmarks/rig_twin.py                           # 20 s per run (about 4 minutes)
    python benchmarks/rig_twin.py --duration 4 --json x.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

TIMEOUT_S = 600
#: (name, the double's options)
DOUBLES = (("exact", ()), ("pole +20 %", ("--set", "plant.m=1.2")),
           ("clock -50 ppm", ("--clock-ppm", "-50")), ("clock +300 ppm", ("--clock-ppm", "300")))


def _tspend(*args: str, cwd: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "tspend.cli", *args], cwd=cwd,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def twin_run(options: tuple[str, ...], duration_s: float, work: Path) -> dict:
    """One LQR run with --twin on a double with ``options``; its metrics."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        url = f"udp://127.0.0.1:{s.getsockname()[1]}"
    double = _tspend("rig", "serve", "pendulum_mujoco", "--listen", url, "--wait-s",
                     str(TIMEOUT_S), *options, cwd=work)
    double.stdout.readline()  # listening
    metrics = work / "m.json"
    metrics.unlink(missing_ok=True)
    runner = _tspend("run", "pendulum_mujoco", "--controller", "lqr", "--rig", url, "--twin",
                     "--duration", str(duration_s), "--metrics", str(metrics), "--no-record",
                     cwd=work)
    _, err = runner.communicate(timeout=TIMEOUT_S)
    double.communicate(timeout=TIMEOUT_S)
    if runner.returncode != 0:
        raise SystemExit(f"{options}: exit {runner.returncode}: {err.strip()}")
    return json.loads(metrics.read_text())


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=20.0, help="seconds per run (default 20)")
    p.add_argument("--json", type=Path, help="also write the rows as JSON here")
    args = p.parse_args()
    if not 0.5 <= args.duration <= 120:
        raise SystemExit("--duration: 0.5 to 120 s")
    rows = []
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores; kernel {platform.release()}; "
          f"load average {os.getloadavg()[0]:.2f} at the start; {args.duration:g} s per run")
    print(f"{'double':15} | {'hinge rms/max mrad':>19} {'slider rms/max mm':>18} "
          f"{'u rms N':>8} | {'gain us/s':>9} {'realigned':>9} {'stale':>7} {'load':>5}")
    with tempfile.TemporaryDirectory() as tmp:
        for name, options in DOUBLES:
            m = twin_run(options, args.duration, Path(tmp))
            gap, timing = m["twin_gap"], m["timing"]
            row = {"double": name, "options": list(options), "twin_gap": gap, "timing": timing,
                   "load": os.getloadavg()[0]}
            rows.append(row)
            h, s, clock = gap["states"]["hinge"], gap["states"]["slider"], timing["clock"]
            print(f"{name:15} | {h['rms'] * 1e3:9.3f}/{h['max_abs'] * 1e3:<9.3f} "
                  f"{s['rms'] * 1e3:8.3f}/{s['max_abs'] * 1e3:<9.3f} {gap['u']['rms']:8.2f} | "
                  f"{clock['rig_gain_us_per_s']:9.1f} {clock['realigned']:9d} "
                  f"{timing['frames']['stale_cycles']:7d} {row['load']:5.2f}", flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps({"uname": list(platform.uname()), "duration_s":
                                         args.duration, "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
