"""The gymnasium envs against the physics they step, measured in one process (issue 31).

Prints, each the median of ``--repeat`` rounds (default 3; the rounds interleave the
contenders, so that load on a shared machine falls on all of them alike):

* single env, ``tspend/pendulum_mujoco-v0`` at ``control_period=0.02`` (20 RK4 steps of
  1 ms): ``env.step`` (through ``gymnasium.make``'s wrappers) against bare
  ``mujoco.mj_step(m, d, 20)`` on the same model; the overhead per step (the difference)
  against gymnasium's own ``InvertedPendulum-v5`` (``env.step`` against ``mj_step(m, d,
  frame_skip)`` on its model) -- targets: <= 1.2x, and overhead <= 2x gymnasium's;
* vector envs at N = 1, 4, 16, 64: env-steps/s of tspend's vector env
  (``make_vec(..., vectorization_mode="vector_entry_point")``; and with ``threads=1``, the
  caller's thread alone: their ratio is what the threads give, whatever the load), of
  ``make_vec`` "sync"
  and "async" (one process per env; up to ``--async-max`` envs), of MuJoCo's
  ``rollout`` (physics only, no task: N models in its thread pool, one thread per core)
  and the one-core physics floor ``1 / (frame_skip x bare mj_step)`` -- target at N = 16:
  >= 1.6x the floor on 2 cores.

Single-env times are medians over calls, ``env.step`` and the bare ``mj_step`` (on the env's own
mjData) in turn call after call (``time.perf_counter`` around each; the resets of ended
episodes are not counted);
vector figures are N over the median time of a ``step`` call.  Medians, because on a
machine shared with other jobs a call the scheduler interrupts would otherwise count its
milliseconds of someone else's work.  Actions are 0 N: the pole falls after about 2 s (108 steps), so episodes end
and reset as in training.

Run: ``python benchmarks/env_speed.py`` (about two minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from typing import Any, Callable

import gymnasium
import mujoco
import numpy as np
import numba

import tspend.gym  # noqa: F401  (registers tspend/<scenario>-v0)
from short_mode import short_defaults

ENV_ID = "tspend/pendulum_mujoco-v0"
PERIOD = 0.02


def _paired(env: Any, action: np.ndarray, model: Any, data: Any, nstep: int, steps: int
            ) -> tuple[float, float]:
    """Median seconds of ``env.step`` and of bare ``mj_step(model, data, nstep)`` on the env's
    own mjData, call after call in turn (so that a shared machine's load, and the caches,
    fall on both alike; the bare steps only move the env on); the resets of ended
    episodes are outside the clock."""
    env.reset(seed=0)
    took = np.zeros((steps, 2))
    clock = time.perf_counter
    for k in range(steps):
        t0 = clock()
        _, _, term, trunc, _ = env.step(action)
        t1 = clock()
        mujoco.mj_step(model, data, nstep)
        t2 = clock()
        took[k] = t1 - t0, t2 - t1
        if term or trunc:
            env.reset()
    # medians: a call the scheduler interrupted (other jobs) counts as one call, not its
    # milliseconds
    return float(np.median(took[:, 0])), float(np.median(took[:, 1]))


def single_env(steps: int) -> dict[str, Callable[[], tuple[float, float]]]:
    """The single-env contenders: seconds per env step and per bare physics of it."""
    ours = gymnasium.make(ENV_ID, control_period=PERIOD)
    plant = ours.unwrapped.plant
    nstep = ours.unwrapped.frame_skip * round(ours.unwrapped.dt / plant.model.opt.timestep)
    theirs = gymnasium.make("InvertedPendulum-v5")
    skip2 = theirs.unwrapped.frame_skip
    return {
        "tspend": lambda: _paired(ours, np.zeros(1), plant.model, plant.data, nstep, steps),
        "InvertedPendulum-v5": lambda: _paired(theirs, np.zeros(1, np.float32),
                                               theirs.unwrapped.model, theirs.unwrapped.data,
                                               skip2, steps),
    }


def _vector_rate(envs: Any, steps: int) -> float:
    """Env-steps per second of ``envs.step`` (N over the median call of ``steps``;
    autoresets counted in the calls they fall in)."""
    n = envs.num_envs
    action = np.zeros((n, 1))
    envs.reset(seed=0)
    envs.step(action)
    took = np.zeros(steps)
    clock = time.perf_counter
    for k in range(steps):
        t0 = clock()
        envs.step(action)
        took[k] = clock() - t0
    return n / float(np.median(took))


def _rollout_rate(model: Any, n: int, nstep: int, calls: int, start: np.ndarray) -> float:
    """Env-steps per second of MuJoCo's ``rollout``: N copies of the model, ``nstep``
    physics steps each per call, on its thread pool (one thread per core)."""
    from mujoco import rollout

    threads = os.cpu_count() or 1
    datas = [mujoco.MjData(model) for _ in range(threads)]
    state = np.tile(start, (n, 1))
    control = np.zeros((n, nstep, model.nu))
    with rollout.Rollout(nthread=threads) as pool:
        pool.rollout([model] * n, datas, state, control, nstep=nstep)
        took = np.zeros(calls)
        clock = time.perf_counter
        for k in range(calls):
            t0 = clock()
            pool.rollout([model] * n, datas, state, control, nstep=nstep)
            took[k] = clock() - t0
        return n / float(np.median(took))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--steps", type=int, default=3000, help="single-env steps per round")
    ap.add_argument("--sizes", default="1,4,16,64")
    ap.add_argument("--async-max", type=int, default=16,
                    help="largest N run with make_vec 'async' (one process per env)")
    ap.add_argument("--vector-seconds", type=float, default=0.6,
                    help="about this long per vector measurement")
    short_defaults(ap, repeat=1, steps=300, sizes="1,4", async_max=4, vector_seconds=0.1)
    args = ap.parse_args(argv)
    sizes = [int(s) for s in args.sizes.split(",")]

    print(f"# env_speed: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"numba threads {numba.get_num_threads()}, load average "
          f"{' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    print(f"# mujoco {mujoco.__version__}, gymnasium {gymnasium.__version__}, numba "
          f"{numba.__version__}; {ENV_ID}, control_period {PERIOD} s")

    contenders = single_env(args.steps)
    for f in contenders.values():      # warm up: numba's cache, the first episode
        f()
    pairs: dict[str, list[tuple[float, float]]] = {k: [] for k in contenders}
    for _ in range(args.repeat):
        for name, f in contenders.items():
            pairs[name].append(f())
    print("\n## single env (us per step: env.step, bare mj_step of its frame_skip, the "
          "difference; median of rounds)")
    med = {}
    for name, runs in pairs.items():
        env_s = statistics.median(e for e, _ in runs)
        bare_s = statistics.median(b for _, b in runs)
        over_s = statistics.median(e - b for e, b in runs)
        med[name] = (env_s, bare_s, over_s)
        print(f"{name:20s} env.step {env_s * 1e6:8.2f} us ({1 / env_s:7.0f} steps/s)  bare "
              f"{bare_s * 1e6:8.2f} us  overhead {over_s * 1e6:7.2f} us   rounds "
              + " ".join(f"{e * 1e6:.1f}/{b * 1e6:.1f}" for e, b in runs))
    ours, bare, over = med["tspend"]
    over2 = med["InvertedPendulum-v5"][2]
    print(f"tspend env.step / bare mj_step x20   {ours / bare:.3f}x   (target <= 1.2)")
    print(f"overhead tspend {over * 1e6:.2f} us, InvertedPendulum-v5 {over2 * 1e6:.2f} us: "
          f"{over / over2:.2f}x   (target <= 2)")

    print("\n## vector envs (env-steps/s, median of rounds)")
    probe = gymnasium.make(ENV_ID, control_period=PERIOD).unwrapped
    probe.reset(seed=0)
    model = probe.plant.model
    nstep = probe.frame_skip * round(probe.dt / model.opt.timestep)
    size = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    start = np.zeros(size)
    mujoco.mj_getState(model, probe.plant.data, start, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    floor = 1.0 / bare            # one core: one env-step costs frame_skip bare mj_steps
    print(f"one-core physics floor 1 / (20 x bare mj_step) = {floor:.0f} env-steps/s "
          f"(on c cores: c x this)")
    print(f"{'N':>3s} {'tspend vector':>14s} {'1 thread':>9s} {'sync':>10s} {'async':>10s} "
          f"{'rollout':>10s}  {'vec/floor':>9s} {'vec/1thr':>8s} {'vec/sync':>8s} "
          f"{'vec/async':>9s} {'vec/rollout':>11s}")
    for n in sizes:
        made = {"tspend vector": gymnasium.make_vec(ENV_ID, num_envs=n, control_period=PERIOD,
                                                    vectorization_mode="vector_entry_point"),
                "1 thread": gymnasium.make_vec(ENV_ID, num_envs=n, control_period=PERIOD,
                                               vectorization_mode="vector_entry_point",
                                               threads=1),
                "sync": gymnasium.make_vec(ENV_ID, num_envs=n, control_period=PERIOD,
                                           vectorization_mode="sync")}
        if n <= args.async_max:
            made["async"] = gymnasium.make_vec(ENV_ID, num_envs=n, control_period=PERIOD,
                                               vectorization_mode="async")
        rates: dict[str, list[float]] = {k: [] for k in (*made, "rollout")}
        # about vector_seconds each at the floor's speed
        steps = max(5, int(args.vector_seconds * floor / n))
        for name, envs in made.items():
            _vector_rate(envs, 2)
        for _ in range(args.repeat):
            for name, envs in made.items():
                rates[name].append(_vector_rate(envs, steps))
            rates["rollout"].append(_rollout_rate(model, n, nstep, steps, start))
        for envs in made.values():
            envs.close()
        r = {k: statistics.median(v) for k, v in rates.items() if v}
        vec = r["tspend vector"]
        a = r.get("async")
        one = r["1 thread"]
        print(f"{n:3d} {vec:14.0f} {one:9.0f} {r['sync']:10.0f} {a if a else float('nan'):10.0f} "
              f"{r['rollout']:10.0f}  {vec / floor:9.2f} {vec / one:8.2f} {vec / r['sync']:8.2f} "
              f"{vec / a if a else float('nan'):9.2f} {vec / r['rollout']:11.2f}")
    print("\ntargets: N=16 tspend vector >= 1.6x floor (2 cores); >= 3x 4,460 env-steps/s "
          "(the issue's make_vec sync at N=8) = 13,380")


if __name__ == "__main__":
    main()
