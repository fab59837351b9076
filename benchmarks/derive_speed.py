"""What deriving a machine from its MJCF costs, cold and cached, and what its closed loop costs
against bare MuJoCo (issue: every inverted pendulum from its MJCF).

For each machine of the articulated domain, two fresh processes share one empty derivation
cache (``TSPEND_CACHE_DIR``): the first derives the equations (CasADi SX), writes the
generated module and lets numba compile it (**cold**); the second finds both on disk
(**cached**).  Each reports the time from ``load_machine`` to the first accelerations, and
the whole process's wall time (Python, numpy, MuJoCo and CasADi imports included).

Then the double cart-pole's closed loop (``lqr``, the compiled loop calling MuJoCo's C
``mj_step`` per sample) against bare ``mujoco.mj_step(m, d, nstep=N)`` on the same model
for the same number of steps, both measured in this process: the ratio is the loop's cost
over the physics floor (goal <= 1.5x).

    python benchmarks/derive_speed.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MACHINES = ("double_cartpole", "triple_cartpole", "acrobot", "pendubot", "reaction_wheel",
            "rotary_double")

_PROBE = """
import json, time, sys
t0 = time.perf_counter()
import numpy as np
from tspend.plants.articulated.machine import load_machine
t1 = time.perf_counter()
m = load_machine(sys.argv[1])
m.accelerations(np.zeros(2 * m.nv), 0.0)
t2 = time.perf_counter()
print(json.dumps({"imports_s": t1 - t0, "machine_s": t2 - t1, "dof": m.nv}))
"""


def probe(model: Path, cache: str) -> dict:
    env = dict(os.environ, TSPEND_CACHE_DIR=cache)
    t = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", _PROBE, str(model)], cwd=ROOT, env=env,
                         capture_output=True, text=True, check=True)
    figures = json.loads(out.stdout.strip().splitlines()[-1])
    figures["process_s"] = time.perf_counter() - t
    return figures


def derivation_times() -> list[dict]:
    rows = []
    for name in MACHINES:
        with tempfile.TemporaryDirectory() as cache:
            cold = probe(ROOT / "models" / f"{name}.xml", cache)
            warm = probe(ROOT / "models" / f"{name}.xml", cache)
        rows.append({"machine": name, "dof": cold["dof"], "cold_s": cold["machine_s"],
                     "cold_process_s": cold["process_s"], "cached_s": warm["machine_s"],
                     "cached_process_s": warm["process_s"]})
    return rows


def closed_loop_ratio(repeats: int) -> dict:
    import mujoco
    import numpy as np

    from tspend import load_scenario, override
    from tspend.loop.simulation import run

    scn = override(load_scenario("double_cartpole_mujoco"), **{"run.duration": 10.0})
    run(scn, keep_history=False)  # compile (numba caches the loop on disk as well)
    loop = []
    for _ in range(repeats):
        t = time.perf_counter()
        r = run(scn, keep_history=False)
        loop.append(time.perf_counter() - t)
    steps = int(r.metrics["steps"])
    plant = r.plant
    model = plant.mj_model()
    data = mujoco.MjData(model)
    bare = []
    for _ in range(repeats):
        mujoco.mj_resetData(model, data)
        data.qpos[1] = 0.1
        t = time.perf_counter()
        mujoco.mj_step(model, data, nstep=steps)
        bare.append(time.perf_counter() - t)
    return {"steps": steps, "closed_loop_s": min(loop), "bare_mj_step_s": min(bare),
            "ratio": min(loop) / min(bare), "status": r.status}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    print(f"{'machine':18s} {'dof':>3s} {'cold s':>8s} {'(process)':>10s} {'cached s':>9s} {'(process)':>10s}")
    for row in derivation_times():
        print(f"{row['machine']:18s} {row['dof']:3d} {row['cold_s']:8.2f} {row['cold_process_s']:10.2f} "
              f"{row['cached_s']:9.3f} {row['cached_process_s']:10.2f}")
    cl = closed_loop_ratio(args.repeats)
    print(f"\ndouble cart-pole, lqr, {cl['steps']} steps ({cl['status']}): compiled closed loop "
          f"{cl['closed_loop_s'] * 1e3:.1f} ms, bare mj_step {cl['bare_mj_step_s'] * 1e3:.1f} ms: "
          f"ratio {cl['ratio']:.2f}x (best of {args.repeats})")


if __name__ == "__main__":
    main()
