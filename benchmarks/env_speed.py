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

Single-env times are per call (``time.perf_counter`` around ``step`` only: the resets of
ended episodes are not counted); vector times are whole loops of ``step`` (autoresets
counted).  Actions are 0 N: the pole falls after about 2 s (108 steps), so episodes end
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

ENV_ID = "tspend/pendulum_mujoco-v0"
PERIOD = 0.02


def _per_step(env: Any, action: np.ndarray, steps: int) -> float:
    """Seconds per ``env.step``, the calls alone (resets outside the clock)."""
    env.reset(seed=0)
    spent = 0.0
    clock = time.perf_counter
    for _ in range(steps):
        t0 = clock()
        _, _, term, trunc, _ = env.step(action)
        spent += clock() - t0
        if term or trunc:
            env.reset()
    return spent / steps


def _bare(model: Any, nstep: int, steps: int, qpos: np.ndarray, qvel: np.ndarray) -> float:
    """Seconds per ``mj_step(m, d, nstep)`` from the env's start, restarted every 50 calls."""
    data = mujoco.MjData(model)
    spent = 0.0
    clock = time.perf_counter
    for k in range(steps):
        if k % 50 == 0:
            mujoco.mj_resetData(model, data)
            data.qpos[:], data.qvel[:] = qpos, qvel
            mujoco.mj_forward(model, data)
        t0 = clock()
        mujoco.mj_step(model, data, nstep)
        spent += clock() - t0
    return spent / steps


def single_env(steps: int) -> dict[str, Callable[[], float]]:
    """The single-env contenders: seconds per step of each."""
    ours = gymnasium.make(ENV_ID, control_period=PERIOD)
    plant = ours.unwrapped.plant
    nstep = ours.unwrapped.frame_skip * round(ours.unwrapped.dt / plant.model.opt.timestep)
    ours.reset(seed=0)
    start = (plant.data.qpos.copy(), plant.data.qvel.copy())
    theirs = gymnasium.make("InvertedPendulum-v5")
    theirs.reset(seed=0)
    m2 = theirs.unwrapped.model
    start2 = (theirs.unwrapped.data.qpos.copy(), theirs.unwrapped.data.qvel.copy())
    skip2 = theirs.unwrapped.frame_skip
    zero = np.zeros(1)
    return {
        "tspend env.step": lambda: _per_step(ours, zero, steps),
        "tspend bare mj_step": lambda: _bare(plant.model, nstep, steps, *start),
        "InvertedPendulum-v5 env.step": lambda: _per_step(theirs, np.zeros(1, np.float32),
                                                          steps),
        "InvertedPendulum-v5 bare mj_step": lambda: _bare(m2, skip2, steps, *start2),
    }


def _vector_rate(envs: Any, steps: int) -> float:
    """Env-steps per second of ``steps`` calls of ``envs.step`` (autoresets counted)."""
    n = envs.num_envs
    action = np.zeros((n, 1))
    envs.reset(seed=0)
    envs.step(action)
    t0 = time.perf_counter()
    for _ in range(steps):
        envs.step(action)
    return n * steps / (time.perf_counter() - t0)


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
        t0 = time.perf_counter()
        for _ in range(calls):
            pool.rollout([model] * n, datas, state, control, nstep=nstep)
        return n * calls / (time.perf_counter() - t0)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--steps", type=int, default=3000, help="single-env steps per round")
    ap.add_argument("--sizes", default="1,4,16,64")
    ap.add_argument("--async-max", type=int, default=16,
                    help="largest N run with make_vec 'async' (one process per env)")
    ap.add_argument("--vector-seconds", type=float, default=0.6,
                    help="about this long per vector measurement")
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
    times: dict[str, list[float]] = {k: [] for k in contenders}
    for _ in range(args.repeat):
        for name, f in contenders.items():
            times[name].append(f())
    med = {k: statistics.median(v) for k, v in times.items()}
    ours, bare = med["tspend env.step"], med["tspend bare mj_step"]
    theirs, bare2 = med["InvertedPendulum-v5 env.step"], med["InvertedPendulum-v5 bare mj_step"]
    print("\n## single env (median of rounds; us per step)")
    for k, v in med.items():
        print(f"{k:34s} {v * 1e6:9.2f} us   {1 / v:10.0f} steps/s   "
              f"rounds {' '.join(f'{t * 1e6:.2f}' for t in times[k])}")
    over, over2 = ours - bare, theirs - bare2
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
