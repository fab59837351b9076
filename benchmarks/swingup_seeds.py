"""A swing-up scenario over seeds: status, and each joint's largest excursion over the run
and over its last 2 s (angles wrapped), the largest |u| (docs/controllers.md, "Planned
swing-ups").

    python benchmarks/swingup_seeds.py double_cartpole_swingup 1,2,...,20 [controller=KIND] [KEY=JSON ...]
    python benchmarks/swingup_seeds.py --summarize RAW.txt OUT.json

Each seed prints one row (a Python dict). ``--summarize`` reads such rows (the raw output
kept in benchmarks/results/) and writes, per the figures docs/controllers.md quotes, the
runs, how many completed, and per quantity the median, min and max over the seeds.
"""
import json
import sys
import time

import numpy as np

from tspend.loop.simulation import run
from tspend.scenario import load_scenario, override


def summarize(raw: str, out: str) -> None:
    import ast
    from pathlib import Path

    rows = [ast.literal_eval(line) for line in Path(raw).read_text().splitlines()
            if line.startswith("{'seed'")]
    keys = sorted({k for r in rows for k in r if k.startswith(("max|", "last2s_max|"))})
    data = {"raw": raw, "runs": len(rows),
            "completed": sum(r["status"] == "completed" for r in rows),
            "seeds": [r["seed"] for r in rows]}
    for k in keys:
        v = np.array([r[k] for r in rows if k in r], dtype=float)
        # "max|hinge1|" -> "max_abs_hinge1": no "|" in a key a Markdown table cites
        name = k.replace("max|", "max_abs_").rstrip("|")
        data[name] = {"median": float(np.median(v)), "min": float(v.min()), "max": float(v.max())}
    Path(out).write_text(json.dumps(data, indent=1) + "\n")


def main() -> None:
    if sys.argv[1] == "--summarize":
        summarize(sys.argv[2], sys.argv[3])
        return
    name, seeds = sys.argv[1], [int(s) for s in sys.argv[2].split(",")]
    kind, extra = None, {}
    for a in sys.argv[3:]:
        k, v = a.split("=", 1)
        if k == "controller":
            kind = v
        else:
            extra[k] = json.loads(v)
    for seed in seeds:
        scn = override(load_scenario(name), **{"run.seed": seed, **extra})
        t0 = time.time()
        r = run(scn, controller=kind)
        h, dt, ctrl = r.history, scn.run.dt, r.controller
        row = {"seed": seed, "status": r.status, "wall_s": round(time.time() - t0, 1)}
        if "plan_s" in h:
            row["plan_s"] = round(float(np.max(h["plan_s"])), 2)
        if getattr(ctrl, "plan", None) is not None:
            row["iters"] = ctrl.plan.solver.get("iterations")
        full, names = h["state"], r.plant.state_names
        last = full[-int(2.0 / dt):]
        for i, n in enumerate(names[:len(names) // 2]):
            v = last[:, i]
            if ctrl.model.angles[i]:
                v = np.angle(np.exp(1j * v))
            row[f"last2s_max|{n}|"] = float(np.abs(v).max())
            row[f"max|{n}|"] = float(np.abs(full[:, i]).max())
        row["max|u|"] = float(np.abs(h["u"]).max())
        print(row, flush=True)


if __name__ == "__main__":
    main()
