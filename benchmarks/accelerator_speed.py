"""tspend's MJX sweep and vector env beside the bare MJX loop and mujoco.batch, in one run.

    python benchmarks/accelerator_speed.py                      # small sizes: any CPU
    python benchmarks/accelerator_speed.py --envs 1024,16384,131072 --precision float32,float64 \\
        --machines cartpole,double_cartpole,triple_cartpole     # on a GPU

For each machine (tspend's scenario of that model: its MJCF as the CPU plant compiles it,
its full-state LQR gain designed on the CPU) and batch size N, on the same machine:

* ``mjx loop``: N closed loops u = -K s (the LQR's state feedback) in a jax.lax.scan of
  ``--steps`` physics steps of mjx.step under jax.vmap, per precision: physics steps/s of
  all envs together (the second call; the first, compile included, is ``compile_s``);
* ``batch``: the same loop on ``mujoco.batch.Batch`` (MuJoCo's C step on every core of
  this machine, ``nthread=0``): steps/s;
* ``cpu env`` and ``mjx env`` (where tspend imports, at N up to ``--env-max``): env-steps/s
  of ``gymnasium.make_vec(..., vectorization_mode="vector_entry_point")`` on the CPU
  backend (its threads on every core) and with ``backend="mjx"``, zero actions;

and prints the ratios mjx loop / batch and mjx / cpu env.  Then tspend's own paths at each N
(where tspend imports, N up to ``--tspend-max``), beside the bare loop at that N:

* ``sweep``: ``tspend sweep --backend mjx``'s program (:mod:`tspend.mjx.sweep`: the LQR
  law, the reference and disturbance, every ending and metric folded on the device) on N
  machines the scenario's ``[randomize]`` draws, ``--steps`` samples: physics steps/s of
  the second call, and its ratio to the bare loop's;
* ``mjx env``: ``backend="mjx"``'s vector env at N: env-steps/s and the host's time per
  step (this thread's CPU time over the step outside its wait for the device's result,
  the call's dispatch included: :func:`timed_env`), so what grows with N on the host.

``--prepare DIR`` writes what the device part needs (each model as MuJoCo's binary .mjb,
the gain, the start state, and the scenarios tspend's rows run) and stops; ``--plan DIR``
runs from it: the bare loop with only MuJoCo, MJX, JAX and numpy, tspend's rows where the
device's checkout imports tspend (a line says when it does not).  ``--json FILE``
appends one JSON line per measurement.  ``--departure`` also measures MJX's departure
from CPU MuJoCo after 0.1 s and 1 s from the same states (float64 and float32).
docs/accelerator.md.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

#: the machines and the scenario that gives each its model and gain
MACHINES = {"cartpole": "pendulum_mujoco", "double_cartpole": "double_cartpole_mujoco",
            "triple_cartpole": "triple_cartpole_mujoco", "acrobot": "acrobot_mujoco",
            "pendubot": "pendubot_mujoco", "reaction_wheel": "reaction_wheel_mujoco",
            "rotary_double": "rotary_double_mujoco", "furuta": "furuta_mujoco"}
MAX_ENVS = 1 << 20
#: the scenario each machine's tspend rows run: its randomised form where one ships
RANDOMIZED = {"cartpole": "pendulum_mujoco_randomized",
              "double_cartpole": "double_cartpole_mujoco_randomized"}


def _ints(text: str, what: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise SystemExit(f"accelerator_speed: {what} {text!r}: integers separated by commas")
    if not values or any(not 1 <= v <= MAX_ENVS for v in values):
        raise SystemExit(f"accelerator_speed: {what} {text!r}: each from 1 to {MAX_ENVS}")
    return values


def prepare(machines: list[str], where: Path) -> dict:
    """Each machine's model (.mjb), LQR gain and start state, computed with tspend."""
    import mujoco
    import warnings

    from tspend.loop.simulation import prepare as prepare_run
    from tspend.mjx.machines import build_fleet
    from tspend.scenario import load_scenario

    where.mkdir(parents=True, exist_ok=True)
    plan = {}
    for name in machines:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            scn = load_scenario(MACHINES[name])
            fleet = build_fleet(scn, [scn.run.seed], steps=1)
            ctrl = prepare_run(fleet.scenario, controller="lqr").controller
        K = np.asarray(getattr(ctrl, "K"), dtype=float)
        if K.size != fleet.qpos0.shape[1] + fleet.qvel0.shape[1]:
            raise SystemExit(f"accelerator_speed: {name}: the lqr gain is not full-state")
        path = where / f"{name}.mjb"
        mujoco.mj_saveModel(fleet.plant.model, str(path), None)
        plan[name] = {"model": path.name, "K": K.tolist(), "actuator": fleet.actuator,
                      "nstep": fleet.nstep, "qpos0": fleet.qpos0[0].tolist(),
                      "qvel0": fleet.qvel0[0].tolist(), "scenario": MACHINES[name],
                      "sweep_scenario": RANDOMIZED.get(name, MACHINES[name])}
    (where / "plan.json").write_text(json.dumps(plan, indent=1))
    return plan


def mjx_loop(model, spec: dict, n: int, steps: int, precision: str) -> tuple[float, float]:
    """(compile + first call s, steps/s of the second call) of n closed loops."""
    import jax
    import jax.numpy as jnp
    from mujoco import mjx

    jax.config.update("jax_enable_x64", precision == "float64")
    dtype = jnp.float64 if precision == "float64" else jnp.float32
    mx = jax.tree_util.tree_map(
        lambda x: x.astype(dtype) if hasattr(x, "dtype") and jnp.issubdtype(x.dtype, jnp.floating)
        else x, mjx.put_model(model))
    K = jnp.asarray(spec["K"], dtype=dtype)
    act, nstep = spec["actuator"], spec["nstep"]
    rng = np.random.default_rng(0)
    q0 = np.asarray(spec["qpos0"]) + 0.01 * rng.uniform(-1, 1, (n, len(spec["qpos0"])))
    v0 = np.broadcast_to(np.asarray(spec["qvel0"]), (n, len(spec["qvel0"])))
    d0 = mjx.make_data(mx)
    data = jax.vmap(lambda q, v: d0.replace(qpos=q, qvel=v))(jnp.asarray(q0, dtype),
                                                           jnp.asarray(v0, dtype))

    def run(data):
        def sample(d, _):
            s = jnp.concatenate((d.qpos, d.qvel))
            d = d.replace(ctrl=d.ctrl.at[act].set(-(K @ s)))
            for _ in range(nstep):
                d = mjx.step(mx, d)
            return d, None

        return jax.lax.scan(sample, data, None, length=steps)[0]

    f = jax.jit(jax.vmap(run))
    t0 = time.perf_counter()
    jax.block_until_ready(f(data))
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = jax.block_until_ready(f(data))
    took = time.perf_counter() - t0
    if not np.isfinite(np.asarray(out.qpos)).all():
        raise SystemExit("accelerator_speed: the MJX closed loop diverged")
    return first, n * steps / took


def batch_loop(model, spec: dict, n: int, steps: int) -> float:
    """steps/s of n closed loops on mujoco.batch.Batch (every core)."""
    from mujoco import batch as mjbatch

    b = mjbatch.Batch(model, nsim=n, nthread=0)
    qpos, qvel, ctrl = b.bind("qpos"), b.bind("qvel"), b.bind("ctrl")
    rng = np.random.default_rng(0)
    qpos[:] = np.asarray(spec["qpos0"]) + 0.01 * rng.uniform(-1, 1, qpos.shape)
    qvel[:] = np.asarray(spec["qvel0"])
    K = np.asarray(spec["K"])
    nq = qpos.shape[1]
    act, nstep = spec["actuator"], spec["nstep"]
    t0 = time.perf_counter()
    for _ in range(steps):
        ctrl[:, act] = -(qpos @ K[:nq] + qvel @ K[nq:])
        b.step(nstep=nstep)
    return n * steps / (time.perf_counter() - t0)


def env_rates(scenario: str, n: int, steps: int) -> tuple[float, float, float]:
    """(cpu env-steps/s, mjx env-steps/s, mjx env compile s) of tspend's vector env."""
    import warnings

    import gymnasium

    import tspend.gym  # noqa: F401

    rates, compile_s = [], 0.0
    for backend in ("cpu", "mjx"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            envs = gymnasium.make_vec(f"tspend/{scenario}-v0", num_envs=n,
                                      vectorization_mode="vector_entry_point", backend=backend)
        envs.reset(seed=0)
        a = np.zeros((n, 1))
        t0 = time.perf_counter()
        envs.step(a)
        if backend == "mjx":
            compile_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        for _ in range(steps):
            envs.step(a)
        rates.append(n * steps / (time.perf_counter() - t0))
        envs.close()
    return rates[0], rates[1], compile_s


def departure(model, spec: dict) -> dict:
    """Largest |s_mjx - s_cpu| after 100 and 1000 steps of the closed loop from the same
    16 states, per precision (each backend closing the loop on its own state)."""
    import mujoco

    n, out = 16, {}
    rng = np.random.default_rng(1)
    q0 = np.asarray(spec["qpos0"]) + 0.01 * rng.uniform(-1, 1, (n, len(spec["qpos0"])))
    K, act = np.asarray(spec["K"]), spec["actuator"]
    cpu = {}
    for horizon in (100, 1000):
        states = []
        for i in range(n):
            d = mujoco.MjData(model)
            d.qpos[:], d.qvel[:] = q0[i], spec["qvel0"]
            for _ in range(horizon):
                d.ctrl[act] = -(K @ np.concatenate((d.qpos, d.qvel)))
                mujoco.mj_step(model, d, spec["nstep"])
            states.append(np.concatenate((d.qpos, d.qvel)))
        cpu[horizon] = np.array(states)
    for precision in ("float64", "float32"):
        import jax
        import jax.numpy as jnp
        from mujoco import mjx

        jax.config.update("jax_enable_x64", precision == "float64")
        dtype = jnp.float64 if precision == "float64" else jnp.float32
        mx = jax.tree_util.tree_map(
            lambda x: x.astype(dtype) if hasattr(x, "dtype") and jnp.issubdtype(x.dtype, jnp.floating)
            else x, mjx.put_model(model))
        Kj = jnp.asarray(K, dtype)
        d0 = mjx.make_data(mx)

        def run(q, horizon):
            def sample(d, _):
                d = d.replace(ctrl=d.ctrl.at[act].set(-(Kj @ jnp.concatenate((d.qpos, d.qvel)))))
                for _ in range(spec["nstep"]):
                    d = mjx.step(mx, d)
                return d, None

            d = d0.replace(qpos=q, qvel=jnp.asarray(spec["qvel0"], dtype))
            d = jax.lax.scan(sample, d, None, length=horizon)[0]
            return jnp.concatenate((d.qpos, d.qvel))

        for horizon in (100, 1000):
            f = jax.jit(jax.vmap(lambda q: run(q, horizon)))
            got = np.asarray(f(jnp.asarray(q0, dtype)), dtype=float)
            out[f"{precision}_{horizon}"] = float(np.abs(got - cpu[horizon]).max())
    return out


def sweep_rate(scenario: str, n: int, steps: int, precision: str) -> tuple[float, float]:
    """(compile + first call s, physics steps/s of the second call) of tspend's MJX sweep
    program on n machines of ``scenario`` (seeds 0 .. n-1), ``steps`` samples."""
    import warnings

    import jax

    from tspend.loop.simulation import prepare as prepare_run
    from tspend.mjx import sweep as mjx_sweep
    from tspend.mjx.machines import build_fleet
    from tspend.scenario import load_scenario, override

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scn = load_scenario(scenario)
        scn = override(scn, **{"run.duration": steps * scn.run.dt})
        fleet = build_fleet(scn, range(n))
        ctrl = prepare_run(fleet.scenario, controller="lqr").controller
    program = mjx_sweep.prepare_program(fleet, ctrl, precision)
    inputs = mjx_sweep.batch_inputs(fleet, np.arange(n), program)
    t0 = time.perf_counter()
    mjx_sweep.run_batch(program.run, inputs)
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    jax.block_until_ready(mjx_sweep.run_batch(program.run, inputs))
    return first, n * fleet.steps / (time.perf_counter() - t0)


def timed_env(scenario: str, n: int, precision: str) -> tuple[Any, Any]:
    """The MJX vector env at n envs, reset and compiled, and ``step(probe=None)`` that steps
    it with zero actions and returns (wall s, host s, probe s, dispatch s) of that step.  The host's time is what this
    thread spends computing per step outside the device's computation: its CPU time over
    the step (``time.thread_time``) less its CPU time while it waits for the device's
    result.  The jitted call's dispatch (its arguments, the launch) is the host's work and
    counted (and returned on its own as dispatch s); the wait is not, nor is time this
    thread is off the CPU (another process's,
    or the device's own threads on JAX's CPU backend).  ``probe``, a callable, runs right
    after the wait; its CPU time is returned as probe s and not counted as the host's (a
    step with a probe warms the caches for its own host work: time one or the other)."""
    import warnings

    import gymnasium
    import jax

    import tspend.gym  # noqa: F401

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        envs = gymnasium.make_vec(f"tspend/{scenario}-v0", num_envs=n, precision=precision,
                                  vectorization_mode="vector_entry_point", backend="mjx")
    device = envs.unwrapped._device          # what the envs keep on the device
    waited_cpu_s, probe_cpu_s, probes, dispatch_s = [0.0], [0.0], [None], [0.0]
    call = device.call

    def timed(*args):
        d = time.thread_time()
        out = call(*args)                      # dispatched: the host's work
        c = time.thread_time()
        dispatch_s[0] = c - d
        jax.block_until_ready(out)
        p = time.thread_time()
        if probes[0] is not None:
            probes[0]()
        probe_cpu_s[0] = time.thread_time() - p
        waited_cpu_s[0] += time.thread_time() - c
        return out

    device.call = timed
    envs.reset(seed=0)
    a = np.zeros((n, 1))
    envs.step(a)                                   # compiles

    def step(probe: Any = None) -> tuple[float, float, float, float]:
        waited_cpu_s[0], probes[0], probe_cpu_s[0], dispatch_s[0] = 0.0, probe, 0.0, 0.0
        t, c = time.perf_counter(), time.thread_time()
        envs.step(a)
        wall, cpu = time.perf_counter() - t, time.thread_time() - c
        return wall, cpu - waited_cpu_s[0], probe_cpu_s[0], dispatch_s[0]

    return envs, step


def env_host(scenario: str, n: int, steps: int, precision: str) -> tuple[float, float]:
    """(env-steps/s, host ms per step) of the MJX vector env at n envs (:func:`timed_env`),
    the median step's host time: on a shared machine a step now and then waits for
    another process."""
    envs, step = timed_env(scenario, n, precision)
    wall, host, _, _ = np.array([step() for _ in range(steps)]).T
    envs.close()
    return n * steps / wall.sum(), 1e3 * float(np.median(host))


def tspend_rows(plan: dict, machines: list[str], sizes: list[int], args: Any,
                bare: dict, emit: Any) -> None:
    """The sweep and env rows of tspend's own paths (module docstring)."""
    try:
        import tspend  # noqa: F401
    except ImportError as exc:
        print(f"tspend's rows not run: tspend does not import here ({exc})")
        return
    print(f"{'machine':<16} {'N':>7} {'precision':>9} {'sweep':>10} {'sweep/loop':>10} "
          f"{'sweep compile_s':>15} {'mjx env':>10} {'env host ms/step':>16}")
    for name in machines:
        spec = plan[name]
        for n in (v for v in sizes if v <= args.tspend_max):
            for q in args.precisions:
                first, rate = sweep_rate(spec.get("sweep_scenario", spec["scenario"]), n,
                                         args.steps, q)
                env_rate, host_ms = env_host(spec["scenario"], n, args.env_steps, q)
                loop = bare.get((name, n, q), float("nan"))
                emit({"machine": name, "envs": n, "precision": q, "sweep": rate,
                      "sweep_compile_s": first, "sweep_over_loop": rate / loop,
                      "mjx_env": env_rate, "env_host_ms": host_ms})
                print(f"{name:<16} {n:>7} {q:>9} {rate:>10.3g} {rate / loop:>10.3g} "
                      f"{first:>15.1f} {env_rate:>10.3g} {host_ms:>16.3g}", flush=True)
    print("sweep: physics steps/s of tspend's whole MJX sweep program (law, endings, metrics); "
          "mjx env: env-steps/s and the host's ms per step of the MJX vector env")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="MJX closed loops against tspend's CPU vector env "
                                            "and mujoco.batch, in one run (docs/accelerator.md)")
    p.add_argument("--machines", default="cartpole",
                   help=f"comma-separated, of {', '.join(MACHINES)} (default cartpole)")
    p.add_argument("--envs", default="1,64", help="batch sizes (default 1,64; a GPU: "
                                                   "1024,16384,131072)")
    p.add_argument("--steps", type=int, default=200, help="physics steps per loop (default 200)")
    p.add_argument("--precision", default="float64",
                   help="float64, float32 or both comma-separated (default float64)")
    p.add_argument("--batch-max", type=int, default=16384,
                   help="the largest N run on mujoco.batch (its time grows with N; default 16384)")
    p.add_argument("--env-max", type=int, default=64,
                   help="the largest N run on the vector envs (default 64; 0: skip them)")
    p.add_argument("--tspend-max", type=int, default=4096,
                   help="the largest N of tspend's sweep and env rows (default 4096; 0: skip)")
    p.add_argument("--env-steps", type=int, default=5,
                   help="steps of the MJX vector env timed per N (default 5)")
    p.add_argument("--departure", action="store_true",
                   help="also measure MJX's departure from CPU MuJoCo (float64, float32)")
    p.add_argument("--prepare", metavar="DIR", help="write the plan for --plan and stop")
    p.add_argument("--plan", metavar="DIR", help="run from a plan (needs no tspend)")
    p.add_argument("--json", metavar="FILE", help="append one JSON line per measurement")
    args = p.parse_args(argv)
    machines = [m for m in args.machines.split(",") if m]
    unknown = [m for m in machines if m not in MACHINES]
    if unknown or not machines:
        raise SystemExit(f"accelerator_speed: --machines {args.machines}: allowed: "
                         f"{', '.join(MACHINES)}")
    sizes = _ints(args.envs, "--envs")
    if not 1 <= args.steps <= 100_000:
        raise SystemExit("accelerator_speed: --steps: from 1 to 100000")
    if not 1 <= args.env_steps <= 10_000 or not 0 <= args.tspend_max <= MAX_ENVS:
        raise SystemExit("accelerator_speed: --env-steps from 1 to 10000, --tspend-max from 0 "
                         f"to {MAX_ENVS}")
    precisions = [q for q in args.precision.split(",") if q]
    if not precisions or any(q not in ("float64", "float32") for q in precisions):
        raise SystemExit(f"accelerator_speed: --precision {args.precision}: float64, float32")
    if args.prepare:
        if (Path(args.prepare) / "plan.json").exists():
            raise SystemExit(f"accelerator_speed: {args.prepare}/plan.json exists; choose "
                             f"another --prepare directory")
        prepare(machines, Path(args.prepare))
        print(f"plan written to {args.prepare}")
        return 0
    import jax
    import mujoco

    if args.plan:
        where = Path(args.plan)
        plan = json.loads((where / "plan.json").read_text())
        tspend_here = False
    else:
        where = Path(os.environ.get("TMPDIR", "/tmp")) / f"tspend-accel-{os.getpid()}"
        plan = prepare(machines, where)
        tspend_here = True
    device = jax.devices()[0]
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(f"device: {device.platform} ({device.device_kind}); CPU: {cores} cores; "
          f"MuJoCo {mujoco.__version__}; JAX {jax.__version__}; {args.steps} steps per loop")
    sink = open(args.json, "a") if args.json else None

    def emit(row: dict) -> None:
        if sink is not None:
            sink.write(json.dumps({**row, "device": device.device_kind}) + "\n")
            sink.flush()

    header = (f"{'machine':<16} {'N':>7} {'precision':>9} {'compile_s':>9} {'mjx loop':>10} "
              f"{'batch':>10} {'loop/batch':>10} {'cpu env':>10} {'mjx env':>10} "
              f"{'mjx loop/cpu env':>16} {'mjx env/cpu env':>15}")
    print(header)
    bare: dict = {}
    for name in machines:
        spec = plan[name]
        model = mujoco.MjModel.from_binary_path(str(where / spec["model"]))
        for n in sizes:
            rate_b = batch_loop(model, spec, n, args.steps) if n <= args.batch_max else float("nan")
            env_cpu = env_mjx = float("nan")
            if tspend_here and 0 < n <= args.env_max:
                env_cpu, env_mjx, _ = env_rates(spec["scenario"], n, args.steps)
            for q in precisions:
                first, rate = mjx_loop(model, spec, n, args.steps, q)
                bare[(name, n, q)] = rate
                row = {"machine": name, "envs": n, "precision": q, "compile_s": first,
                       "mjx_loop": rate, "batch": rate_b, "cpu_env": env_cpu, "mjx_env": env_mjx}
                emit(row)
                print(f"{name:<16} {n:>7} {q:>9} {first:>9.1f} {rate:>10.3g} {rate_b:>10.3g} "
                      f"{rate / rate_b:>10.3g} {env_cpu:>10.3g} {env_mjx:>10.3g} "
                      f"{rate / env_cpu:>16.3g} {env_mjx / env_cpu:>15.3g}", flush=True)
        if args.departure:
            gaps = departure(model, spec)
            emit({"machine": name, "departure": gaps})
            print(f"{name}: max |s_mjx - s_cpu| after 100 / 1000 steps: float64 "
                  f"{gaps['float64_100']:.2g} / {gaps['float64_1000']:.2g}, float32 "
                  f"{gaps['float32_100']:.2g} / {gaps['float32_1000']:.2g}")
    print("steps/s of all envs together; mjx loop and batch: physics steps of the closed loop "
          "u = -K s; env: env steps of tspend's vector env (zero actions)")
    args.precisions = precisions
    if args.tspend_max:
        tspend_rows(plan, machines, sizes, args, bare, emit)
    if sink is not None:
        sink.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
