"""The two uncertainties of ``tspend identify`` over seeds (docs/identify.md): how often
the Gauss-Newton (curvature) interval and the segment bootstrap's interval cover the true
``m`` and ``M`` of the cart-pole, with white and with coloured measurement noise.

    python benchmarks/identify_bootstrap.py [--seeds 0:10] [--replicates 30]
        [--out benchmarks/results/identify_bootstrap.json]

Each seed: MuJoCo steps models/cartpole.xml (a 5 ms copy, so that a seed takes seconds)
open loop from hanging under a multisine push for 6 s; the positions get noise of 1 mrad
/ 1 mm std drawn from the seed, either white or coloured (first-order low-pass of white
noise, correlation time 50 ms, scaled to the same std); ``m`` and ``M`` are fitted from
the nominal values with 0.25 s segments and both intervals computed (the bootstrap: the
training segments resampled with replacement, ``--replicates`` refits, seeded).  The
curvature interval assumes white noise; the bootstrap resamples whole segments, so the
noise's correlation within a segment is kept.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np
import pandas as pd

from tspend.studies import identify as ident
from tspend.studies.identify_model import load_model

ROOT = Path(__file__).resolve().parents[1]
TRUTH = {"m": 1.0, "M": 10.0}


def record(path: str, T: float, seed: int, coloured: bool) -> pd.DataFrame:
    m = mujoco.MjModel.from_xml_path(path)
    d = mujoco.MjData(m)
    h, s = m.joint("hinge").qposadr[0], m.joint("slider").qposadr[0]
    d.qpos[h] = np.pi - 0.5
    n = int(round(T / m.opt.timestep))
    t = np.arange(n) * m.opt.timestep
    u = 15.0 * np.sin(2 * np.pi * np.multiply.outer(t, [0.3, 0.7, 1.3, 2.1]) + np.arange(4.0)).sum(1)
    q = np.empty((n, 2))
    for i in range(n):
        q[i] = d.qpos[h], d.qpos[s]
        d.ctrl[0] = u[i]
        mujoco.mj_step(m, d)
    rng = np.random.default_rng((seed, 0xB00))
    noise = rng.standard_normal((n, 2))
    if coloured:
        from scipy.signal import lfilter

        a = np.exp(-m.opt.timestep / 0.05)          # 50 ms correlation time
        noise = lfilter([1.0 - a], [1.0, -a], noise, axis=0)
        noise /= noise.std(axis=0)
    q = q + 1e-3 * noise
    return pd.DataFrame({"t_s": t, "theta_rad": q[:, 0], "cart_x_m": q[:, 1], "u_N": u})


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="0:10")
    ap.add_argument("--replicates", type=int, default=30)
    ap.add_argument("--noises", default="white,coloured", help="which noises, in this order")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "identify_bootstrap.json"))
    a = ap.parse_args()
    lo, hi = (int(x) for x in a.seeds.split(":"))
    t0 = time.perf_counter()
    out: dict = {"seeds": a.seeds, "replicates": a.replicates, "rows": []}
    with tempfile.TemporaryDirectory() as d:
        spec = mujoco.MjSpec.from_file(str(ROOT / "models" / "cartpole.xml"))
        spec.option.timestep = 0.005
        path = str(Path(d) / "cp5.xml")
        Path(path).write_text(spec.to_xml())
        model = load_model(path)
        model.jit = True                 # one compile, then every fit and refit in C
        for noise in a.noises.split(","):
            for seed in range(lo, hi):
                record(path, 6.0, seed, noise == "coloured").to_csv(Path(d) / "r.csv", index=False)
                rec = ident.read_record(Path(d) / "r.csv", model)
                fit = ident.fit(model, rec, ("m", "M"), segment_s=0.25, bootstrap=a.replicates,
                                rng=np.random.default_rng(seed))
                row = {"noise": noise, "seed": seed}
                for k, v in TRUTH.items():
                    z = 1.959963984540054
                    c_lo = fit.values[k] - z * fit.std_curvature[k]
                    c_hi = fit.values[k] + z * fit.std_curvature[k]
                    b_lo, b_hi = fit.interval(k)
                    row[k] = {"fitted": fit.values[k], "std_curvature": fit.std_curvature[k],
                              "std_bootstrap": fit.std[k],
                              "covered_curvature": bool(c_lo <= v <= c_hi),
                              "covered_bootstrap": bool(b_lo <= v <= b_hi)}
                out["rows"].append(row)
                print(f"{noise:8s} seed {seed:2d}: " + "  ".join(
                    f"{k} {row[k]['fitted']:.5g} std curvature {row[k]['std_curvature']:.2g} "
                    f"bootstrap {row[k]['std_bootstrap']:.2g} covered "
                    f"{'yes' if row[k]['covered_curvature'] else 'NO'}/"
                    f"{'yes' if row[k]['covered_bootstrap'] else 'NO'}" for k in TRUTH), flush=True)
    summary = {}
    for noise in a.noises.split(","):
        rows = [r for r in out["rows"] if r["noise"] == noise]
        summary[noise] = {k: {"n": len(rows),
                              "covered_curvature": sum(r[k]["covered_curvature"] for r in rows),
                              "covered_bootstrap": sum(r[k]["covered_bootstrap"] for r in rows),
                              "median_std_ratio_bootstrap_over_curvature": float(np.median(
                                  [r[k]["std_bootstrap"] / r[k]["std_curvature"] for r in rows])),
                              "rms_error_over_median_std_curvature": float(
                                  np.sqrt(np.mean([(r[k]["fitted"] - TRUTH[k]) ** 2 for r in rows]))
                                  / np.median([r[k]["std_curvature"] for r in rows]))}
                          for k in TRUTH}
    out["summary"] = summary
    out["wall_s"] = time.perf_counter() - t0
    for noise, per in summary.items():
        print(f"{noise}: " + "; ".join(
            f"{k}: covered curvature {v['covered_curvature']}/{v['n']}, bootstrap "
            f"{v['covered_bootstrap']}/{v['n']}, bootstrap std / curvature std (median) "
            f"{v['median_std_ratio_bootstrap_over_curvature']:.2f}, actual rms error / curvature "
            f"std {v['rms_error_over_median_std_curvature']:.2f}" for k, v in per.items()))
    print(f"wall {out['wall_s']:.0f} s (shared, loaded machine)")
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
