"""The figures of docs/controllers.md's learned policy on the double cart-pole: the page's
compare of ``policy`` against ``lqr``, on its seeds and on a second set, into one JSON.

    python benchmarks/policy_double_evidence.py [--seeds 0:20] [--confirm 20:40]
        [--out benchmarks/results/policy_double_evidence.json]

Runs the page's command (``tspend compare double_cartpole_mujoco --controller policy,lqr
--duration 10 --set controllers.policy.path=models/policies/double_cartpole_mujoco.onnx
--set 'randomize.x0=[...]' --metric rmse_ss,max_abs_e_ss,control_energy,max_abs_u``) on
``--seeds`` and on ``--confirm`` (a second set, fixed here), each with ``--metrics`` and
``--out`` (the runs' table), and writes per set: per controller and metric the median,
q1, q3 and the runs the task ended; the paired tests (Wilcoxon p_holm per metric); the
outcome test (McNemar p_holm on the runs ended); per seed the lower link's drawn start and
how the policy's run ended, and the start ranges of its completed and ended runs.
tools/check_claims.py checks the page against it. A command that fails stops the script
and writes nothing. Under ``TSPEND_BENCH_SHORT=1`` (tools/check_docs.py): 2 seeds a set,
1 s runs, into the working folder.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from short_mode import out_path, short, short_defaults, sized  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
TSPEND = [sys.executable, "-m", "tspend.cli"]
POLICY = "models/policies/double_cartpole_mujoco.onnx"
X0 = '[{dist="uniform",low=0.05,high=0.15},{dist="uniform",low=-0.05,high=0.05}]'
METRICS = "rmse_ss,max_abs_e_ss,control_energy,max_abs_u"


def compare(seeds: str, duration: str, folder: Path) -> dict:
    import pandas as pd

    metrics, table = folder / f"c{seeds.replace(':', '_')}.json", folder / f"c{seeds.replace(':', '_')}.parquet"
    args = ["compare", "double_cartpole_mujoco", "--controller", "policy,lqr", "--seeds", seeds,
            "--duration", duration, "--jobs", "2", "--set", f"controllers.policy.path={POLICY}",
            "--set", f"randomize.x0={X0}", "--metric", METRICS, "--metrics", str(metrics),
            "--out", str(table)]
    r = subprocess.run([*TSPEND, *args], capture_output=True, text=True, cwd=ROOT)
    if r.returncode != 0:
        raise SystemExit(f"tspend {' '.join(args)}: exit {r.returncode}: {r.stderr.strip()[-400:]}")
    m = json.loads(metrics.read_text())
    out: dict = {"seeds": seeds, "summary": {}, "wilcoxon_p_holm": {}}
    for row in m["summary"]:
        out["summary"].setdefault(row["controller"], {})[row["metric"]] = {
            k: row[k] for k in ("median", "q1", "q3", "n", "runs", "completed", "terminated",
                                "diverged", "failed")}
    for row in m["pairs"]:
        out["wilcoxon_p_holm"][row["metric"]] = row["p_holm"]
    o = m["outcomes"][0]
    out["mcnemar"] = {k: o[k] for k in ("pairs", "a_bad", "b_bad", "a_only", "b_only",
                                        "p_value", "p_holm")}
    runs = pd.read_parquet(table)
    pol = runs[runs.controller == "policy"]
    start = next((c for c in ("drawn.x0[0]", "x0[0]", "drawn.x0.0") if c in pol.columns), None)
    if start is not None:
        done, ended = pol[pol.status == "completed"], pol[pol.status != "completed"]
        out["policy_start_rad"] = {
            "completed": [float(done[start].min()), float(done[start].max())] if len(done) else None,
            "ended": [float(ended[start].min()), float(ended[start].max())] if len(ended) else None,
            "endings": {str(k): int(v) for k, v in ended.status.value_counts().items()}}
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="0:20", help="the page's seeds (A:B)")
    ap.add_argument("--confirm", default="20:40", help="the second set (A:B)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" /
                                         "policy_double_evidence.json"))
    short_defaults(ap, seeds="0:2", confirm="20:22")
    a = ap.parse_args()
    out = out_path(a.out) if a.out == ap.get_default("out") or short() else Path(a.out)
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="tspend-policy2-") as d:
        data = {"policy": POLICY, "duration_s": float(sized("10", "1")),
                "first": compare(a.seeds, sized("10", "1"), Path(d)),
                "confirm": compare(a.confirm, sized("10", "1"), Path(d))}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(data, indent=1) + "\n")
    print(json.dumps({k: data[k]["mcnemar"] for k in ("first", "confirm")}))
    print(f"{out} ({time.perf_counter() - started:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
