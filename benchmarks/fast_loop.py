"""The compiled closed loop against its floors, measured in one process (issue 13).

Prints, each the median of ``--repeat`` runs (default 3):

* analytic: 20 s of ``ex3_pendulum_ode`` (the cart-pole ODE, no recording) on the
  compiled loop, against 20,000 samples of the same controller called from compiled code
  (target <= 1.5x);
* MuJoCo: 20 s of ``pendulum_mujoco`` (no recording) against 20,000 bare
  ``mujoco.mj_step`` on the same model (target <= 1.5x);
* for both, the speed-up over the generic Python loop (``run(..., compiled=False)``).

Run: ``python benchmarks/fast_loop.py``.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import mujoco
import numpy as np
from numba import njit

from tspend import load_scenario, override, run
from tspend.loop.simulation import build_controller, build_plant, with_gain_sign
from tspend.runtime.jit import drop_stale_kernels
from short_mode import short_defaults

# this folder's cached kernels call tspend's: compiled afresh when tspend changed
drop_stale_kernels(Path(__file__).resolve().parent)

STEPS = 20_000


@njit(cache=True)
def _controller_samples(step, settings, state, scratch, x, ref, dt, diag, steps):
    u = 0.0
    for _ in range(steps):
        u = step(settings, state, scratch, 0.0, x, x, ref, dt, diag)
    return u


def controller_floor(scenario) -> float:
    """20,000 samples of the scenario's controller from compiled code, state fixed at x0."""
    plant = build_plant(scenario)
    ctrl = build_controller(with_gain_sign(scenario, plant))
    c = ctrl.compiled()
    x = np.asarray(scenario.plant.x0, dtype=float)
    ref = scenario.reference.derivatives(np.zeros(1), ctrl.order)[0].copy()
    args = (c.step, c.settings, c.state, c.scratch, x, ref, scenario.run.dt, ctrl.diag)
    _controller_samples(*args, 1)
    t = time.perf_counter()
    _controller_samples(*args, STEPS)
    return time.perf_counter() - t


def mj_step_floor(scenario) -> float:
    """20,000 bare ``mj_step`` on the scenario's own model (one physics step per sample)."""
    plant = build_plant(scenario)
    m, d = plant.model, plant.data
    nstep = round(scenario.run.dt / m.opt.timestep)
    t = time.perf_counter()
    for _ in range(STEPS):
        mujoco.mj_step(m, d, nstep)
    return time.perf_counter() - t


def closed_loop(scenario, compiled: bool) -> float:
    t = time.perf_counter()
    result = run(scenario, keep_history=False, compiled=compiled)
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
    ode = override(load_scenario("ex3_pendulum_ode"), **{"run.duration": 20.0})
    mj = override(load_scenario("pendulum_mujoco"), **{"run.duration": 20.0})
    assert round(20.0 / ode.run.dt) == STEPS and round(20.0 / mj.run.dt) == STEPS
    for scenario in (ode, mj):   # compile (or load the cache) outside the timings
        run(override(scenario, **{"run.duration": 0.01}), keep_history=False)

    rows = []
    for label, scenario, floor_label, floor in (
            ("analytic cart-pole ODE", ode, "controller samples from compiled code",
             controller_floor),
            ("MuJoCo cart-pole", mj, "bare mj_step", mj_step_floor)):
        base = median(lambda: floor(scenario), args.repeat)
        fast = median(lambda: closed_loop(scenario, True), args.repeat)
        slow = median(lambda: closed_loop(scenario, False), args.repeat)
        rows.append((label, floor_label, base, fast, slow))

    for label, floor_label, base, fast, slow in rows:
        ratio = fast / base
        print(f"baseline: {STEPS} {floor_label:<38s} {base:7.3f} s "
              f"({base / STEPS * 1e6:.2f} us/step)")
        print(f"{label} closed loop 20 s, compiled, no recording   {fast:7.3f} s   "
              f"ratio {ratio:5.2f}x  (target <= 1.5x)  {'MET' if ratio <= 1.5 else 'NOT MET'}")
        print(f"{label} closed loop 20 s, generic Python loop      {slow:7.3f} s   "
              f"speed-up of the compiled loop {slow / fast:5.1f}x")


if __name__ == "__main__":
    main()
