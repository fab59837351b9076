"""The MJX vector env's host time per step at two batch sizes, in one run.

    python benchmarks/mjx_env_host.py                 # 64 and 4096 envs, 200 steps each
    python benchmarks/mjx_env_host.py --pin           # the device's threads on a core of their own
    python benchmarks/mjx_env_host.py --host-alone    # the host's own work, the device stubbed

Both envs are built first, then stepped (zero actions) in alternating blocks of
``--block`` steps, so a change of the machine's load falls on both sizes alike.  A step's
host time is the time the host spends on it outside the device's computation: this
thread's CPU time over the step less its CPU time waiting for the device's result, the
jitted call's dispatch counted as the host's (:func:`accelerator_speed.timed_env`; on
JAX's CPU backend the device's computation runs on other threads, and a wall clock would
count it whenever they share a core with this one).  They still share this thread's
caches; ``--pin`` puts JAX's threads on the last core and this thread on the first (as an
accelerator has its own silicon; Linux, two cores or more).  The baseline for that: a
fixed piece of host work, the same at every N (:func:`fixed_host_work`), timed right after
the device's result at every other step (those steps' host times are not used): its
ratio between the sizes is what the device's computation alone does to the host's time
on this machine.  Prints, per N, env-steps/s and the host's
milliseconds per step as the median with the 25th-75th percentiles beside it (the spread
shows the noise) and the median of its part in the jitted call's dispatch, the ratio of the larger N's median to the smaller's, both measured in
this run (what the host does per step should not grow with N: docs/accelerator.md), and
the 1-minute load average before and after.

A second baseline, MJX's own step alone (:func:`timed_bare`): the same models and data
stepped by one jitted call of MJX's physics with nothing of tspend's (no endings,
observations, rewards or restarts), its dispatch and the read-back of one number per env
timed the same way, in a block of its own after each of the env's.  Its ratio between the sizes is what JAX's backend
charges any MJX program's host as N grows (on the CPU backend the call's dispatch grows
with the buffers its kernels partition); the env's ratio is compared with it.

``--host-alone`` times the host's own work with no device computation beside it: each
env's jitted step is replaced by a copy of one packed result it returned (the copy stands
in for reading the result back), so neither JAX's threads nor the caches they fill share
the machine with the host's work: what an accelerator with its own memory would leave.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import Any, Callable

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from accelerator_speed import timed_env  # noqa: E402
from short_mode import short_defaults  # noqa: E402


def fixed_host_work(x: np.ndarray = np.zeros(64)) -> None:
    """Host work that does not depend on N: the numpy calls of a step at 64 envs (clip,
    copies, comparisons, a dict), twenty times over."""
    for _ in range(20):
        u = np.clip(x, -1.0, 1.0)
        ended = u != 0.0
        _ = {"u": u.copy(), "t": u * 0.02, "_u": ended.copy(), "any": ended.any()}


def stub_device(device, n: int) -> None:
    """``device.step`` replaced by a copy of the packed result of one real step; the timed
    call (``device.call``) is not reached, so its dispatch and wait read 0."""
    packed = device.step(np.zeros(n))
    device.step = lambda u: packed.copy()


def timed_bare(env: Any) -> Callable[[], float]:
    """``step()`` of MJX's own physics for the env's models and data, jitted alone (no
    endings, observations, rewards or restarts: what any MJX program pays), returning
    the host's seconds for it, counted as :func:`accelerator_speed.timed_env` counts the
    env's: the call's dispatch and the read-back of one number per env, not the wait for
    the device."""
    import jax
    import jax.numpy as jnp
    from mujoco import mjx

    from tspend.mjx.sweep import mujoco_steps
    from tspend.mjx.vector_env import flat_io

    venv = env.unwrapped
    device, fleet = venv._device, venv.fleet
    model_of, data_of, buffers_of = flat_io(device.trees)
    act, nstep, skip, cap = fleet.actuator, fleet.nstep, venv.frame_skip, fleet.max_input

    def one(model, data, u):
        data = data.replace(ctrl=data.ctrl.at[act].set(u))
        return jax.lax.fori_loop(
            0, skip, lambda _, d: mujoco_steps(mjx, model, d, nstep, cap)[0], data)

    every = jax.vmap(one, in_axes=(fleet.in_axes, 0, 0))

    def flat(model, data, u):
        data = every(model_of(model), data_of(data), u)
        return buffers_of(data), data.qpos[:, 0]

    call = jax.jit(flat, donate_argnums=(1,))
    held, u = [tuple(jnp.copy(a) for a in device.data0)], np.zeros(fleet.n_envs)

    def step() -> float:
        c = time.thread_time()
        out = call(device.model, held[0], u)
        dispatched = time.thread_time()
        jax.block_until_ready(out)
        waited = time.thread_time() - dispatched
        held[0] = out[0]
        np.asarray(out[1])
        return time.thread_time() - c - waited

    step()                                          # compiles
    return step


def _bad(message: str) -> int:
    """Bad input: one line on stderr, exit status 2."""
    print(f"mjx_env_host: {message}", file=sys.stderr)
    return 2


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="the MJX vector env's host time per step at two "
                                            "batch sizes (docs/accelerator.md)")
    p.add_argument("--envs", default="64,4096", help="two batch sizes (default 64,4096)")
    p.add_argument("--steps", type=int, default=200,
                   help="steps timed per size, their median reported (default 200)")
    p.add_argument("--block", type=int, default=20,
                   help="steps of one size before the other's turn (default 20)")
    p.add_argument("--scenario", default="pendulum_mujoco", help="(default pendulum_mujoco)")
    p.add_argument("--pin", action="store_true",
                   help="JAX's threads (the device's computation on the CPU backend) on the "
                        "last core, this thread on the first (default: both anywhere)")
    p.add_argument("--host-alone", action="store_true",
                   help="stub the device: each step returns a copy of one packed result, so "
                        "only the host's own work is timed (default: the real step)")
    short_defaults(p, envs="4,16", steps=4, block=2)
    args = p.parse_args(argv)
    try:
        small, large = (int(v) for v in args.envs.split(","))
    except ValueError:
        return _bad(f"--envs {args.envs!r}: two integers, e.g. 64,4096")
    if not (1 <= small <= 1 << 20 and 1 <= large <= 1 << 20 and 1 <= args.steps <= 1000
            and 1 <= args.block <= args.steps):
        return _bad("--envs each from 1 to 1048576, --steps from 1 to 1000, --block from 1 "
                    "to --steps")
    print(f"load average (1 min) before: {os.getloadavg()[0]:.2f}", flush=True)
    cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if args.pin and len(cores) < 2:
        return _bad("--pin needs Linux and two cores or more")
    if args.pin:       # JAX's threads, made while the envs are built, inherit this core
        os.sched_setaffinity(0, {cores[-1]})
    envs = {n: timed_env(args.scenario, n, "float64") for n in (small, large)}
    if args.host_alone:
        for n, (env, _) in envs.items():
            stub_device(env.unwrapped._device, n)
        print("host alone: the device's step stubbed by a copy of one packed result")
    if args.pin:       # this thread only (0: the calling thread)
        os.sched_setaffinity(0, {cores[0]})
        print(f"pinned: JAX's threads on core {cores[-1]}, this thread on core {cores[0]}")
    bare = {} if args.host_alone else {n: timed_bare(env) for n, (env, _) in envs.items()}
    times = {n: [] for n in envs}          # (wall s, host s, probe s, dispatch s) per step
    probed = {n: [] for n in envs}                 # the same, steps with the fixed work
    bare_s = {n: [] for n in envs}                 # host s of MJX's own step alone
    while len(times[large]) < args.steps:
        for n, (_, step) in envs.items():
            block = min(args.block, args.steps - len(times[n]))
            for _ in range(block):
                times[n].append(step())
                probed[n].append(step(fixed_host_work))
            # a block of its own: a bare step between the env's would change what the
            # env's step finds in the caches
            for _ in range(block if bare else 0):
                bare_s[n].append(bare[n]())
    host, fixed = {}, {}
    for n, (env, _) in envs.items():
        env.close()
        wall, host_s, _, dispatch_s = np.array(times[n]).T
        p25, host[n], p75 = 1e3 * np.percentile(host_s, [25, 50, 75])
        fixed[n] = 1e3 * float(np.median(np.array(probed[n])[:, 2]))
        print(f"{args.scenario} N {n} env-steps/s {n * len(wall) / wall.sum():.3g} "
              f"host ms/step {host[n]:.3g} p25-p75 {p25:.3g}-{p75:.3g} "
              f"of it dispatch ms {1e3 * np.median(dispatch_s):.3g} "
              f"fixed host work ms {fixed[n]:.3g}", flush=True)
    print(f"host time per step at {large} over {small}: {host[large] / host[small]:.2f} "
          f"(baseline: {host[small]:.3g} ms at {small} envs, same run; medians of "
          f"{args.steps} steps each)")
    if bare:
        mjx_ms = {n: 1e3 * float(np.median(v)) for n, v in bare_s.items()}
        print(f"MJX's own step alone, host ms/step: {mjx_ms[small]:.3g} at {small}, "
              f"{mjx_ms[large]:.3g} at {large}: {mjx_ms[large] / mjx_ms[small]:.2f} "
              f"(the same dispatch and read-back, no tspend: what JAX's backend charges "
              f"the host as N grows)")
        print(f"tspend's env over MJX's own step: {host[small] / mjx_ms[small]:.2f} at "
              f"{small}, {host[large] / mjx_ms[large]:.2f} at {large}")
    if not args.host_alone:    # (no device result to follow)
        print(f"fixed host work at {large} over {small}: {fixed[large] / fixed[small]:.2f} "
              f"(the same work at both sizes, right after the device's result: what the "
              f"device's computation does to the host's time here)")
    print(f"load average (1 min) after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
