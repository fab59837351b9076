"""Whole closed loops against the physics floor, measured in one process (issue 5).

Prints three figures, each as a ratio against a baseline measured in the same run:

* MuJoCo: 20 s of the default pendulum scenario at 1 kHz, recorded to an ``.rrd``,
  against 20,000 bare ``mujoco.mj_step`` calls on ``models/cartpole.xml`` (target <= 4x);
  the same loop without recording is printed too;
* analytic: the same scenario on the cart-pole ODE backend (no recording) against
  20,000 RK4 steps of that ODE written plainly in numpy (target <= 4x);
* the recording's cost: with minus without, against the simulation alone.

Each figure is the median of ``--repeat`` runs (default 3).  Run:
``python benchmarks/closed_loop.py``.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np

from tspend import load_scenario, override, run
from short_mode import short_defaults

ROOT = Path(__file__).resolve().parents[1]
STEPS = 20_000


def bare_mj_steps(steps: int = STEPS) -> float:
    m = mujoco.MjModel.from_xml_path(str(ROOT / "models" / "cartpole.xml"))
    d = mujoco.MjData(m)
    d.qpos[1] = np.pi / 30
    t = time.perf_counter()
    for _ in range(steps):
        mujoco.mj_step(m, d)
    return time.perf_counter() - t


def plain_numpy_rk4(steps: int = STEPS, dt: float = 1e-3) -> float:
    """The cart-pole ODE of Example 3 by RK4, written plainly in numpy: the floor."""
    M, m, l, g = 10.0, 1.0, 3.0, 9.8

    def f(x, u):
        s, c = np.sin(x[0]), np.cos(x[0])
        a = (m * l * x[1] ** 2 * s * c - (M + m) * g * s - u * c) / (m * l * c**2 - 4 / 3 * l * (M + m))
        return np.array([x[1], a])

    x = np.array([np.pi / 30, 0.0])
    t = time.perf_counter()
    for _ in range(steps):
        k1 = f(x, 0.0)
        k2 = f(x + 0.5 * dt * k1, 0.0)
        k3 = f(x + 0.5 * dt * k2, 0.0)
        k4 = f(x + dt * k3, 0.0)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return time.perf_counter() - t


def closed_loop(scenario, record: bool, tmp: Path) -> float:
    sinks = []
    rec = None
    if record:
        from tspend.recorder import RerunSink, open_recording

        rec = open_recording("tspend_bench", path=tmp / "bench.rrd")
        sinks = [RerunSink(rec)]
    t = time.perf_counter()
    result = run(scenario, sinks=sinks, keep_history=False)
    if rec is not None:
        rec.flush()
    elapsed = time.perf_counter() - t
    assert result.status == "completed", result.end.message
    return elapsed


def median(fn, repeat: int) -> float:
    return statistics.median(fn() for _ in range(repeat))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    short_defaults(ap, repeat=1)
    args = ap.parse_args()
    mj_scn = override(load_scenario("pendulum_mujoco"), **{"run.duration": 20.0})
    ode_scn = override(load_scenario("ex3_pendulum_ode"), **{"run.duration": 20.0})
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        closed_loop(override(mj_scn, **{"run.duration": 0.1}), True, tmp)   # warm caches
        base_mj = median(bare_mj_steps, args.repeat)
        loop_rec = median(lambda: closed_loop(mj_scn, True, tmp), args.repeat)
        loop_bare = median(lambda: closed_loop(mj_scn, False, tmp), args.repeat)
        base_rk4 = median(plain_numpy_rk4, args.repeat)
        loop_ode = median(lambda: closed_loop(ode_scn, False, tmp), args.repeat)
        size = (tmp / "bench.rrd").stat().st_size
    print(f"baseline: {STEPS} bare mj_step                       {base_mj:8.3f} s "
          f"({base_mj / STEPS * 1e6:.2f} us/step)")
    print(f"MuJoCo closed loop 20 s, recorded to .rrd           {loop_rec:8.3f} s   "
          f"ratio {loop_rec / base_mj:5.2f}x  (target <= 4x)  "
          f"{'MET' if loop_rec <= 4 * base_mj else 'NOT MET'}")
    print(f"MuJoCo closed loop 20 s, no recording               {loop_bare:8.3f} s   "
          f"ratio {loop_bare / base_mj:5.2f}x")
    print(f"recording cost (recorded - not) vs simulation alone {loop_rec - loop_bare:8.3f} s   "
          f"ratio {(loop_rec - loop_bare) / loop_bare:5.2f}x  (.rrd {size / 1e6:.1f} MB)")
    print(f"baseline: {STEPS} plain numpy RK4 steps of the ODE    {base_rk4:8.3f} s "
          f"({base_rk4 / STEPS * 1e6:.2f} us/step)")
    print(f"ODE closed loop 20 s (analytic backend)             {loop_ode:8.3f} s   "
          f"ratio {loop_ode / base_rk4:5.2f}x  (target <= 4x)  "
          f"{'MET' if loop_ode <= 4 * base_rk4 else 'NOT MET'}")


if __name__ == "__main__":
    main()
