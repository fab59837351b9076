"""The machines of a scenario at N seeds, batched for MJX (tspend.mjx's docstring).

Env ``i`` is the machine the CPU backend runs at seed ``seeds[i]``: the scenario with
``run.seed = seeds[i]`` goes through :func:`tspend.loop.simulation.build_plant` (its
``[randomize]`` drawn by :mod:`tspend.plants.randomize`, the MJCF edited and compiled by
the CPU plant, reset to x0), and that plant's own ``mjModel`` is put into MJX.  Fields
equal across the envs stay single (``in_axes`` None), the others are stacked on a leading
env axis, so ``jax.vmap(f, in_axes=(fleet.in_axes, 0))`` steps each env on its own machine.

Where the draw's keys have an array form, only the first seed is built so: the others are
its compiled model with their draw written into its fields (:mod:`tspend.mjx.drawn`), so
10^5 machines cost seconds, not the hours of a CPU build each (docs/accelerator.md).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from tspend.runtime.errors import ScenarioError

__all__ = ["Fleet", "build_fleet", "refusal"]


def refusal(scenario: Any) -> str:
    """Why the MJX backend cannot run ``scenario`` (one line), or ""."""
    from tspend.loop.effects import needs_hook, needs_plant_wrapper
    from tspend.plants.registry import PLANT_KINDS

    where = scenario.path or scenario.name
    kind = scenario.plant.kind
    if not PLANT_KINDS[kind].mujoco:
        return (f"{where}: plant kind {kind} is not a MuJoCo machine: the mjx backend runs the "
                f"machines read from their MJCF (*_mujoco scenarios)")
    if needs_hook(scenario.effects) or needs_plant_wrapper(scenario.effects):
        return (f"{where}: [effects] that act per sample in Python (sensor noise, delay, outer "
                f"loop, saturation, rate limit, a scheduled change) are not in the mjx backend; "
                f"run it on the CPU backend")
    if scenario.run.control_delay:
        return (f"{where}: run.control_delay = {scenario.run.control_delay} is not in the mjx "
                f"backend; run it on the CPU backend")
    return ""


@dataclass
class Fleet:
    """N machines of one scenario, as the MJX loops need them (module docstring)."""

    #: the scenario at the first seed, controller.gain_sign resolved (what the CPU designs on)
    scenario: Any
    seeds: tuple[int, ...]
    #: the batched mjx.Model and its vmap axes (0: per env, None: shared)
    model: Any
    in_axes: Any
    #: each env's state after the CPU plant's reset to its x0
    qpos0: np.ndarray
    qvel0: np.ndarray
    #: the actuator's index in ctrl, the dof the disturbance pushes and its gain per env
    actuator: int
    omega: int
    d_to_tau: np.ndarray
    #: MuJoCo steps per physics step of run.dt
    nstep: int
    #: what MuJoCo takes as a huge value (its mjMAXVAL): beyond it an input is refused and
    #: a state unstable (:mod:`tspend.plants.mujoco_plant`)
    max_input: float
    dt: float
    steps: int
    #: the task: full-state names, the view's indices, which view entries are angles,
    #: the bounds lo < s < hi per env (N, nfull)
    names: tuple[str, ...]
    view_index: np.ndarray
    wraps: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    #: r .. r^(n) at physics steps 0 .. steps (steps + 1, n + 1) and d at steps 0 .. steps - 1
    ref: np.ndarray
    dist: np.ndarray
    #: per env: the task (for its messages), what the metrics know of the machine, the
    #: CPU plant's input range
    tasks: list
    machines: list
    u_lo: np.ndarray
    u_hi: np.ndarray
    #: the first env's CPU plant (joints, names, render), the scenario's task on it
    plant: Any

    @property
    def n_envs(self) -> int:
        return len(self.seeds)

    @property
    def order(self) -> int:
        return int(self.view_index.size)


def _seeded(scenario: Any, seed: int) -> Any:
    from tspend.scenario import override

    return scenario if seed == scenario.run.seed else override(scenario, **{"run.seed": int(seed)})


def _tables(scenario: Any, steps: int, order: int) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(steps + 1) * scenario.run.dt
    ref = np.ascontiguousarray(scenario.reference.derivatives(t, order), dtype=float)
    dist = np.ascontiguousarray(scenario.disturbance(t[:-1]), dtype=float)
    return ref, dist


def build_fleet(scenario: Any, seeds: Sequence[int], *, steps: int | None = None) -> Fleet:
    """The machines of ``scenario`` at ``seeds`` (module docstring); ``steps`` physics
    steps of tables (default: the run's).  ScenarioError for what the backend cannot run.

    One CPU build (the first seed's) and the ``[randomize]`` draw as arrays written into
    its model's fields per env (:mod:`tspend.mjx.drawn`) where the draw's keys have that form;
    else each seed's CPU build (:func:`build_fleet_per_seed`)."""
    from tspend.mjx.drawn import array_form, drawn_fleet

    seeds = tuple(int(s) for s in seeds)
    if len(seeds) < 2 or not array_form(scenario):
        return build_fleet_per_seed(scenario, seeds, steps=steps)
    first = build_fleet_per_seed(scenario, seeds[:1], steps=steps)
    # the reference and disturbance may depend on the seed: one table serves all only
    # where the last seed's is the first's (else the per-seed build says where they differ)
    ref, dist = _tables(_seeded(scenario, seeds[-1]), first.steps, first.order)
    if not (np.array_equal(ref, first.ref) and np.array_equal(dist, first.dist)):
        return build_fleet_per_seed(scenario, seeds, steps=steps)
    return drawn_fleet(scenario, seeds, first)


def build_fleet_per_seed(scenario: Any, seeds: Sequence[int], *,
                         steps: int | None = None) -> Fleet:
    """:func:`build_fleet` by the CPU backend's build of every seed (the reference the
    array form is tested against, and the form of draws it does not know)."""
    from tspend.loop import simulation
    from tspend.mjx import set_precision

    # the models go into MJX in float64 whatever the run's precision (a float32 run casts
    # them later): put_model under JAX's default float32 would round them here
    set_precision("float64")
    seeds = tuple(int(s) for s in seeds)
    if not seeds:
        raise ScenarioError("the mjx backend: no seeds to run")
    why = refusal(scenario)
    if why:
        raise ScenarioError(why)
    steps = simulation.steps_of(scenario) if steps is None else int(steps)
    built: list[Any] = []
    for seed in seeds:
        built.append(_seed_build(scenario, seed, steps, built[0] if built else None, seeds[0]))
    b0 = built[0]
    model, in_axes = _batched([b.model for b in built])
    hinges = {j.name for j in b0.plant.joints if j.kind == "hinge"}
    link0, task0 = b0.link, b0.task
    return Fleet(
        scenario=simulation.with_gain_sign(b0.scn, b0.plant), seeds=seeds, model=model,
        in_axes=in_axes, qpos0=np.stack([b.qpos for b in built]),
        qvel0=np.stack([b.qvel for b in built]), actuator=int(link0.actuator),
        omega=int(link0.omega), d_to_tau=np.array([float(b.link.d_to_tau) for b in built]),
        nstep=int(link0.nstep), max_input=float(link0.max_input), dt=float(b0.scn.run.dt),
        steps=steps, names=tuple(task0.names),
        view_index=np.asarray(task0.view_index, dtype=np.int64),
        wraps=np.array([v in hinges for v in task0.view], dtype=bool),
        lo=np.stack([b.task.lo for b in built]), hi=np.stack([b.task.hi for b in built]),
        ref=b0.ref, dist=b0.dist, tasks=[b.task for b in built],
        machines=[b.machine for b in built], u_lo=np.array([b.u_range[0] for b in built]),
        u_hi=np.array([b.u_range[1] for b in built]), plant=b0.plant)


def _seed_build(scenario: Any, seed: int, steps: int, first: Any, first_seed: int) -> Any:
    """The CPU backend's build of ``seed``'s machine, its task, tables, start state and
    MJX model; ScenarioError where it cannot share a batch with ``first`` (the first
    seed's build, None for the first)."""
    from types import SimpleNamespace

    import jax
    from mujoco import mjx

    from tspend.loop import simulation
    from tspend.plants import randomize
    from tspend.task.feasibility import check_task

    scn = _seeded(scenario, seed)
    with warnings.catch_warnings():
        if first is not None:   # the model's departures were warned about once
            warnings.simplefilter("ignore")
        plant = simulation.build_plant(scn)
    link = plant.compiled_mujoco(scn.run.dt) if hasattr(plant, "compiled_mujoco") else None
    if link is None:
        raise ScenarioError(f"{scn.path or scn.name}: plant {plant.name} offers no MuJoCo "
                            f"model to step (the mjx backend needs one)")
    task = simulation.scenario_task(scn, plant)
    ref, dist = _tables(scn, steps, len(task.view))
    if first is None:
        check_task(plant, task, scn)
    elif (link.actuator, link.omega, link.nstep) != (first.link.actuator, first.link.omega,
                                                     first.link.nstep):
        raise ScenarioError(f"{scn.path or scn.name}: seed {seed} draws a machine of "
                            f"another layout (actuator, disturbed dof, substeps) than "
                            f"seed {first_seed}: one batch cannot hold both")
    elif not (np.array_equal(ref, first.ref) and np.array_equal(dist, first.dist)):
        raise ScenarioError(f"{scn.path or scn.name}: the reference or disturbance "
                            f"differs between seeds; the mjx backend shares one table")
    drawn = randomize.draw(scn).values
    return SimpleNamespace(
        scn=scn, plant=plant, link=link, task=task, ref=ref, dist=dist,
        machine=simulation.machine_info(plant, task, scn, drawn),
        u_range=simulation.input_range(plant, scn),
        qpos=np.array(plant.data.qpos, dtype=float), qvel=np.array(plant.data.qvel, dtype=float),
        model=mjx.put_model(plant.model, device=jax.devices("cpu")[0]))


def _batched(models: list) -> tuple[Any, Any]:
    """One mjx.Model whose leaves that differ between ``models`` are stacked (axis 0), and
    the matching tree of vmap axes."""
    import jax

    leaves0, tree = jax.tree_util.tree_flatten(models[0])
    others = [jax.tree_util.tree_flatten(m)[0] for m in models[1:]]
    out, axes = [], []
    for k, leaf in enumerate(leaves0):
        column = [leaf] + [o[k] for o in others]
        arrays = [np.asarray(v) for v in column]
        same = all(a.shape == arrays[0].shape and np.array_equal(a, arrays[0], equal_nan=True)
                   for a in arrays[1:])
        if same:
            out.append(arrays[0] if hasattr(leaf, "shape") else leaf)
            axes.append(None)
        else:
            out.append(np.stack(arrays))
            axes.append(0)
    return (jax.tree_util.tree_unflatten(tree, out), jax.tree_util.tree_unflatten(tree, axes))

