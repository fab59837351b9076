"""``tspend sweep --backend mjx``: a sweep's closed loops stepped together by MJX.

The jobs of one scenario (grid point) and controller kind are one batch: their seeds'
machines (:func:`tspend.mjx.machines.build_fleet`), the kind's JAX law
(:mod:`tspend.mjx.control`), sampled every ``control_every`` physics steps and held in
between as the CPU runner does, stepped in a ``jax.lax.scan`` over blocks of
:data:`BLOCK` physics steps under ``jax.vmap``.  Each block's samples (full state and u
per env and step) come back to the host, where the CPU's own code decides everything a
row says: the runner's end conditions (:meth:`tspend.loop.runner.ClosedLoop._diagnose`:
the state or u not finite, ``plant.state_bound``, ``run.control_bound``, the task's
bounds), its closing (``_finish``: ``not_reached``, the message) and the metrics
(:class:`tspend.loop.metrics.MetricsAccumulator`, fed the runner's blocks).  So a row has
the CPU sweep's columns, and the rows of the seeds both backends ran agree
(tests/test_mjx.py: same status, rmse and rmse_ss within 1e-6 relative).

What the CPU row has and this one does not: the controller's diagnostics (not computed
in JAX: no counters), a MuJoCo warning in the message, ``controller_ms`` (null, as in a
compiled CPU loop).  ``wall_s`` is the batch's wall time divided by its runs.  With
``--record failed`` (or ``all``) the recording is the CPU backend's run of that seed.
"""

from __future__ import annotations

import time
from types import SimpleNamespace
from typing import Any, Iterable, Iterator

import numpy as np

from tspend.runtime.errors import ScenarioError

__all__ = ["BLOCK", "MAX_BATCH", "closed_loop_rows", "run_jobs", "check_memory", "samples_batch"]

#: physics steps per scan call (the CPU runner's block size: the metrics fold the same blocks)
BLOCK = 1000
#: envs stepped in one batch at most (more seeds run as several batches)
MAX_BATCH = 1 << 17
#: bytes one block's samples of a batch may take (the device's output, its float64 copy
#: on the host, their slices): the batch is made smaller to fit (131,072 cart-poles would
#: take 16 GB a block)
SAMPLES_BUDGET_BYTES = 1 << 30


def samples_batch(n_full: int, batch: int = MAX_BATCH) -> int:
    """Envs per batch so one block's samples (full state and u, float64, three copies)
    stay within :data:`SAMPLES_BUDGET_BYTES`."""
    return max(1, min(batch, SAMPLES_BUDGET_BYTES // (BLOCK * (n_full + 1) * 8 * 3)))


def check_memory(scenario: Any, n_envs: int) -> None:
    """ScenarioError, before any work, when ``n_envs`` machines of ``scenario`` would not
    fit in the memory this process can have (:func:`available_bytes`): each env holds an
    MJX model (measured: about 2.2 x MuJoCo's model buffer on the cart-pole), the run's
    reference and disturbance tables are held whole, a batch's samples take at most
    :data:`SAMPLES_BUDGET_BYTES`."""
    from tspend.loop import simulation

    plant = simulation.build_plant(scenario)
    model = getattr(plant, "model", None)
    if model is None:
        return   # no MuJoCo model: the backend refuses it with its own line
    steps = simulation.steps_of(scenario)
    per_env = 3 * model.nbuffer + getattr(plant, "data").nbuffer + (64 << 10)
    tables = (steps + 1) * (plant.order + 2) * 8 * 4   # r .. r^(n), d, t; four copies
    need = n_envs * per_env + tables + SAMPLES_BUDGET_BYTES
    have = available_bytes()
    if need > have:
        gib = 2.0**30
        raise ScenarioError(
            f"{scenario.path or scenario.name}: --backend mjx: {n_envs} runs need about "
            f"{need / gib:.1f} GiB of memory ({per_env / 2**20:.1f} MiB per machine, "
            f"{tables / gib:.2f} GiB of tables for {steps} steps), more than the "
            f"{have / gib:.1f} GiB this process can have (free memory, ulimit -v); run "
            f"fewer seeds per sweep (several --seeds ranges into one --out) or a shorter "
            f"run.duration")


def available_bytes() -> float:
    """Memory this process can still take: the system's available memory, and what its
    address-space and data limits (``ulimit -v``, ``-d``) leave; inf where unknown."""
    import resource

    def field(path: str, name: str) -> float:
        try:
            with open(path) as f:
                for line in f:
                    if line.startswith(name + ":"):
                        return float(line.split()[1]) * 1024.0   # kB
        except OSError:
            pass
        return float("inf")

    have = field("/proc/meminfo", "MemAvailable")
    for limit, used in ((resource.RLIMIT_AS, "VmSize"), (resource.RLIMIT_DATA, "VmData")):
        soft = resource.getrlimit(limit)[0]
        if soft != resource.RLIM_INFINITY:
            taken = field("/proc/self/status", used)
            have = min(have, soft - (0.0 if taken == float("inf") else taken))
    return have


class _NoContacts:
    """The plant a run's closing asks what MuJoCo applied at the end: the batch keeps no
    CPU plant per env, so it reports nothing (the row's message has no "while MuJoCo
    applied ..." part)."""

    @staticmethod
    def constraint_active() -> str:
        return ""


def make_block_runner(fleet: Any, law: Any, every: int, block: int = BLOCK) -> Any:
    """A jitted ``run(model, data, u_held, params, d_to_tau, ref, dist, g0)`` that steps
    every env ``block`` physics steps from step ``g0``: the new data, the held u, and per
    env and step the full state before the step and the u applied over it."""
    import jax
    import jax.numpy as jnp
    from mujoco import mjx

    act, omega, nstep = fleet.actuator, fleet.omega, fleet.nstep
    dt = fleet.dt

    def one_env(model, data, u_held, params, d_to_tau, ref, dist, g0):
        def sample(carry, k):
            data, u_held, params = carry
            g = g0 + k
            full = jnp.concatenate((data.qpos, data.qvel))
            r = jax.lax.dynamic_index_in_dim(ref, k, keepdims=False)
            d = jax.lax.dynamic_index_in_dim(dist, k, keepdims=False)
            # sampled control: a new u every `every` steps, held in between (the runner's);
            # the law's carry (an adaptive controller's state) moves only when it samples
            due = g % every == 0
            u_new, adapted = law(params, g * dt, full, r, dt * every)
            u = jnp.where(due, u_new.astype(full.dtype), u_held)
            params = jax.tree_util.tree_map(lambda a, b: jnp.where(due, a, b), adapted, params)
            data = data.replace(ctrl=data.ctrl.at[act].set(u),
                                qfrc_applied=data.qfrc_applied.at[omega].set(d_to_tau * d))
            for _ in range(nstep):
                data = mjx.step(model, data)
            return (data, u, params), (full, u)

        (data, u_held, params), (full, u) = jax.lax.scan(sample, (data, u_held, params),
                                                         jnp.arange(block))
        return data, u_held, params, full, u

    batched = jax.vmap(one_env, in_axes=(fleet.in_axes, 0, 0, 0, 0, None, None, None))
    return jax.jit(batched)


def initial_data(fleet: Any, index: np.ndarray, dtype: Any) -> Any:
    """MJX data of the envs ``index``, at their CPU plants' reset states."""
    import jax
    import jax.numpy as jnp
    from mujoco import mjx

    model0 = jax.tree_util.tree_map(lambda x, a: x if a is None else x[0], fleet.model,
                                    fleet.in_axes, is_leaf=lambda x: x is None)
    data = mjx.make_data(model0)
    n = index.size

    def tile(x):
        return jnp.broadcast_to(x, (n,) + x.shape) if hasattr(x, "shape") else x

    data = jax.tree_util.tree_map(tile, data)
    data = data.replace(qpos=jnp.asarray(fleet.qpos0[index], dtype=dtype),
                        qvel=jnp.asarray(fleet.qvel0[index], dtype=dtype))
    # committed to the device, as a jitted step's outputs are: jit keys its cache on that,
    # so uncommitted inputs to the first call would compile the loop a second time
    return jax.device_put(data, jax.devices()[0])


def _subset(fleet: Any, index: np.ndarray, dtype: Any) -> Any:
    """The batched model of envs ``index`` in ``dtype``."""
    import jax
    import jax.numpy as jnp

    def pick(x, a):
        if a is None:
            x = jnp.asarray(x)
        else:
            x = jnp.asarray(np.asarray(x)[index])
        return x.astype(dtype) if jnp.issubdtype(x.dtype, jnp.floating) else x

    return jax.tree_util.tree_map(pick, fleet.model, fleet.in_axes, is_leaf=lambda x: x is None)


def closed_loop_rows(fleet: Any, controller: Any, precision: str = "float64",
                     batch: int = MAX_BATCH) -> Iterator[tuple[int, str, str, dict]]:
    """``(env, status, message, metrics)`` of each env's closed loop under ``controller``
    (the CPU controller built on the nominal scenario), as the CPU run ends and measures
    it; batches of at most ``batch`` envs."""
    import jax
    import jax.numpy as jnp

    from tspend.loop.metrics import MetricsAccumulator
    from tspend.loop.runner import BlockBuffer, ClosedLoop, LoopSettings
    from tspend.loop.simulation import control_every
    from tspend.loop.sinks import Block
    from tspend.mjx import set_precision
    from tspend.mjx.control import jax_law, seeded_carries

    set_precision(precision)
    dtype = jnp.float64 if precision == "float64" else jnp.float32
    scn = fleet.scenario
    law, _, _ = jax_law(scn, controller, fleet.view_index, dtype)
    every = control_every(scn.run, controller)
    batch = samples_batch(len(fleet.names), batch)   # a block's samples within a budget
    steps, dt, n = fleet.steps, fleet.dt, fleet.order
    settings = LoopSettings(dt=dt, steps=steps, block_size=BLOCK,
                            state_bound=scn.plant.state_bound,
                            control_bound=scn.run.control_bound, control_every=every)
    bounded = settings.state_bound > 0.0 or settings.control_bound > 0.0
    blocks = -(-steps // BLOCK)
    ref = np.zeros((blocks * BLOCK + 1, n + 1))
    ref[:steps + 1] = fleet.ref
    dist = np.zeros(blocks * BLOCK)
    dist[:steps] = fleet.dist
    runner = make_block_runner(fleet, law, every)
    view = fleet.view_index
    wraps = fleet.wraps
    for first in range(0, fleet.n_envs, batch):
        index = np.arange(first, min(first + batch, fleet.n_envs))
        started = time.perf_counter()
        model = _subset(fleet, index, dtype)
        data = initial_data(fleet, index, dtype)
        u_held = jax.device_put(jnp.zeros(index.size, dtype=dtype), jax.devices()[0])
        # every env's law starts from the state its CPU run's controller is reset to
        params = jax.device_put(seeded_carries(controller, [fleet.seeds[e] for e in index],
                                               dtype), jax.devices()[0])
        d_to_tau = jnp.asarray(fleet.d_to_tau[index], dtype=dtype)
        accs, ends = [], {}
        for e in index:
            acc = MetricsAccumulator(dt, ss_start=0.5 * steps * dt, seed=fleet.seeds[e],
                                     machine=fleet.machines[e])
            acc.start(SimpleNamespace(diagnostics=()))
            accs.append(acc)
        buf = BlockBuffer(BLOCK, n, 0, (), (), len(fleet.names), wraps)
        alive = np.ones(index.size, dtype=bool)
        for b in range(blocks):
            if not alive.any():
                break
            g0 = b * BLOCK
            data, u_held, params, full, u = runner(model, data, u_held, params, d_to_tau,
                                           jnp.asarray(ref[g0:g0 + BLOCK], dtype=dtype),
                                           jnp.asarray(dist[g0:g0 + BLOCK], dtype=dtype), g0)
            full = np.asarray(full, dtype=float)
            u = np.asarray(u, dtype=float)
            k = min(BLOCK, steps - g0)
            t = (g0 + np.arange(k)) * dt
            r = ref[g0:g0 + k]
            d = dist[g0:g0 + k]
            lo, hi = fleet.lo[index][:, None, :], fleet.hi[index][:, None, :]
            with np.errstate(invalid="ignore"):
                bad = ~np.isfinite(u[:, :k]) | (full[:, :k] < lo).any(-1) | (full[:, :k] > hi).any(-1)
                if bounded:
                    x = full[:, :k][..., view]
                    if settings.state_bound > 0.0:
                        bad |= np.abs(x).max(-1) > settings.state_bound
                    if settings.control_bound > 0.0:
                        bad |= np.abs(u[:, :k]) > settings.control_bound
            for j in np.flatnonzero(alive):
                e = int(index[j])
                stop = int(np.argmax(bad[j])) if bad[j].any() else k
                kept = stop
                if stop < k:
                    x_s = full[j, stop][view]
                    own = SimpleNamespace(s=settings, task=fleet.tasks[e])
                    problem, more, status = ClosedLoop._diagnose(own, x_s, float(u[j, stop]),
                                                                 float(t[stop]), full[j, stop])
                    kept = stop + more
                    ends[j] = (status, problem, g0 + kept)
                    alive[j] = False
                if kept > 0:
                    buf.full[:kept] = full[j, :kept]
                    buf.x[:kept] = full[j, :kept][:, view]
                    buf.u[:kept] = u[j, :kept]
                    accs[j].block(Block(start=g0, data=buf.view(kept, t, r, d)))
        share = (time.perf_counter() - started) / index.size
        for j, e in enumerate(index):
            status, message, done = ends.get(j, ("completed", "", steps))
            own = SimpleNamespace(controller=controller, plant=_NoContacts(), end=None)
            end = ClosedLoop._finish(own, [accs[j]], status, message, done,
                                     time.perf_counter() - share)
            yield int(e), end.status, end.message, end.metrics


def run_jobs(jobs: Iterable[Any], precision: str = "float64",
             batch: int = MAX_BATCH) -> Iterator[tuple[Any, str, str, dict[str, Any], float]]:
    """How each of a sweep's ``jobs`` (:class:`tspend.sweep.plan.Job`) ended, each scenario
    point and controller kind one batch of its seeds: ``(job, status, message, metrics,
    job_s)``, its share of the time in ``job_s``.  The sweep makes the row and any
    recording of it (:func:`tspend.sweep.worker.finished_row`): this backend knows nothing
    of the sweep's table."""
    from tspend.loop.simulation import prepare
    from tspend.mjx.machines import build_fleet

    groups: dict[tuple[int, Any], list] = {}
    for job in jobs:
        groups.setdefault((id(job.scenario), job.run_kind), []).append(job)
    for (_, kind), group in groups.items():
        started = time.perf_counter()
        scenario = group[0].scenario
        fleet = build_fleet(scenario, [job.seed for job in group])
        controller = prepare(fleet.scenario, controller=kind).controller
        built = (time.perf_counter() - started) / len(group)
        for e, status, message, metrics in closed_loop_rows(fleet, controller, precision, batch):
            yield group[e], status, message, metrics, built + float(metrics.get("wall_s") or 0.0)


def check_batch(batch: Any) -> int:
    if isinstance(batch, bool) or not isinstance(batch, int) or not 1 <= batch <= MAX_BATCH:
        raise ScenarioError(f"--batch: an integer from 1 to {MAX_BATCH}, got {batch!r}")
    return batch

