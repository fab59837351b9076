"""Identification over seeds on the double cart-pole (docs/identify.md): for each seed a
randomised machine is drawn, excited, run, exported, given measurement noise and
identified through the articulated domain's derived equations; the drawn values are
checked against the reported 95 % intervals.

    python benchmarks/identify_seeds_articulated.py [--seeds 0:20] [--noise 1e-3]
        [--out benchmarks/results/identify_seeds_articulated.json]

The articulated domain's ``[plant]`` has no per-parameter keys for ``[randomize]`` to
draw, so the randomised double cart-pole is made here: each seed draws, from its own
``numpy.random.Generator((seed, 0xA27))``, both links' masses (x U(0.8, 1.2)), their
centres of mass along the link (x U(0.9, 1.1)) and both hinges' viscous damping
(U(0.002, 0.02) N m s/rad), and writes them into a copy of models/double_cartpole.xml
(the same MjSpec edits as a calibrated model; the inertias about the centres of mass
stay the model's).  One experiment (``tspend excite double_cartpole_mujoco``: multisine
of 12 N, 0.3-5 Hz, on lqr designed on the nominal model; ``[effects] noise_std`` on, so
the controller sees noisy angles) is run on each drawn machine; the positions handed to
``tspend identify --jit`` carry white noise of ``--noise`` (m and rad) drawn from the
seed.  The cart's mass and the motor's gear are known (a weighed cart, a calibrated
force); the six drawn numbers are fitted from the nominal model.

The seeds run one after another, each command in a process of its own with one BLAS
thread (``OPENBLAS_NUM_THREADS=1`` and its kin, unless the caller set them): the fit's
trust-region steps take an SVD of a ~18,000 x 192 Jacobian each, and OpenBLAS's default
threads spin against each other on a shared machine (one such SVD: 6.9 s with the default
threads, 0.68 s with one, load 4 on 2 cores; the identify of seed 5: 46 s CPU against
14 s, the same fit to 1e-14). Under ``TSPEND_BENCH_SHORT=1`` (tools/check_docs.py) one
seed runs and the summary goes to the working folder (benchmarks/short_mode.py).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from tspend.studies.identify_model import load_model

sys.path.insert(0, str(Path(__file__).resolve().parent))
from short_mode import out_path, short_defaults  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "models" / "double_cartpole.xml"
TSPEND = [sys.executable, "-m", "tspend.cli"]
#: one BLAS/OpenMP thread per command (see the module help); what the caller set wins
THREADS = {k: "1" for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
#: what each seed draws: name -> (kind, low, high); "rel" multiplies the model's value
DRAWS = {"link1.mass": ("rel", 0.8, 1.2), "link2.mass": ("rel", 0.8, 1.2),
         "link1.ipos_z": ("rel", 0.9, 1.1), "link2.ipos_z": ("rel", 0.9, 1.1),
         "hinge1.damping": ("abs", 0.002, 0.02), "hinge2.damping": ("abs", 0.002, 0.02)}


def sh(args: list[str]) -> str:
    r = subprocess.run(args, capture_output=True, text=True, cwd=ROOT,
                       env={**THREADS, **os.environ})
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(args)}: exit {r.returncode}: {r.stderr.strip()}")
    return r.stdout


def _column(df: pd.DataFrame, name: str) -> str:
    """The export's column for ``name``: ``name`` itself or ``name_<unit>`` (u_N, d_N)."""
    if name in df.columns:
        return name
    found = [c for c in df.columns if c.startswith(f"{name}_") and c.count("_") == 1]
    if len(found) != 1:
        raise SystemExit(f"the export has no single column for {name!r}: {list(df.columns)}")
    return found[0]


def draw(seed: int, nominal: dict[str, float]) -> dict[str, float]:
    rng = np.random.default_rng((seed, 0xA27))
    out = {}
    for name, (kind, lo, hi) in DRAWS.items():
        v = float(rng.uniform(lo, hi))
        out[name] = v * nominal[name] if kind == "rel" else v
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="0:20")
    ap.add_argument("--noise", type=float, default=1e-3)
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--amplitude", type=float, default=12.0)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "identify_seeds_articulated.json"))
    ap.add_argument("--keep", metavar="DIR",
                    help="work in DIR (made; must not exist) and keep its files: exp.toml, "
                         "per seed the drawn trueSEED.xml, expSEED.toml, sSEED.rrd, sSEED.csv, "
                         "the noisy nSEED.csv and the fit fSEED.json")
    short_defaults(ap, seeds="0:1")
    a = ap.parse_args()
    a.out = str(out_path(a.out) if a.out == ap.get_default("out") else a.out)
    lo, hi = (int(x) for x in a.seeds.split(":"))
    names = list(DRAWS)
    model = load_model(str(MODEL))
    rows = []
    t0 = time.perf_counter()
    if a.keep and Path(a.keep).exists():
        ap.error(f"--keep: {a.keep} exists (nothing of yours is overwritten)")
    with (contextlib.nullcontext(a.keep) if a.keep else tempfile.TemporaryDirectory()) as d:
        d = Path(d).resolve()
        d.mkdir(parents=True, exist_ok=True)
        exp = d / "exp.toml"
        sh([*TSPEND, "excite", "double_cartpole_mujoco", "--out", str(exp), "--duration",
            str(a.duration), "--amplitude", str(a.amplitude), "--f-min", "0.3", "--f-max", "5"])
        text = exp.read_text(encoding="utf-8") + "\n[effects]\nnoise_std = [0.001, 0.01]\n"
        for seed in range(lo, hi):
            ts = time.perf_counter()
            drawn = draw(seed, model.nominal)
            true_xml = d / f"true{seed}.xml"
            model.write(drawn, true_xml)
            scen = d / f"exp{seed}.toml"
            scen.write_text(text.replace(f'model = "{MODEL}"', f'model = "{true_xml}"'),
                            encoding="utf-8")
            rrd, csv, fit = d / f"s{seed}.rrd", d / f"s{seed}.csv", d / f"f{seed}.json"
            sh([*TSPEND, "run", str(scen), "--seed", str(seed), "--out", str(rrd)])
            sh([*TSPEND, "export", str(rrd), "--out", str(csv)])
            df = pd.read_csv(csv, comment="#")
            rng = np.random.default_rng((seed, 0x1DE))
            # the export names the input and disturbance with their units (u_N, d_N);
            # identify reads either form
            u_col, d_col = _column(df, "u"), _column(df, "d")
            noisy = pd.DataFrame({"t_s": df["t_s"], u_col: df[u_col], d_col: df[d_col]})
            for c in ("slider_m", "hinge1_rad", "hinge2_rad"):
                noisy[c] = df[c] + a.noise * rng.standard_normal(len(df))
            ncsv = d / f"n{seed}.csv"
            noisy.to_csv(ncsv, index=False)
            sh([*TSPEND, "identify", str(ncsv), "--model", str(MODEL), "--params",
                ",".join(names), "--jit", "--metrics", str(fit)])
            res = json.loads(fit.read_text())
            row = {"seed": seed, "validation_rms": res["rms_validation"],
                   "validation_rms_nominal": res["rms_validation_nominal"],
                   "noise_std": res["noise_std"], "wall_s": time.perf_counter() - ts}
            for n in names:
                p = res["parameters"][n]
                lo95, hi95 = p["ci95"]
                row[n] = {"drawn": drawn[n], "fitted": p["value"], "std": p["std"],
                          "rel_err": abs(p["value"] - drawn[n]) / abs(drawn[n]),
                          "covered": bool(lo95 <= drawn[n] <= hi95)}
            rows.append(row)
            print(f"seed {seed:2d}: " + "  ".join(
                f"{n} {row[n]['drawn']:.5g} -> {row[n]['fitted']:.5g} +/- {1.96 * row[n]['std']:.2g}"
                f" ({100 * row[n]['rel_err']:.2f} %{'' if row[n]['covered'] else ', NOT covered'})"
                for n in names)
                + "  validation rms identified/nominal: " + ", ".join(
                f"{c} {row['validation_rms'][c]:.3g}/{row['validation_rms_nominal'][c]:.3g}"
                for c in row["validation_rms"]) + f"  ({row['wall_s']:.0f} s)", flush=True)
            Path(a.out).parent.mkdir(parents=True, exist_ok=True)
            Path(a.out).write_text(json.dumps(_summary(a, rows, names, t0), indent=2))
    s = _summary(a, rows, names, t0)
    print(f"\n{len(rows)} seeds: every drawn value inside its 95 % interval in "
          f"{s['seeds_all_covered']}; per parameter: "
          + ", ".join(f"{n} {s['coverage'][n]}" for n in names))
    print("median relative error: " + ", ".join(f"{n} {100 * v:.3f} %" for n, v in s["median_rel_err"].items()))
    print("max relative error: " + ", ".join(f"{n} {100 * v:.3f} %" for n, v in s["max_rel_err"].items()))
    print(f"identified model predicts the validation part better than the nominal on every "
          f"channel in {s['validation_better']} of {len(rows)} seeds; median validation rms "
          f"identified / nominal: " + ", ".join(
              f"{c} {v[0]:.3g} / {v[1]:.3g}" for c, v in s["median_validation_rms"].items())
          + f"; wall {s['wall_s']:.0f} s (shared machine)")
    return 0


#: docs/identify.md's seeds table lies between these (tools/check_claims.py rebuilds it)
TABLE_BEGIN, TABLE_END = "<!-- SEEDS -->", "<!-- SEEDS: end -->"


def seeds_table(summary: dict) -> str:
    """docs/identify.md's table of the seeds from the summary this script writes: per seed
    each parameter drawn -> fitted +/- its 95 % half-width, and the validation RMS
    identified / nominal (mm, mrad)."""
    names = list(summary["draws"])
    head = ("| seed | " + " | ".join(f"`{n}` drawn -> fitted (+/-95 %)" for n in names)
            + " | validation RMS identified / nominal (slider mm, hinge1, hinge2 mrad) |")
    lines = [head, "|---|" + "---|" * (len(names) + 1)]
    for r in summary["rows"]:
        cells = []
        for n in names:
            p = r[n]
            cells.append(f"{p['drawn']:.4g} -> {p['fitted']:.4g} +/- {1.96 * p['std']:.2g}"
                         + ("" if p["covered"] else " **not covered**"))
        rms = ", ".join(f"{1e3 * r['validation_rms'][c]:.2f} / "
                        f"{1e3 * r['validation_rms_nominal'][c]:.2f}" for c in r["validation_rms"])
        lines.append(f"| {r['seed']} | " + " | ".join(cells) + f" | {rms} |")
    return "\n".join(lines)


def _spread(values: list[float]) -> dict:
    """median, min and max (empty: {})."""
    return ({"median": float(np.median(values)), "min": float(np.min(values)),
             "max": float(np.max(values))} if values else {})


def _summary(a, rows, names, t0) -> dict:
    chans = list(rows[0]["validation_rms"]) if rows else []
    return {"seeds": a.seeds, "noise": a.noise, "duration": a.duration, "amplitude": a.amplitude,
            "draws": {n: list(v) for n, v in DRAWS.items()},
            "wall_s": time.perf_counter() - t0, "done": len(rows),
            "wall_per_seed_s": _spread([r["wall_s"] for r in rows]),
            "seeds_all_covered": sum(all(r[n]["covered"] for n in names) for r in rows),
            "coverage": {n: sum(r[n]["covered"] for r in rows) for n in names},
            "median_rel_err": {n: float(np.median([r[n]["rel_err"] for r in rows])) for n in names},
            "max_rel_err": {n: float(np.max([r[n]["rel_err"] for r in rows])) for n in names},
            "validation_better": sum(all(r["validation_rms"][c] < r["validation_rms_nominal"][c]
                                         for c in r["validation_rms"]) for r in rows),
            "median_validation_rms": {c: [float(np.median([r["validation_rms"][c] for r in rows])),
                                          float(np.median([r["validation_rms_nominal"][c] for r in rows]))]
                                      for c in chans},
            "rows": rows}


if __name__ == "__main__":
    sys.exit(main())
