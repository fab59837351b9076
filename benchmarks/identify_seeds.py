"""Identification over seeds (docs/identify.md): for each seed of a randomised scenario,
excite, run, export, add measurement noise, ``tspend identify`` the drawn parameters, and
check the drawn values against the reported 95 % intervals.

    python benchmarks/identify_seeds.py [--seeds 0:20] [--scenario pendulum_mujoco_randomized]
        [--noise 1e-3] [--out benchmarks/results/identify_seeds.json]

The experiment is written once by ``tspend excite`` (multisine on lqr, amplitude sized on
the nominal machine) with sensor noise on for the controller (``[effects] noise_std``); the
positions handed to ``tspend identify`` carry white noise of ``--noise`` (rad and m) drawn
from the seed, so the fit sees a noisy record, as on a rig.  The actuator gain is given its
drawn value (``--fix gear=...``: a calibrated force); ``m``, ``l`` and ``M`` are fitted.
Prints, per seed, each parameter's drawn and fitted value, its relative error and whether
the interval covers the drawn value; then the coverage count and the median relative error.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from tspend.studies.identify import column
from tspend.studies.identify_model import load_model

ROOT = Path(__file__).resolve().parents[1]
TSPEND = [sys.executable, "-m", "tspend.cli"]


def sh(args: list[str]) -> None:
    r = subprocess.run(args, capture_output=True, text=True, cwd=ROOT)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(args)}: exit {r.returncode}: {r.stderr.strip()}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="0:20")
    ap.add_argument("--scenario", default="pendulum_mujoco_randomized")
    ap.add_argument("--params", default="m,l,M")
    ap.add_argument("--noise", type=float, default=1e-3)
    ap.add_argument("--sensor-noise", default="[0.001, 0.01]",
                    help="[effects] noise_std of the experiment (what the controller sees)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "identify_seeds.json"))
    a = ap.parse_args()
    lo, hi = (int(x) for x in a.seeds.split(":"))
    names = a.params.split(",")
    rows = []
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        exp = d / "exp.toml"
        t0 = time.perf_counter()
        sh([*TSPEND, "excite", a.scenario, "--out", str(exp), "--duration", "16"])
        with open(exp, "a", encoding="utf-8") as f:
            f.write(f"\n[effects]\nnoise_std = {a.sensor_noise}\n")
        for seed in range(lo, hi):
            rrd, csv, met, fit = (d / f"s{seed}.rrd", d / f"s{seed}.csv", d / f"s{seed}.json",
                                  d / f"f{seed}.json")
            sh([*TSPEND, "run", str(exp), "--seed", str(seed), "--out", str(rrd), "--metrics", str(met)])
            sh([*TSPEND, "export", str(rrd), "--to", str(csv)])
            drawn = json.loads(met.read_text())["drawn"]
            df = pd.read_csv(csv, comment="#")
            rng = np.random.default_rng((seed, 0x1DE))
            model = load_model(str(ROOT / "models" / "cartpole.xml"))
            # the export's names, through identify's one mapping (either vocabulary)
            cols = [column(df, cands, "position") for cands in model.position_columns]
            u = column(df, model.input_columns, "input")
            noisy = pd.DataFrame({"t_s": df["t_s"], u: df[u]})
            for c in cols:
                noisy[c] = df[c] + a.noise * rng.standard_normal(len(df))
            ncsv = d / f"n{seed}.csv"
            noisy.to_csv(ncsv, index=False)
            sh([*TSPEND, "identify", str(ncsv), "--model", "models/cartpole.xml", "--params",
                a.params, "--fix", f"gear={drawn['gear']!r}", "--metrics", str(fit)])
            res = json.loads(fit.read_text())
            row = {"seed": seed, "validation_rms": res["rms_validation"],
                   "validation_rms_nominal": res["rms_validation_nominal"]}
            for n in names:
                p = res["parameters"][n]
                lo95, hi95 = p["ci95"]
                row[n] = {"drawn": drawn[n], "fitted": p["value"], "std": p["std"],
                          "rel_err": abs(p["value"] - drawn[n]) / drawn[n],
                          "covered": bool(lo95 <= drawn[n] <= hi95)}
            rows.append(row)
            print(f"seed {seed:2d}: " + "  ".join(
                f"{n} {row[n]['drawn']:.5g} -> {row[n]['fitted']:.5g} +/- {1.96 * row[n]['std']:.2g} "
                f"({100 * row[n]['rel_err']:.2f} %{'' if row[n]['covered'] else ', NOT covered'})"
                for n in names), flush=True)
        wall = time.perf_counter() - t0
    covered_all = sum(all(r[n]["covered"] for n in names) for r in rows)
    summary = {"seeds": a.seeds, "scenario": a.scenario, "noise": a.noise,
               "sensor_noise": a.sensor_noise, "wall_s": wall,
               "seeds_all_covered": covered_all,
               "coverage": {n: sum(r[n]["covered"] for r in rows) for n in names},
               "median_rel_err": {n: float(np.median([r[n]["rel_err"] for r in rows])) for n in names},
               "max_rel_err": {n: float(np.max([r[n]["rel_err"] for r in rows])) for n in names},
               "validation_better": sum(all(r["validation_rms"][c] < r["validation_rms_nominal"][c]
                                            for c in r["validation_rms"]) for r in rows),
               "rows": rows}
    print(f"\n{len(rows)} seeds: every drawn value inside its 95 % interval in {covered_all}; "
          f"per parameter: " + ", ".join(f"{n} {summary['coverage'][n]}" for n in names))
    print("median relative error: " + ", ".join(f"{n} {100 * v:.3f} %" for n, v in summary["median_rel_err"].items()))
    print("max relative error: " + ", ".join(f"{n} {100 * v:.3f} %" for n, v in summary["max_rel_err"].items()))
    print(f"identified model predicts the validation part better than the nominal on every channel "
          f"in {summary['validation_better']} of {len(rows)} seeds; wall {wall:.0f} s (shared machine)")
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
