"""Planned swing-ups (``tvlqr``, a plan made at the first sample from the observed state
on the nominal model) against the energy swing-up (``swingup``) over randomised machines.

Each seed draws the machine and its start ([randomize], the same draw for both kinds);
the controllers are designed on the nominal machine.  Success: the run completes with
the task's goal met (the pole within ``task.goal_angle`` from ``task.goal_by`` on).
Paired Wilcoxon signed-rank tests over the seeds both kinds swing up, Holm-corrected over
every test of the run.

    python benchmarks/planned_swingups.py [--seeds 20] [--out benchmarks/results/planned_swingups.json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

MACHINES = {
    # the 3 m cart-pole: pole mass, half-length and cart mass +/-20 %, start near hanging
    "swingup_mujoco": {
        "randomize.x0": [{"dist": "uniform", "low": 3.0415926535897933, "high": 3.241592653589793},
                         {"dist": "uniform", "low": -0.1, "high": 0.1}],
        "randomize.m": {"dist": "uniform", "low": 0.8, "high": 1.2, "relative": True},
        "randomize.l": {"dist": "uniform", "low": 0.9, "high": 1.1, "relative": True},
        "randomize.M": {"dist": "uniform", "low": 0.8, "high": 1.2, "relative": True},
    },
    # the QUBE: the pendulum's damping (its least certain number) x0.5-2, start near hanging
    "furuta_swingup": {
        "randomize.x0": [{"dist": "uniform", "low": 3.0415926535897933, "high": 3.241592653589793},
                         {"dist": "uniform", "low": -0.1, "high": 0.1}],
        "randomize.pendulum_damping": {"dist": "uniform", "low": 0.5, "high": 2.0, "relative": True},
    },
}
KINDS = ("swingup", "tvlqr")
METRICS = ("reached_at_s", "control_energy", "max_abs_u")


def one(name: str, changes: dict, seed: int, kind: str) -> dict:
    from tspend.loop.simulation import run
    from tspend.scenario import load_scenario, override

    scn = override(load_scenario(name), **{**changes, "run.seed": seed})
    started = time.perf_counter()
    r = run(scn, controller=kind, keep_history=kind == "tvlqr")
    m = r.metrics
    goal = m.get("goal") or {}
    row = {"machine": name, "kind": kind, "seed": seed, "status": r.status,
           "success": r.status == "completed" and bool(goal.get("met")),
           "reached_at_s": goal.get("reached_at_s"), "control_energy": m.get("control_energy"),
           "max_abs_u": m.get("max_abs_u"), "wall_s": time.perf_counter() - started}
    if kind == "tvlqr" and "plan_s" in r.history:
        row["plan_s"] = float(np.max(r.history["plan_s"]))
    return row


def holm(pvalues: list[float]) -> list[float]:
    order = np.argsort(pvalues)
    out, running = [0.0] * len(pvalues), 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (len(pvalues) - rank) * pvalues[i]))
        out[i] = running
    return out


def summarize(rows: list[dict]) -> dict:
    """Per machine and kind the figures docs/controllers.md quotes: runs, swung up, the
    other endings counted, reached_at_s and control_energy as q25/median/q75 over the
    swung-up runs, the median max |u|, planning median and max."""
    out: dict = {}
    for name in MACHINES:
        for kind in KINDS:
            rs = [r for r in rows if r["machine"] == name and r["kind"] == kind]
            ok = [r for r in rs if r["success"]]
            cell = {"runs": len(rs), "swung_up": len(ok),
                    "endings": {st: sum(r["status"] == st for r in rs)
                                for st in sorted({r["status"] for r in rs})}}
            for key in ("reached_at_s", "control_energy"):
                v = np.array([r[key] for r in ok], dtype=float)
                if v.size:
                    a, b, c = np.percentile(v, [25, 50, 75])
                    cell[key] = {"q25": float(a), "median": float(b), "q75": float(c)}
            if ok:
                cell["max_abs_u_median"] = float(np.median([r["max_abs_u"] for r in ok]))
            plan = [r["plan_s"] for r in rs if "plan_s" in r]
            if plan:
                cell["plan_s"] = {"median": float(np.median(plan)), "max": float(max(plan))}
            out.setdefault(name, {})[kind] = cell
    return out


def main() -> None:
    from scipy.stats import wilcoxon

    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--out", default="")
    ap.add_argument("--summarize", metavar="JSON",
                    help="run nothing: add the summary to a JSON this script wrote")
    args = ap.parse_args()
    if args.summarize:
        path = Path(args.summarize)
        data = json.loads(path.read_text())
        data["summary"] = summarize(data["rows"])
        path.write_text(json.dumps(data, indent=1) + "\n")
        return
    rows = []
    for name, changes in MACHINES.items():
        for seed in range(args.seeds):
            for kind in KINDS:
                rows.append(one(name, changes, seed, kind))
                print(json.dumps(rows[-1]), flush=True)
    tests = []
    print("\n| machine | kind | swung up | reached_at_s median [IQR] | control_energy median [IQR] | max_abs_u median | plan_s median [max] |")
    print("|---|---|---|---|---|---|---|")
    for name in MACHINES:
        for kind in KINDS:
            rs = [r for r in rows if r["machine"] == name and r["kind"] == kind]
            ok = [r for r in rs if r["success"]]

            def q(key):
                v = np.array([r[key] for r in ok], dtype=float)
                if not v.size:
                    return "n/a"
                a, b, c = np.percentile(v, [25, 50, 75])
                return f"{b:.3g} [{a:.3g}, {c:.3g}]"
            plan = [r["plan_s"] for r in rs if "plan_s" in r]
            plan_s = f"{np.median(plan):.2g} [{max(plan):.2g}]" if plan else "-"
            umax = f"{np.median([r['max_abs_u'] for r in ok]):.3g}" if ok else "n/a"
            print(f"| {name} | `{kind}` | {len(ok)}/{len(rs)} | {q('reached_at_s')} | "
                  f"{q('control_energy')} | {umax} | {plan_s} |")
        pairs = {s: {r["kind"]: r for r in rows if r["machine"] == name and r["seed"] == s}
                 for s in range(args.seeds)}
        both = [p for p in pairs.values() if all(p[k]["success"] for k in KINDS)]
        for key in ("reached_at_s", "control_energy"):
            a = np.array([p["tvlqr"][key] for p in both], dtype=float)
            b = np.array([p["swingup"][key] for p in both], dtype=float)
            p = float(wilcoxon(a, b).pvalue) if len(both) >= 6 and np.any(a != b) else float("nan")
            tests.append((name, key, len(both), float(np.median(a - b)) if both else float("nan"), p))
    adjusted = holm([t[4] if t[4] == t[4] else 1.0 for t in tests])
    print("\n| machine | metric | pairs | median tvlqr - swingup | Wilcoxon p (Holm) |")
    print("|---|---|---|---|---|")
    for t, p in zip(tests, adjusted):
        print(f"| {t[0]} | {t[1]} | {t[2]} | {t[3]:.3g} | {p:.2g} |")
    if args.out:
        with open(args.out, "w") as f:
            json.dump({"rows": rows, "tests": tests, "holm": adjusted,
                       "summary": summarize(rows)}, f, indent=1)


if __name__ == "__main__":
    main()
