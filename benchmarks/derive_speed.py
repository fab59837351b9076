"""The articulated domain's start-up and step costs (issue 32), measured in one run.

Prints:

* per model under ``models/`` that the articulated domain reads: the time a fresh process
  takes to read the MJCF, derive the equations (Lagrange over CasADi SX), write the
  Python source and compile it with numba, up to its first evaluated acceleration, with
  an empty derivation cache (cold) and again with the cache that run left (cached).
  Goals: cached < 2 s; cold < 60 s for 3 degrees of freedom;
* the double cart-pole: the closed loop (the run's ``wall_s``) of 10 s (10,000 samples)
  with ``lqr`` on ``double_cartpole_mujoco`` and on ``double_cartpole_ode`` (both on the
  compiled loop), no recording, against
  10,000 bare ``mujoco.mj_step`` calls on the same model (goal <= 1.5x), and 10,000 RK4
  steps of the derived numba rhs from compiled code (the ODE's floor).

Each figure is the median of ``--repeat`` runs (default 3); ratios are taken within this
run.  On a shared machine the absolute times move; the ratios less so.

Run: ``python benchmarks/derive_speed.py``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from numba import njit

ROOT = Path(__file__).resolve().parents[1]
STEPS = 10_000

_PROBE = """
import time, sys
t0 = time.perf_counter()
import numpy as np
from tspend.plants.articulated.machine import load_machine
t1 = time.perf_counter()
m = load_machine(sys.argv[1])
t2 = time.perf_counter()
m.accelerations(np.zeros(2 * m.nv), 0.0)
t3 = time.perf_counter()
print(f"{t1 - t0} {t2 - t1} {t3 - t2} {m.nv}")
"""


def start_up(model: Path, cache: str) -> tuple[float, float, float, int, float]:
    """``(import, derive or load, compile or load, nv, wall)`` seconds of a fresh process."""
    env = {**os.environ, "TSPEND_CACHE_DIR": cache}
    t = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", _PROBE, str(model)], env=env, cwd=ROOT,
                         capture_output=True, text=True, check=True).stdout.split()
    wall = time.perf_counter() - t
    return float(out[0]), float(out[1]), float(out[2]), int(out[3]), wall


def articulated_models() -> list[Path]:
    import mujoco

    from tspend.plants.articulated.tree import read_tree

    found = []
    for path in sorted((ROOT / "models").glob("*.xml")):
        try:
            tree = read_tree(mujoco.MjModel.from_xml_path(str(path)))
        except ValueError:
            continue
        if not tree.refusals and tree.actuators:
            found.append(path)
    return found


@njit(cache=True)
def _rk4_steps(rhs, s, u, qfrc, p, M, r, k1, k2, k3, k4, tmp, dt, steps):
    for _ in range(steps):
        rhs(s, u, qfrc, p, M, r, k1)
        tmp[:] = s + 0.5 * dt * k1
        rhs(tmp, u, qfrc, p, M, r, k2)
        tmp[:] = s + 0.5 * dt * k2
        rhs(tmp, u, qfrc, p, M, r, k3)
        tmp[:] = s + dt * k3
        rhs(tmp, u, qfrc, p, M, r, k4)
        s[:] = s + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def loops(repeat: int) -> None:
    import mujoco

    from tspend import load_scenario, override, run
    from tspend.plants.articulated.machine import load_machine

    rows = {}
    for name in ("double_cartpole_mujoco", "double_cartpole_ode"):
        scn = override(load_scenario(name), **{"run.duration": STEPS * 1e-3, "run.dt": 1e-3})
        run(scn, controller="lqr")   # warm: compile, cache
        times, loop = [], []
        for _ in range(repeat):
            t = time.perf_counter()
            result = run(scn, controller="lqr")
            times.append(time.perf_counter() - t)
            loop.append(float(result.metrics["wall_s"]))
        rows[name] = (statistics.median(times), statistics.median(loop), result.status)
    model = mujoco.MjModel.from_xml_path(str(ROOT / "models" / "double_cartpole.xml"))
    data = mujoco.MjData(model)
    bare = []
    for _ in range(repeat):
        mujoco.mj_resetData(model, data)
        data.qpos[1] = 0.1
        t = time.perf_counter()
        for _ in range(STEPS):
            mujoco.mj_step(model, data)
        bare.append(time.perf_counter() - t)
    bare_s = statistics.median(bare)
    m = load_machine(ROOT / "models" / "double_cartpole.xml")
    n = m.nv
    arrays = [np.zeros(n * n), np.zeros(n)] + [np.zeros(2 * n) for _ in range(5)]
    s0 = np.zeros(2 * n)
    s0[1] = 0.1
    args = (m.module.rhs, s0.copy(), np.zeros(1), np.zeros(n), m.p, *arrays, 1e-3)
    _rk4_steps(*args, 1)
    floor = []
    for _ in range(repeat):
        t = time.perf_counter()
        _rk4_steps(*args, STEPS)
        floor.append(time.perf_counter() - t)
    floor_s = statistics.median(floor)
    print(f"\n10,000 samples of the double cart-pole (median of {repeat})")
    print(f"  bare mujoco.mj_step x {STEPS}            {bare_s * 1e3:8.1f} ms   1.00x")
    for name, (sec, loop_s, status) in rows.items():
        print(f"  closed loop lqr {name:<23} {loop_s * 1e3:8.1f} ms {loop_s / bare_s:6.2f}x   "
              f"({status}; whole run() call {sec * 1e3:.0f} ms)")
    print(f"  derived rhs, RK4 from numba x {STEPS}   {floor_s * 1e3:8.1f} ms {floor_s / bare_s:6.2f}x")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-loops", action="store_true", help="start-up figures only")
    ap.add_argument("--no-start-up", action="store_true", help="closed-loop figures only")
    args = ap.parse_args()
    if args.no_start_up:
        loops(args.repeat)
        return
    print("start-up of a fresh process (s): import, derive|load, compile|load, total wall")
    print(f"  {'model':<24} {'dof':>3} {'':<7} {'import':>7} {'derive':>7} {'compile':>8} {'wall':>7}")
    for model in articulated_models():
        with tempfile.TemporaryDirectory(prefix="tspend-derive-") as cache:
            for label in ("cold", "cached"):
                runs = [start_up(model, cache)]
                if label == "cached":
                    runs += [start_up(model, cache) for _ in range(args.repeat - 1)]
                imp, der, comp, nv, wall = (statistics.median(r[i] for r in runs) for i in range(5))
                print(f"  {model.name:<24} {int(nv):>3} {label:<7} {imp:7.2f} {der:7.2f} {comp:8.2f} "
                      f"{wall:7.2f}")
    if not args.no_loops:
        loops(args.repeat)


if __name__ == "__main__":
    main()
