"""The figures of docs/gym.md's "Measured" table: the cart-pole's learned policy
(models/policies/pendulum_mujoco.onnx) run and compared by the table's own commands.

    python benchmarks/policy_evidence.py [--out benchmarks/results/policy_evidence.json]

Runs, each a ``tspend`` process of its own in a scratch folder with ``--metrics``:

* ``run10``: ``tspend run pendulum_mujoco --controller policy --duration 10``;
* ``run20``: the same at the scenario's 20 s;
* ``x0_X``: the 10 s run from ``plant.x0 = [X, 0]``, X = -0.2, -0.1, 0, 0.1, 0.2 rad;
* ``compare``: ``tspend compare pendulum_mujoco --controller policy,pd,lqr,second_type
  --seeds 0:5 --duration 10 --metric rmse_ss,max_abs_e_ss,control_energy``;
* ``compare_noise``: ``tspend compare pendulum_sensor_noise --controller policy,pd --seeds
  0:5 --duration 10 --metric rmse_ss,max_abs_e_ss``.

Written: per run its status, rmse_ss and max_abs_u; per compare, per controller and metric
its median, q1 and q3 over the seeds. tools/check_claims.py checks the table against it.
A command that fails stops the script with its message and writes nothing. Under
``TSPEND_BENCH_SHORT=1`` (tools/check_docs.py): 1 s runs, seeds 0:2, into the working
folder.
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
from short_mode import out_path, short, sized  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
POLICY = "models/policies/pendulum_mujoco.onnx"
STARTS = (-0.2, -0.1, 0.0, 0.1, 0.2)


def run_entry(m: dict) -> dict:
    return {"status": m["status"], "rmse_ss": m["rmse_ss"], "max_abs_u": m["max_abs_u"]}


def compare_entry(m: dict) -> dict:
    out: dict = {}
    for row in m["summary"]:
        out.setdefault(row["controller"], {})[row["metric"]] = {
            "median": row["median"], "q1": row["q1"], "q3": row["q3"], "n": row["n"]}
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "policy_evidence.json"),
                    help="the JSON written at the end (nothing when a command fails)")
    a = ap.parse_args()
    out = out_path(a.out) if a.out == ap.get_default("out") or short() else Path(a.out)
    ten, twenty, seeds = sized("10", "1"), sized([], ["--duration", "1"]), sized("0:5", "0:2")
    data: dict = {"policy": POLICY}
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="tspend-policy-") as d:
        folder = Path(d)
        base = ["run", "pendulum_mujoco", "--controller", "policy"]
        data["run10"] = run_entry(tspend([*base, "--duration", ten], folder))
        data["run20"] = run_entry(tspend([*base, *twenty], folder))
        for x in STARTS:
            data[f"x0_{x:g}"] = run_entry(tspend([*base, "--duration", ten, "--set",
                                                  f"plant.x0=[{x}, 0.0]"], folder))
        data["compare"] = compare_entry(tspend(
            ["compare", "pendulum_mujoco", "--controller", "policy,pd,lqr,second_type",
             "--seeds", seeds, "--duration", ten, "--metric",
             "rmse_ss,max_abs_e_ss,control_energy", "--jobs", "1"], folder))
        data["compare_noise"] = compare_entry(tspend(
            ["compare", "pendulum_sensor_noise", "--controller", "policy,pd", "--seeds", seeds,
             "--duration", ten, "--metric", "rmse_ss,max_abs_e_ss", "--set",
             f"controllers.policy.path={POLICY}", "--jobs", "1"], folder))
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(data, indent=1) + "\n")
    print(json.dumps({k: v for k, v in data.items() if k.startswith(("run", "x0"))}))
    print(f"{out} ({time.perf_counter() - started:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
