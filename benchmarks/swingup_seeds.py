"""A swing-up scenario over seeds: status, and each joint's largest excursion over the run
and over its last 2 s (angles wrapped), the largest |u| (docs/controllers.md, "Planned
swing-ups").

    python benchmarks/swingup_seeds.py double_cartpole_swingup 1,2,...,20 [controller=KIND] [KEY=JSON ...]
"""
import json
import sys
import time

import numpy as np

from tspend.loop.simulation import run
from tspend.scenario import load_scenario, override


def main() -> None:
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
