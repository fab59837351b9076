"""Cost of one compiled controller step against one bare ``mj_step``.

Run from the project root::

    .venv/bin/python benchmarks/controller_step.py [--blocks 31] [--no-startup]

Everything is measured in this process: the baseline is one ``mujoco.mj_step`` of
``models/cartpole.xml`` (or, if that file is missing, a minimal inline cart-pole MJCF with
RK4), then the whole controller sample (T-S model + compensator + both adaptive laws,
``ControllerConfig()`` = Example 3 sizes) through ``controller.sample(x, ref, dt)``, Python
call included.  Each figure is the median over blocks of the mean cost of one call in
the block.  Then the scaling table (sets per state input, plant order) and the start-up
time of a fresh interpreter that imports the controller, builds it and takes one
step with a warm numba cache (run twice, the second reported).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tspend.config import ControllerConfig, SetSpec  # noqa: E402
from tspend.controllers.paper.controller import make_controller  # noqa: E402
from short_mode import judged, short_defaults  # noqa: E402
from tspend.runtime.jit import drop_stale_kernels  # noqa: E402

# this folder's cached kernels call tspend's: compiled afresh when tspend changed
drop_stale_kernels(Path(__file__).resolve().parent)

#: the target of the benchmark: a controller step costs at most this many mj_steps
TARGET_RATIO = 0.6
STARTUP_LIMIT_S = 1.0

INLINE_CARTPOLE = """
<mujoco model="cartpole-inline">
  <compiler angle="radian" inertiafromgeom="false" autolimits="true"/>
  <option timestep="0.001" integrator="RK4" gravity="0 0 -9.8">
    <flag contact="disable"/>
  </option>
  <worldbody>
    <body name="cart" pos="0 0 1">
      <joint name="slider" type="slide" axis="1 0 0"/>
      <inertial pos="0 0 0" mass="10" diaginertia="1 1 1"/>
      <body name="pole" pos="0 0 0.25">
        <joint name="hinge" type="hinge" axis="0 -1 0"/>
        <inertial pos="0 0 3" mass="1" diaginertia="3 3 0.0001"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="force" joint="slider" gear="1"/>
  </actuator>
</mujoco>
"""

STARTUP_CODE = """
import time
t0 = time.perf_counter()
import numpy as np
from tspend.controllers.paper.controller import make_controller
from tspend.config import ControllerConfig
c = make_controller(ControllerConfig())
c.reset(np.random.default_rng(0))
c.sample(np.array([0.1, 0.0]), np.array([0.0, 0.0, 0.0]), 1e-3)
print(time.perf_counter() - t0)
"""


def median_cost(call, items: list, blocks: int, per_block: int, between=None) -> float:
    """Median over ``blocks`` of the mean seconds per ``call(item)`` in a block."""
    k = len(items)
    for i in range(min(per_block, 50)):         # warm-up
        call(items[i % k])
    costs = []
    for _ in range(blocks):
        if between is not None:
            between()
        j0 = np.random.randint(k)
        block = [items[(j0 + i) % k] for i in range(per_block)]
        t0 = time.perf_counter_ns()
        for it in block:
            call(it)
        costs.append((time.perf_counter_ns() - t0) / per_block)
    return float(np.median(costs)) * 1e-9


def mj_step_cost(blocks: int, per_block: int) -> tuple[float, str]:
    import mujoco

    path = ROOT / "models" / "cartpole.xml"
    if path.exists():
        model, source = mujoco.MjModel.from_xml_path(str(path)), str(path.relative_to(ROOT))
    else:
        model, source = mujoco.MjModel.from_xml_string(INLINE_CARTPOLE), "inline MJCF (RK4)"
    data = mujoco.MjData(model)

    def reset():
        mujoco.mj_resetData(model, data)
        data.qpos[1] = np.pi / 30
        data.ctrl[0] = 1.0

    step = mujoco.mj_step
    return median_cost(lambda _: step(model, data), [None], blocks, per_block, reset), source


def signals(cfg: ControllerConfig, samples: int = 2000, dt: float = 1e-3):
    """(x, ref) pairs along a smooth trajectory inside the state sets (Example 3-like)."""
    n = cfg.order
    t = np.arange(samples) * dt
    amp = np.array([0.5 * max(abs(s.lo), abs(s.hi)) for s in cfg.state_sets])
    X = amp * np.sin(t[:, None] * (1.0 + np.arange(n)) + 0.3 * np.arange(n))
    R = np.zeros((samples, n + 1))
    R[:, :n] = X + 0.05 * amp * np.cos(2.0 * t[:, None] + np.arange(n))
    R[:, n] = np.sin(t)
    return [(X[k].copy(), R[k].copy()) for k in range(samples)]


def step_cost(cfg: ControllerConfig, blocks: int, per_block: int, seed: int = 1) -> float:
    ctrl = make_controller(cfg)
    ctrl.reset(np.random.default_rng(seed))
    items = signals(cfg)
    step = ctrl.sample
    dt = 1e-3
    return median_cost(lambda it: step(it[0], it[1], dt), items, blocks, per_block,
                       lambda: ctrl.reset(np.random.default_rng(seed)))


def kernel_only_cost(cfg: ControllerConfig, steps: int = 100_000) -> float:
    """The step looped inside compiled code (``controller.compiled()``): no Python call."""
    from numba import njit

    @njit(cache=True)
    def loop(count, step, settings, state, scratch, x, ref, dt, diag):
        u = 0.0
        for _ in range(count):
            u = step(settings, state, scratch, 0.0, x, x, ref, dt, diag)
        return u

    c = make_controller(cfg)
    c.reset(np.random.default_rng(1))
    x, ref = signals(cfg)[100]
    c_step = c.compiled()
    args = (c_step.step, c_step.settings, c_step.state, c_step.scratch, x, ref, 1e-6, c.diag)
    loop(10, *args)
    costs = []
    for _ in range(5):
        t0 = time.perf_counter_ns()
        loop(steps, *args)
        costs.append((time.perf_counter_ns() - t0) / steps)
    return float(np.median(costs)) * 1e-9


def startup_time() -> tuple[float, float, float]:
    """Wall time of a fresh interpreter (import, build, one step); runs twice."""
    walls, inner = [], 0.0
    for _ in range(2):
        t0 = time.perf_counter()
        out = subprocess.run([sys.executable, "-c", STARTUP_CODE], cwd=ROOT, check=True,
                             capture_output=True, text=True)
        walls.append(time.perf_counter() - t0)
        inner = float(out.stdout.strip().splitlines()[-1])
    return walls[0], walls[1], inner


def order_config(n: int, sets: int) -> ControllerConfig:
    """Example 3's design with ``sets`` sets per state input at plant order n."""
    lam = {2: (1.0, 2.0), 3: (1.0, 3.0, 3.0)}[n]
    Q = tuple(tuple(10.0 if i == j else 0.0 for j in range(n)) for i in range(n))
    spec = SetSpec(sets, -np.pi / 4, np.pi / 4)
    return ControllerConfig(lam=lam, Q=Q, state_sets=(spec,) * n)


def us(seconds: float) -> str:
    return f"{seconds * 1e6:9.2f} us"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--blocks", type=int, default=31, help="timed blocks per figure")
    ap.add_argument("--per-block", type=int, default=2000, help="calls per block (numba)")
    ap.add_argument("--no-startup", action="store_true", help="skip the start-up figure")
    short_defaults(ap, blocks=3, per_block=200)
    a = ap.parse_args()
    blocks, per = a.blocks, a.per_block

    print("controller step vs mujoco.mj_step (median over blocks, Python call included)")
    base, source = mj_step_cost(blocks, per)
    print(f"  baseline mj_step ({source}):      {us(base)}")
    cfg = ControllerConfig()
    t_nb = step_cost(cfg, blocks, per)
    ratio = t_nb / base
    ok = ratio <= TARGET_RATIO
    print(f"  controller step (Example 3):         {us(t_nb)}   = {ratio:7.2f} x mj_step"
          f"   (target <= {TARGET_RATIO:g}: {'met' if ok else 'MISSED'})")
    t_k = kernel_only_cost(cfg)
    print(f"    of which the step itself:          {us(t_k)}   (Python call: "
          f"{(t_nb - t_k) * 1e6:.2f} us)")
    print()
    print("scaling (n = plant order, sets per state input; u_o 3 sets, compensator 5 x 5)")
    head = f"  {'n':>2} {'sets':>4} {'model':>6} {'comp':>5} {'rules':>6}"
    head += f" | {'step':>13} {'per rule':>11} {'x mj_step':>9}"
    print(head)
    for n, sets in ((2, 3), (2, 5), (2, 7), (3, 3), (3, 5)):
        c = order_config(n, sets)
        h = sets ** n * c.u_sets.terms
        hc = c.e_delta_sets.terms * c.x_norm_sets.terms
        row = f"  {n:>2} {sets:>4} {h:>6} {hc:>5} {h + hc:>6}"
        t = step_cost(c, blocks, per)
        row += f" | {us(t):>13} {t / (h + hc) * 1e9:8.1f} ns {t / base:9.2f}"
        print(row)

    if not a.no_startup:
        print()
        first, second, inner = startup_time()
        good = second < STARTUP_LIMIT_S
        print("start-up: fresh interpreter, import tspend.controllers.paper.controller, build, one step")
        print(f"  first run {first:.3f} s, second run (warm cache) {second:.3f} s "
              f"(of which in-process {inner:.3f} s)   (limit {STARTUP_LIMIT_S:g} s: "
              f"{'met' if good else 'MISSED'})")
        ok = ok and good
    return 0 if ok or not judged() else 1


if __name__ == "__main__":
    sys.exit(main())
