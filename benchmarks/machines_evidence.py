"""The figures of docs/machines.md (and docs/furuta.md's cross-check): the cross-check of every articulated machine (derived
equations against MuJoCo) and lqr balancing each one, as the page's commands run them.

    python benchmarks/machines_evidence.py [--out benchmarks/results/machines_evidence.json]

For each machine of the page's tables it runs ``tspend crosscheck <scenario> --metrics``
(gymnasium's inverted_double_pendulum.xml through double_cartpole_mujoco with
``--set plant.model=... --set plant.timestep=0.001``, as the page says) and
``tspend run <scenario> --metrics`` (lqr, the scenario's controller), each in a process of
its own in a scratch folder, and writes every command's metrics to one JSON, keyed by
machine: ``crosscheck`` (the cross-check's metrics) and ``run`` (the run's status and
metrics). tools/check_claims.py checks the page's figures against it. A command that fails
stops the script with its message; nothing is written then. Under ``TSPEND_BENCH_SHORT=1``
(tools/check_docs.py) it runs the first machine only and writes into the working folder.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cli_metrics import metrics_of as tspend  # noqa: E402
from short_mode import out_path, short, short_defaults  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: machine -> (scenario, extra options), in the page's order
MACHINES = {
    "double_cartpole": ("double_cartpole_mujoco", []),
    "triple_cartpole": ("triple_cartpole_mujoco", []),
    "acrobot": ("acrobot_mujoco", []),
    "pendubot": ("pendubot_mujoco", []),
    "reaction_wheel": ("reaction_wheel_mujoco", []),
    "rotary_double": ("rotary_double_mujoco", []),
    "gymnasium_inverted_double_pendulum": ("double_cartpole_mujoco", ["GYMNASIUM"]),
    # the single-pole machines, through the same derivation (docs/machines.md, docs/furuta.md)
    "cartpole": ("pendulum_mujoco", []),
    "furuta": ("furuta_mujoco", []),
}
#: what the lqr table runs (gymnasium's model: the cross-check only)
RUNS = ("double_cartpole", "triple_cartpole", "acrobot", "pendubot", "reaction_wheel",
        "rotary_double")


def gymnasium_model() -> str:
    import gymnasium

    path = Path(gymnasium.__file__).parent / "envs" / "mujoco" / "assets" / "inverted_double_pendulum.xml"
    if not path.is_file():
        raise SystemExit(f"no {path}: gymnasium's MuJoCo assets are missing")
    return str(path)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--machines", default=",".join(MACHINES),
                    help="comma-separated machines (default: every one of the page)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" /
                                         "machines_evidence.json"),
                    help="the JSON written at the end (nothing when a command fails)")
    short_defaults(ap, machines="acrobot")
    a = ap.parse_args()
    wanted = a.machines.split(",")
    unknown = [m for m in wanted if m not in MACHINES]
    if unknown:
        ap.error(f"--machines: unknown {unknown[0]!r} (one of {', '.join(MACHINES)})")
    out = out_path(a.out) if a.out == ap.get_default("out") or short() else Path(a.out)
    data: dict = {}
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="tspend-machines-") as d:
        folder = Path(d)
        for name in wanted:
            scenario, extra = MACHINES[name]
            sets = (["--set", f"plant.model={gymnasium_model()}", "--set", "plant.timestep=0.001"]
                    if extra == ["GYMNASIUM"] else [])
            t0 = time.perf_counter()
            cc = tspend(["crosscheck", scenario, *sets], folder)
            entry = {"scenario": scenario, "crosscheck": cc}
            if name in RUNS:
                entry["run"] = tspend(["run", scenario], folder)
            data[name] = entry
            # a single-pole machine's cross-check has no acceleration or free-motion part
            shown = {k: cc[k] for k in ("accel_max_diff", "open_loop_max_tracked",
                                        "open_loop_within_tol_s", "free_max_diff_first_s",
                                        "free_within_tight_s", "free_within_loose_s")
                     if k in cc}
            print(f"{name}: " + ", ".join(f"{k} {v:.3g}" for k, v in shown.items())
                  + (f"; run {entry['run'].get('status', '?')}" if "run" in entry else "")
                  + f" ({time.perf_counter() - t0:.0f} s)", flush=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(data, indent=1, default=float) + "\n")
    print(f"{out} ({time.perf_counter() - started:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
