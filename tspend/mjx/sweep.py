"""``tspend sweep --backend mjx``: a sweep's closed loops stepped together by MJX.

The jobs of one scenario (grid point) and controller kind are one batch: their seeds'
machines (:func:`tspend.mjx.machines.build_fleet`), the kind's JAX law
(:mod:`tspend.mjx.control`), sampled every ``control_every`` physics steps and held in
between as the CPU runner does.  The whole run of a batch is one jitted program
(:func:`make_run`, a ``jax.lax.scan`` over the run's samples under ``jax.vmap``): each
env's ending is decided on the device and frozen at its sample, by the CPU loop's own
text (:mod:`tspend.loop.endings`, built for JAX: u not finite or beyond
``run.control_bound``, the view beyond ``plant.state_bound``, the full state outside the
task's bounds; an input MuJoCo would refuse) and MuJoCo's own instability check (NaN or
beyond 1e10 in qpos, qvel, qacc: :func:`mujoco_steps`),
and every figure of its row is folded on the device by the CPU's own text
(:func:`tspend.loop.metrics.fold_samples`, the error by
:func:`tspend.loop.runner.output_error`).  The host receives one small record per env
(the figures, the ending's code, sample, state and u) and builds the rows with the CPU's
code: the message (:meth:`tspend.loop.runner.ClosedLoop._diagnose`), the closing
(``_finish``: ``not_reached``) and the metrics
(:meth:`tspend.loop.metrics.MetricsAccumulator.result`).  So a row has the CPU sweep's
columns, and the rows of the seeds both backends ran agree (tests/test_mjx.py: same
status, metrics within 1e-9 relative, on runs that complete, fall, reach the rail's end
and go non-finite).

What the CPU row has and this one does not: the controller's diagnostics (not computed
in JAX: no counters), a MuJoCo warning in the message, ``controller_ms`` (null, as in a
compiled CPU loop).  ``wall_s`` is the batch's wall time divided by its runs.  With
``--record failed`` (or ``all``) the recording is the CPU backend's run of that seed.
"""

from __future__ import annotations

import dataclasses
import time
from types import SimpleNamespace
from typing import Any, Iterable, Iterator

import numpy as np

from tspend.runtime.errors import ScenarioError

__all__ = ["CHUNK", "MAX_BATCH", "batch_inputs", "check_memory", "closed_loop_rows", "make_run",
           "memory_need", "mujoco_steps", "plant_error", "prepare_program", "run_batch", "run_jobs"]

#: samples folded into the figures at once on the device (memory: CHUNK full states per env)
CHUNK = 100
#: envs stepped in one batch at most (more seeds run as several batches)
MAX_BATCH = 1 << 17
#: how a run ended on the device: it did not; the sample's check (the runner's
#: _diagnose says why); an input MuJoCo refuses; MuJoCo's instability check
ALIVE, CHECK, BAD_INPUT, UNSTABLE = 0, 1, 2, 3


def memory_need(scenario: Any, n_envs: int) -> tuple[float, float, float, int] | None:
    """``(need, per_env, tables, steps)``: the bytes that ``n_envs`` machines of ``scenario`` take on
    the device (None: no MuJoCo model).  Per env: its MJX model and data three times (the
    step's inputs, outputs and intermediates; :func:`_mjx_bytes`), the :data:`CHUNK`
    samples it folds at once (full state, u, keep) and its figures; the samples never
    leave the device, so
    nothing grows with the run's length but the reference and disturbance tables, held
    whole (padded to whole chunks)."""
    from tspend.loop import simulation

    plant = simulation.build_plant(scenario)
    model = getattr(plant, "model", None)
    if model is None:
        return None   # no MuJoCo model: the backend refuses it with its own line
    steps = simulation.steps_of(scenario)
    n_full = int(model.nq + model.nv)
    samples = CHUNK * (n_full + 2) * 8 * 2          # a chunk's samples, and the fold's copy
    per_env = 3 * _mjx_bytes(model) + samples + (64 << 10)
    tables = (steps + CHUNK) * (plant.order + 2) * 8 * 4   # r .. r^(n), d, t; four copies
    return n_envs * per_env + tables, per_env, tables, steps


def _mjx_bytes(model: Any) -> int:
    """The bytes of ``model`` in MJX and of its data, as if every field were the env's own
    (an upper bound: fields equal across envs are held once).  Not MuJoCo's ``nbuffer``:
    that counts what MJX does not hold (a model's textures and meshes for drawing, the
    data's arena), 800 kB against MJX's 3 kB for the randomised cart-pole."""
    import jax
    from mujoco import mjx

    on_cpu = mjx.put_model(model, device=jax.devices("cpu")[0])
    trees = (on_cpu, mjx.make_data(on_cpu))
    return int(sum(getattr(leaf, "nbytes", 0) for tree in trees
                   for leaf in jax.tree_util.tree_leaves(tree)))


def check_memory(scenario: Any, n_envs: int) -> None:
    """ScenarioError, before any work, when ``n_envs`` machines of ``scenario`` would not
    fit in the memory this process can have (:func:`available_bytes`; the estimate:
    :func:`memory_need`)."""
    need = memory_need(scenario, n_envs)
    if need is None:
        return
    need, per_env, tables, steps = need
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


def _is_bad(jnp: Any, v: Any, max_value: float) -> Any:
    """MuJoCo's mju_isBad over a vector: any entry NaN or beyond +-max_value."""
    return jnp.any(~(jnp.abs(v) <= max_value))


def _integrator(mjx: Any, model: Any) -> Any:
    """The integration ``mjx.step`` runs after its forward, by the model's integrator."""
    import mujoco

    by_kind = {int(mujoco.mjtIntegrator.mjINT_EULER): mjx.euler,
               int(mujoco.mjtIntegrator.mjINT_RK4): mjx.rungekutta4,
               int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST): mjx.implicit}
    kind = int(model.opt.integrator)
    if kind not in by_kind:
        raise ScenarioError(f"the mjx backend: MuJoCo integrator {kind} is not in MJX")
    return by_kind[kind]


def mujoco_steps(mjx: Any, model: Any, data: Any, nstep: int, max_value: float) -> Any:
    """``(data, unstable)``: ``nstep`` of MuJoCo's ``mj_step`` in MJX with mj_step's own
    instability check (qpos, qvel before each step, qacc after its forward: NaN or beyond
    ``max_value``), which ``mjx.step`` does not make; an unstable run is not reset here, the
    caller ends it.  mjx.step's parts, since its data's qacc is RK4's last stage, not the
    checked one."""
    import jax.numpy as jnp

    integrate = _integrator(mjx, model)
    unstable = jnp.zeros((), dtype=bool)
    for _ in range(nstep):
        unstable |= _is_bad(jnp, data.qpos, max_value) | _is_bad(jnp, data.qvel, max_value)
        data = mjx.forward(model, data)
        unstable |= _is_bad(jnp, data.qacc, max_value)
        data = integrate(model, data)
    return data, unstable


def make_run(fleet: Any, law: Any, every: int, bounds: Any, fold: Any, dtype: Any,
             chunk: int = CHUNK) -> Any:
    """A jitted ``run(model, data, carry, d_to_tau, lo, hi, u_lo, u_hi, ref, dist)``: every
    env's whole closed loop of ``fleet.steps`` samples, ``law`` its controller
    (:func:`tspend.mjx.control.jax_law`) and ``carry`` each env's start of the law's carry
    (:func:`tspend.mjx.control.seeded_carries`); per env its figures
    (:func:`tspend.loop.metrics.fold_samples` under ``fold``, whose ``u_lo``/``u_hi``
    are the env's), the ending's code, sample ``g``, full state, u and d."""
    import jax
    import jax.numpy as jnp

    from tspend.loop.metrics import fold_samples, start_figures
    from tspend.loop.runner import output_error

    view, n, dt = np.asarray(fleet.view_index), fleet.order, fleet.dt
    wraps = fleet.wraps if fleet.wraps.any() else None
    chunks = -(-fleet.steps // chunk)
    sample_of = _sample_step(fleet, law, every, bounds, dtype)

    def one_env(model, data, params, d_to_tau, lo, hi, u_lo, u_hi, ref, dist):
        settings = dataclasses.replace(fold, u_lo=u_lo, u_hi=u_hi)
        sample = sample_of(model, (data.qpos, data.qvel), d_to_tau, lo, hi, ref, dist)

        def fold_chunk(carry, c):
            loop, figures = carry
            g = c * chunk + jnp.arange(chunk)
            loop, (full, u, keep) = jax.lax.scan(sample, loop, g)
            e1 = output_error(jnp, full[:, view], ref[g, :n], wraps)[:, 0]
            figures = fold_samples(jnp, figures, g * jnp.asarray(dt, dtype), e1, u, full, keep,
                                   settings)
            return (loop, figures), None

        full0 = jnp.concatenate((data.qpos, data.qvel))
        zero = jnp.zeros((), dtype)
        end = (jnp.asarray(ALIVE), jnp.asarray(0), full0 * 0, zero, zero)
        loop = (data, zero, params, jnp.asarray(True), end)
        (loop, figures), _ = jax.lax.scan(fold_chunk, (loop, start_figures(jnp, fold, dtype)),
                                          jnp.arange(chunks))
        return figures, loop[4]

    axes = (fleet.in_axes, 0, 0, 0, 0, 0, 0, 0, None, None)
    return jax.jit(jax.vmap(one_env, in_axes=axes))


def _sample_step(fleet: Any, law: Any, every: int, bounds: Any, dtype: Any) -> Any:
    """``sample_of(model, start, d_to_tau, lo, hi, ref, dist)``: one env's sample as a scan
    step ``(data, u_held, params, alive, end), g -> carry, (full, u, keep)``: the law
    (sampled every ``every`` steps, held in between), the ending's checks
    (:mod:`tspend.loop.endings`, the CPU loop's text), MuJoCo's steps and the record of
    the first ending; ``start`` the env's (qpos, qvel) at x0."""
    import jax
    import jax.numpy as jnp
    from mujoco import mjx

    from tspend.loop.endings import jax_checks

    act, omega, nstep, steps = fleet.actuator, fleet.omega, fleet.nstep, fleet.steps
    view, dt, max_value = np.asarray(fleet.view_index), fleet.dt, fleet.max_input
    checks = jax_checks()

    def sample_of(model, start, d_to_tau, lo, hi, ref, dist):
        def sample(carry, g):
            data, u_held, params, alive, end = carry
            full = jnp.concatenate((data.qpos, data.qvel))
            x, r, d = full[view], ref[g], dist[g]
            # sampled control: a new u every `every` steps, held in between (the runner's);
            # the law's carry (an adaptive controller's state) moves only when it samples
            due = g % every == 0
            u_new, adapted = law(params, g * dt, full, r, dt * every)
            u = jnp.where(due, u_new.astype(dtype), u_held)
            params = jax.tree_util.tree_map(lambda a, b: jnp.where(due, a, b), adapted, params)
            check = checks.sample_ends(x, u, full, lo, hi, bounds.state_bound,
                                       bounds.control_bound)
            refused = checks.refuses_input(u, d, max_value)
            data = data.replace(ctrl=data.ctrl.at[act].set(u),
                                qfrc_applied=data.qfrc_applied.at[omega].set(d_to_tau * d))
            data, unstable = mujoco_steps(mjx, model, data, nstep, max_value)
            code = jnp.where(check, CHECK, jnp.where(refused, BAD_INPUT,
                                                     jnp.where(unstable, UNSTABLE, ALIVE)))
            ends = alive & (g < steps) & (code != ALIVE)
            # the runner keeps the sample that ends the run unless it is not finite
            keep = alive & (g < steps) & (~ends | (code != CHECK) |
                                          (checks.all_finite(x) & jnp.isfinite(u)))
            end = jax.tree_util.tree_map(lambda new, old: jnp.where(ends, new, old),
                                         (code, g, full, u, d), end)
            alive = alive & ~ends
            # an ended run restarts from x0 (masked): its NaN would hold the batch's solver
            # at its iteration limit
            data = data.replace(qpos=jnp.where(alive, data.qpos, start[0]),
                                qvel=jnp.where(alive, data.qvel, start[1]))
            return (data, u, params, alive, end), (full, u, keep)

        return sample

    return sample_of


def initial_data(fleet: Any, index: np.ndarray, dtype: Any) -> Any:
    """MJX data of the envs ``index``, at their CPU plants' reset states, on the device."""
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


def _padded_tables(fleet: Any, chunk: int) -> tuple[np.ndarray, np.ndarray]:
    """The reference and disturbance tables padded to whole chunks (the samples past the
    run's end are not kept)."""
    steps, n = fleet.steps, fleet.order
    size = -(-steps // chunk) * chunk
    ref = np.zeros((size, n + 1))
    ref[:steps] = fleet.ref[:steps]
    dist = np.zeros(size)
    dist[:steps] = fleet.dist
    return ref, dist


def run_batch(run: Any, inputs: tuple) -> Any:
    """One batch's whole run: the inputs already on the device, no transfer between host
    and device inside it (``jax.transfer_guard("disallow")``); the host receives the
    records (one per env) only when it asks for them."""
    import jax

    with jax.transfer_guard("disallow"):
        out = run(*inputs)
        jax.block_until_ready(out)
    return out


def batch_inputs(fleet: Any, index: np.ndarray, program: Any) -> tuple:
    """The device arrays of envs ``index`` that ``program``'s run takes
    (:func:`prepare_program`)."""
    import jax
    import jax.numpy as jnp

    from tspend.mjx.control import seeded_carries

    dtype = program.dtype
    ref, dist = _padded_tables(fleet, program.chunk)
    dev = jax.devices()[0]

    def put(a):
        return jax.device_put(jnp.asarray(a, dtype=dtype), dev)

    # every env's law starts from the state its CPU run's controller is reset to
    carries = seeded_carries(program.controller, [fleet.seeds[e] for e in index], dtype)
    return (jax.device_put(_subset(fleet, index, dtype), dev), initial_data(fleet, index, dtype),
            jax.device_put(carries, dev), put(fleet.d_to_tau[index]),
            put(fleet.lo[index]), put(fleet.hi[index]), put(fleet.u_lo[index]),
            put(fleet.u_hi[index]), put(ref), put(dist))


def prepare_program(fleet: Any, controller: Any, precision: str = "float64") -> Any:
    """The jitted program of ``fleet``'s closed loops under ``controller`` (:func:`make_run`)
    and what reading its records needs: ``run``, ``controller`` (whose resets give each
    env's carry: :func:`batch_inputs`), ``settings`` (the runner's :class:`~tspend.loop.runner.LoopSettings`), ``ss_start``,
    ``chunk``, ``dtype``."""
    import jax.numpy as jnp

    from tspend.loop.metrics import FoldSettings
    from tspend.loop.runner import LoopSettings
    from tspend.loop.simulation import control_every
    from tspend.mjx import set_precision
    from tspend.mjx.control import jax_law

    set_precision(precision)
    dtype = jnp.float64 if precision == "float64" else jnp.float32
    scn = fleet.scenario
    law, _, _ = jax_law(scn, controller, fleet.view_index, dtype)
    every = control_every(scn.run, controller)
    steps, dt = fleet.steps, fleet.dt
    settings = LoopSettings(dt=dt, steps=steps, block_size=steps,
                            state_bound=scn.plant.state_bound,
                            control_bound=scn.run.control_bound, control_every=every)
    ss_start = 0.5 * steps * dt
    fold = FoldSettings.of(dt, ss_start, fleet.machines[0])
    chunk = min(CHUNK, steps)
    run = make_run(fleet, law, every, settings, fold, dtype, chunk)
    return SimpleNamespace(run=run, controller=controller, settings=settings, ss_start=ss_start,
                           chunk=chunk, dtype=dtype)


def _ending(fleet: Any, e: int, settings: Any, code: int, g: int, full: np.ndarray, u: float,
            d: float) -> tuple[str, str, int]:
    """``(status, message, samples done)`` of env ``e``'s run that ended at sample ``g``,
    by the CPU runner's own words."""
    from tspend.loop.runner import ClosedLoop

    t = g * fleet.dt
    if code == CHECK:
        own = SimpleNamespace(s=settings, task=fleet.tasks[e])
        problem, more, status = ClosedLoop._diagnose(own, full[fleet.view_index], u, t, full)
        return status, problem, g + more
    error = plant_error(fleet, code == BAD_INPUT, u, d, t)
    return "diverged", f"diverged at t = {t:.4f} s: the plant failed ({error})", g + 1


def plant_error(fleet: Any, refused: bool, u: float, d: float, t: float) -> Exception:
    """The error the CPU plant raises at time ``t`` for an input MuJoCo refuses
    (``refused``) or a step MuJoCo found unstable: the words of a run's or an env's
    "the plant failed" on both backends."""
    from tspend.plants.mujoco_plant import instability_error, refuse_huge_input

    if refused:
        try:
            refuse_huge_input(fleet.plant.name, u, d, t)
        except Exception as exc:   # the DivergenceError the CPU plant raises
            return exc
    flagged = [SimpleNamespace(number=1)] * 3
    return instability_error(fleet.plant.name, flagged, t)


def closed_loop_rows(fleet: Any, controller: Any, precision: str = "float64",
                     batch: int = MAX_BATCH) -> Iterator[tuple[int, str, str, dict]]:
    """``(env, status, message, metrics)`` of each env's closed loop under ``controller``
    (the CPU controller built on the nominal scenario), as the CPU run ends and measures
    it; batches of at most ``batch`` envs, each one program on the device."""
    import jax

    from tspend.loop.metrics import MetricsAccumulator
    from tspend.loop.runner import ClosedLoop

    program = prepare_program(fleet, controller, precision)
    steps, dt = fleet.steps, fleet.dt
    for first in range(0, fleet.n_envs, batch):
        index = np.arange(first, min(first + batch, fleet.n_envs))
        started = time.perf_counter()
        figures, end = jax.device_get(run_batch(program.run, batch_inputs(fleet, index, program)))
        figures = {k: np.asarray(v, dtype=float if np.asarray(v).dtype.kind == "f" else None)
                   for k, v in figures.items()}
        code, g, full, u, d = (np.asarray(a) for a in end)
        share = (time.perf_counter() - started) / index.size
        for j, e in enumerate(index):
            e = int(e)
            status, message, done = "completed", "", steps
            if code[j] != ALIVE:
                status, message, done = _ending(fleet, e, program.settings, int(code[j]),
                                                int(g[j]), full[j].astype(float), float(u[j]),
                                                float(d[j]))
            acc = MetricsAccumulator(dt, program.ss_start, seed=fleet.seeds[e],
                                     machine=fleet.machines[e])
            acc.figures = {k: v[j] for k, v in figures.items()}
            own = SimpleNamespace(controller=controller, plant=_NoContacts(), end=None)
            end_e = ClosedLoop._finish(own, [acc], status, message, done,
                                       time.perf_counter() - share)
            yield e, end_e.status, end_e.message, end_e.metrics


def run_jobs(jobs: Iterable[Any], precision: str = "float64", batch: int = MAX_BATCH,
             report: Any = None) -> Iterator[tuple[Any, str, str, dict[str, Any], float]]:
    """How each of a sweep's ``jobs`` (:class:`tspend.sweep.plan.Job`) ended, each scenario
    point and controller kind one batch of its seeds: ``(job, status, message, metrics,
    job_s)``, its share of the time in ``job_s``.  The sweep makes the row and any
    recording of it (:func:`tspend.sweep.worker.finished_row`): this backend knows nothing
    of the sweep's table.  ``report(line)``, when given, hears how long the machines took
    to build."""
    from tspend.loop.simulation import prepare
    from tspend.mjx.machines import build_fleet

    groups: dict[tuple[int, Any], list] = {}
    for job in jobs:
        groups.setdefault((id(job.scenario), job.run_kind), []).append(job)
    for (_, kind), group in groups.items():
        started = time.perf_counter()
        scenario = group[0].scenario
        fleet = build_fleet(scenario, [job.seed for job in group])
        built_s = time.perf_counter() - started
        if report is not None:
            report(f"mjx: built the machines of {len(group)} seeds of "
                   f"{scenario.name} in {built_s:.1f} s")
        controller = prepare(fleet.scenario, controller=kind).controller
        built = (time.perf_counter() - started) / len(group)
        for e, status, message, metrics in closed_loop_rows(fleet, controller, precision, batch):
            yield group[e], status, message, metrics, built + float(metrics.get("wall_s") or 0.0)


def check_batch(batch: Any) -> int:
    if isinstance(batch, bool) or not isinstance(batch, int) or not 1 <= batch <= MAX_BATCH:
        raise ScenarioError(f"--batch: an integer from 1 to {MAX_BATCH}, got {batch!r}")
    return batch

