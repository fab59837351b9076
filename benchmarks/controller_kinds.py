"""Per-step cost of every controller kind against one bare ``mj_step``.

Run from the project root::

    .venv/bin/python benchmarks/controller_kinds.py [--blocks 31]

The baseline is one ``mujoco.mj_step`` of ``models/cartpole.xml`` (RK4, 1 ms), measured
in this process.  Each kind is built for ``pendulum_mujoco`` (and the oracle also for
Example 1, where it runs Newton's method) and called as the runner calls it,
``controller.step(obs, dt)`` with the Observation the runner builds (the plant's full
state, the task's view of it, its constraints) at states and references near the
operating region;
each figure is the median over blocks of the mean cost of one call in the block.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tspend import load_scenario  # noqa: E402
from tspend.controllers import KINDS  # noqa: E402
from tspend.controllers.base import Observation  # noqa: E402
from tspend.loop.simulation import build_controller, build_plant, scenario_task  # noqa: E402
from short_mode import short_defaults


def median_cost(call, items: list, blocks: int, per_block: int) -> float:
    k = len(items)
    for i in range(min(per_block, 50)):
        call(items[i % k])
    costs = []
    for _ in range(blocks):
        t0 = time.perf_counter()
        for i in range(per_block):
            call(items[i % k])
        costs.append((time.perf_counter() - t0) / per_block)
    return float(np.median(costs))


def bare_mj_step(blocks: int, per_block: int) -> float:
    import mujoco

    m = mujoco.MjModel.from_xml_path(str(ROOT / "models" / "cartpole.xml"))
    d = mujoco.MjData(m)
    d.qpos[:] = 0.0
    d.qpos[-1] = 0.1

    def step(_):
        mujoco.mj_step(m, d)
        if abs(d.qpos[-1]) > 1.0:  # keep the pole near upright so the work stays the same
            d.qpos[:] = 0.0
            d.qvel[:] = 0.0
            d.qpos[-1] = 0.1

    return median_cost(step, [None], blocks, per_block)


def kind_cost(scenario_name: str, kind: str, blocks: int, per_block: int) -> float:
    s = load_scenario(scenario_name)
    ctrl = build_controller(s, kind=kind)  # designed on the nominal machine
    ctrl.reset(np.random.default_rng(0))
    rng = np.random.default_rng(1)
    n = ctrl.order
    scale = 0.1 if s.plant.kind.startswith("cartpole") else 0.5
    t = rng.uniform(0, 20, 256)
    refs = s.reference.derivatives(t, n)
    # the observation the runner builds: the full state (the view near its reference, the
    # other states at the start's), the task's view of it, its names and constraints (a
    # full-state kind such as mpc reads the whole state)
    task = scenario_task(s, build_plant(s))
    start = np.zeros(len(task.names))
    items = []
    for i in range(256):
        full = start.copy()
        full[list(task.view_index)] = refs[i, :n] + rng.normal(scale=0.1 * scale, size=n)
        # the sample's time held at 0: a time-varying kind (tvlqr) stays at its plan's
        # first sample as the items cycle
        items.append(Observation(0.0, full, full[list(task.view_index)], refs[i],
                                 task.names, task.constraints))
    dt = s.run.dt
    step = ctrl.step
    return median_cost(lambda obs: step(obs, dt), items, blocks, per_block)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--blocks", type=int, default=31)
    ap.add_argument("--per-block", type=int, default=2000)
    short_defaults(ap, blocks=3, per_block=100)
    a = ap.parse_args()
    base = bare_mj_step(a.blocks, a.per_block)
    print(f"bare mj_step (models/cartpole.xml, RK4): {base * 1e6:.2f} us")
    print("| kind | scenario | step | against one mj_step |")
    print("|---|---|---|---|")
    rows = [("pendulum_mujoco", k) for k in KINDS]
    rows.append(("ex1_nonaffine_case2", "feedback_linearization"))
    for scenario_name, kind in rows:
        c = kind_cost(scenario_name, kind, a.blocks, a.per_block)
        print(f"| {kind} | {scenario_name} | {c * 1e6:.2f} us | {c / base:.2f}x |", flush=True)


if __name__ == "__main__":
    main()
