"""Build a closed loop from a scenario and run it: the Python API behind the CLI.

>>> from tspend import load_scenario, override, run
>>> s = override(load_scenario("ex2_duffing"), **{"run.duration": 5.0})
>>> result = run(s)
>>> result.metrics["rmse_ss"], result.history["x"].shape      # doctest: +SKIP
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from tspend import __version__
from tspend.config import RunConfig, Scenario
from tspend.runtime.errors import ControllerError, ScenarioError
from tspend.controllers import build as build_controller_kind
from tspend.controllers import needs_machine as controller_needs_machine
from tspend.controllers.base import Controller
from tspend.loop.effects import (EffectsPlant, Measurement, needs_hook, needs_plant_wrapper,
    unsupported as effects_unsupported)
from tspend.loop.metrics import MachineInfo, MetricsAccumulator
from tspend.plants import randomize
from tspend.plants import registry as plant_registry
from tspend.plants.base import Plant
from tspend.runtime.plugins import own_failure
from tspend.runtime.errors import ModelWarning
from tspend.loop.runner import ClosedLoop, LoopSettings, StopRequest, controller_failure
from tspend.loop.sinks import Block, InnerSnapshot, RunEnd, RunInfo, Sink
from tspend.task import Task, build_task
from tspend.task.feasibility import check_task


def build_plant(scenario: Scenario, kind: str | None = None) -> Plant:
    """The scenario's plant (or the same machine on backend ``kind``), reset to x0, with
    the scenario's real-world effects on the actuator, rail and parameters, and what its
    ``[randomize]`` draws at its seed (:mod:`tspend.plants.randomize`).

    A MuJoCo model's departures from the paper's ODE are warned about here, once, as
    :class:`tspend.runtime.errors.ModelWarning` (one line each), before the first step.

    Raises
    ------
    ScenarioError
        ``scenario`` is not a Scenario, ``kind`` is not a backend of its domain, or the
        model cannot be built (file, joint names, timestep, ``dt``).
    """
    _check_scenario(scenario)
    if kind is not None and not isinstance(kind, str):
        raise ScenarioError(f"plant kind: expected a string, got {kind!r:.80}")
    return _built(randomize.draw(scenario).scenario, kind)


def machine_kind_hint(scenario: Scenario) -> str:
    """When the scenario's model is another domain's machine (a double pendulum on a cart
    given to the single cart-pole's kind, say): which plant kind takes it, and a shipped
    scenario of that kind on a model with the same joints ("" when the model fits the
    scenario's own domain, or cannot be read: the error says enough then)."""
    import tomllib

    from tspend.runtime.model_file import read_spec

    def joint_types(path) -> tuple[tuple[str, ...], object] | None:
        """``(joint types in the model's order, compiled model)``; None: unreadable."""
        try:
            model = read_spec(path).compile()
        except Exception:  # an unreadable model: no hint, the error itself stands
            return None
        return tuple(mujoco_joint_type(int(t)) for t in model.jnt_type), model

    try:
        path = plant_registry.resolve_model_path(scenario)
    except Exception:
        return ""
    found = joint_types(path) if path is not None and path.is_file() else None
    if found is None:
        return ""
    types, model = found
    own = plant_registry.domain_of(scenario.plant.kind)
    if own.fits_model(model):
        return ""
    domain = next((d for d in plant_registry.DOMAINS.values()
                   if d is not own and d.mujoco_kind() and d.fits_model(model)), None)
    if domain is None:
        return ""
    kind = domain.mujoco_kind()
    from tspend.scenario import available_scenarios, load_scenario

    named = ""
    for file in available_scenarios():
        try:
            with open(file, "rb") as fh:
                if tomllib.load(fh).get("plant", {}).get("kind") != kind:
                    continue
            other = load_scenario(file)
            theirs = joint_types(plant_registry.resolve_model_path(other))
        except Exception:  # a scenario that does not load is no example
            continue
        if theirs is not None and theirs[0] == types:
            named = file.stem
            break
    where = f" (scenario {named}, with plant.model set to this file)" if named else ""
    return (f"a model with joints {', '.join(types)} is the {domain.name} domain's machine: "
            f"run it as plant.kind = \"{kind}\"{where}")


def mujoco_joint_type(code: int) -> str:
    """MuJoCo's joint type code as MJCF names it ("slide", "hinge", "ball", "free")."""
    import mujoco

    return mujoco.mjtJoint(code).name.removeprefix("mjJNT_").lower()


def _built(scenario: Scenario, kind: str | None) -> Plant:
    """:func:`build_plant` of a scenario whose draws are applied already."""
    refused = effects_unsupported(scenario.effects, plant_registry.domain_of(scenario.plant.kind))
    if refused:
        raise ScenarioError(f"{scenario.path}: {refused}")
    try:
        plant = plant_registry.build(scenario, kind)
    except ScenarioError as exc:
        hint = machine_kind_hint(scenario)
        if not hint:
            raise
        raise ScenarioError(f"{exc}; {hint}") from exc
    plant.check_sample_time(scenario.run.dt)
    for line in plant.departures(scenario.run.dt):
        warnings.warn(f"{plant.model_path}: {line}", ModelWarning, stacklevel=2)  # type: ignore[attr-defined]
    plant.reset(np.asarray(scenario.plant.x0, dtype=float))
    active = plant.constraint_active()
    if active:
        # a contact or a limit at t = 0 acts on every run from the first step: named before
        # any run, not found afterwards in a fall's cause
        warnings.warn(f"{plant.model_path}: at the start ({scenario.plant.kind}, x0 = "  # type: ignore[attr-defined]
                      f"{list(scenario.plant.x0)}): {active}; MuJoCo applies it from t = 0 and "
                      f"the ODE does not have it", ModelWarning, stacklevel=2)
    if needs_plant_wrapper(scenario.effects):
        plant = EffectsPlant(plant, scenario.effects)
        plant.reset(np.asarray(scenario.plant.x0, dtype=float))
    return plant


def _check_scenario(scenario: object) -> None:
    if not isinstance(scenario, Scenario):
        raise ScenarioError(f"expected a Scenario (from tspend.load_scenario), got "
                            f"{type(scenario).__name__}")


def with_gain_sign(scenario: Scenario, plant: Plant) -> Scenario:
    """Resolve ``controller.gain_sign = "plant"`` to the sign the plant measures."""
    if scenario.controller.gain_sign != "plant":
        return scenario
    sign = plant.gain_sign
    return replace(scenario, controller=replace(
        scenario.controller, gain_sign="negative" if sign < 0 else "positive"))


def with_input_sets(scenario: Scenario, plant: Plant) -> tuple[Scenario, str]:
    """The paper's controller's input sets (``[controller.sets] u``, in the units of u,
    sized for the scenario's own actuator) scaled to ``plant``'s actuator range where they
    reach beyond it, and the line saying so ("" when unchanged): sets for a 40 N motor on
    an actuator of control range +/-1 would keep it saturated.  A range the sets fit is
    left alone (the scenario's ``effects.saturation`` is a limit the controller is not
    told of)."""
    inner = getattr(plant, "inner", plant)
    if not inner.inputs:
        return scenario, ""
    inp = inner.inputs[0]
    sets = scenario.controller.u_sets
    lo, hi = float(inp.lo), float(inp.hi)
    if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo) or \
            (sets.lo >= lo - 1e-12 * (hi - lo) and sets.hi <= hi + 1e-12 * (hi - lo)):
        return scenario, ""
    unit = f" {inp.unit}" if inp.unit else ""
    line = (f"controller.sets.u [{sets.lo:g}, {sets.hi:g}] reaches beyond actuator "
            f"'{inp.name}''s range [{lo:g}, {hi:g}]{unit}: the paper's controller's input sets "
            f"are scaled to that range")
    return replace(scenario, controller=replace(
        scenario.controller, u_sets=replace(sets, lo=lo, hi=hi))), line


def nominal_machine(scenario: Scenario) -> Plant:
    """The machine a controller designs on: the scenario's plant as the file writes it,
    NOT the one ``[randomize]`` draws for the run's seed.

    Nominal on purpose: a model-based controller knows the machine's data sheet, not the
    draw (a randomised run measures how it copes with the difference, and the draw would
    otherwise leak into the design: :mod:`tspend.plants.randomize`).  Built once per run
    and handed to the controller's builder; it is never stepped."""
    return plant_registry.build(scenario)


def build_controller(scenario: Scenario, rng: np.random.Generator | None = None,
                     kind: str | None = None, machine: Plant | None = None) -> Controller:
    """The controller ``kind`` (default: the scenario's own), reset with ``rng``
    (default: a generator seeded with the scenario's seed), designed on ``machine``
    (default: the :func:`nominal_machine`, built here when the kind designs on one).

    Raises
    ------
    ScenarioError
        ``scenario`` is not a Scenario, ``kind`` is unknown, or its settings are invalid.
    ControllerError
        the controller's ``reset`` raised (a plug-in's failure; exit 6 on the CLI).
    """
    _check_scenario(scenario)
    if machine is None and controller_needs_machine(scenario, kind):
        machine = nominal_machine(scenario)  # nominal, not drawn: see nominal_machine
    ctrl = build_controller_kind(scenario, kind, machine)
    try:
        ctrl.reset(rng if rng is not None else np.random.default_rng(scenario.run.seed))
    except BaseException as exc:  # a plug-in's reset: its failure, before any sample
        if not own_failure(exc):
            raise
        raise ControllerError(controller_failure(exc, 0.0, ctrl.kind)) from None
    return ctrl


def scenario_text(scenario: Scenario) -> str:
    """The file's text, with the overrides applied on top written after it as comments."""
    if not scenario.overrides:
        return scenario.text
    lines = "\n".join(f"#   {k} = {v!r}" for k, v in scenario.overrides)
    return f"{scenario.text.rstrip()}\n\n# overrides applied on top of this file:\n{lines}\n"


def run_info(scenario: Scenario, plant: Plant, steps: int, kind: str | None = None,
             controller: Controller | None = None, task: Task | None = None) -> RunInfo:
    kind = kind or scenario.plant.kind
    fuzzy = controller.fuzzy_inputs() if controller is not None else {}
    task = task if task is not None else scenario_task(scenario, plant)
    u_lo, u_hi = input_range(plant, scenario)
    return RunInfo(
        scenario_name=scenario.name, scenario_text=scenario_text(scenario),
        scenario_path=scenario.path,
        seed=scenario.run.seed, version=__version__, plant_kind=kind,
        order=plant.order, dt=scenario.run.dt, duration=steps * scenario.run.dt, steps=steps,
        model_inputs=fuzzy.get("model", ()), compensator_inputs=fuzzy.get("compensator", ()),
        extras=tuple(plant.extras().keys()), drawing=plant_registry.drawing(plant, scenario),
        controller_kind=controller.kind if controller is not None else "",
        diagnostics=tuple(controller.diagnostics) if controller is not None else (),
        state_names=task.names, state_units=task.units, view=task.view, bounds=task.bounds(),
        input_unit=plant.inputs[0].unit if plant.inputs else "",
        force_unit=getattr(plant.inputs[0], "force_unit", "") if plant.inputs else "",
        force_per_unit=getattr(plant.inputs[0], "force_per_unit", 1.0) if plant.inputs else 1.0,
        u_lo=u_lo, u_hi=u_hi)


class History:
    """A sink that keeps every sample (for the Python API; memory grows with the run)."""

    def __init__(self) -> None:
        self.blocks: list[dict[str, np.ndarray]] = []
        self.info: RunInfo | None = None

    def start(self, info: RunInfo) -> None:
        self.info = info  # the layout to_pandas names the columns by

    def block(self, block: Block) -> None:
        self.blocks.append({k: np.array(v, copy=True) for k, v in block.data.items()})

    def inner(self, snap: InnerSnapshot) -> None:
        pass

    def finish(self, end: RunEnd) -> None:
        pass

    def arrays(self) -> dict[str, np.ndarray]:
        if not self.blocks:
            return {}
        return {k: np.concatenate([b[k] for b in self.blocks]) for k in self.blocks[0]}


@dataclass
class RunResult:
    scenario: Scenario
    end: RunEnd
    history: dict[str, np.ndarray]
    controller: Controller
    plant: Plant
    #: what the sinks were told before the first block (names, units, view, diagnostics)
    info: RunInfo | None = None

    @property
    def metrics(self) -> dict:
        return self.end.metrics

    @property
    def status(self) -> str:
        return self.end.status

    def to_pandas(self, units: bool | None = None):
        """The time series as a pandas DataFrame indexed by ``t_s``, with the columns and
        the names of ``tspend export`` (the model's joint names, the unit at the end:
        ``hinge_rad``, ``hinge_dot_rad_s``, ``ref_rad``, ``u_N``, ``slider_m``, ...), so
        ``to_pandas().reset_index()`` is the export's table of the same run.

        ``units=False``, deprecated (removed in the next release): the series' internal keys
        (``x1``, ``r_d1``, ``e_1``, ``u``), indexed by ``t``.
        """
        from tspend.recorder.timeseries import history_frame, run_table

        if units is False:
            import warnings

            warnings.warn("to_pandas(units=False) is deprecated and goes in the next release: "
                          "to_pandas() names every column as tspend export does (hinge_rad)",
                          FutureWarning, stacklevel=2)
            return history_frame(self.history, self.controller.diagnostics)
        if self.info is None:
            raise ValueError("to_pandas: this result kept no history (keep_history=False)")
        return run_table(self.history, self.info)

    def plot(self, every: int = 1):
        """The run in the paper's panels (states against references, then u): a matplotlib
        Figure (needs the ``plot`` extra)."""
        from tspend.recorder.plotting import run_figure

        return run_figure(self, every)


def input_range(plant: Plant, scenario: Scenario) -> tuple[float, float]:
    """The range the plant clips ``u`` to: its input's bounds, narrowed by
    ``effects.saturation``; (-inf, inf) for a plant without a limit."""
    lo, hi = -math.inf, math.inf
    if plant.inputs:
        lo, hi = plant.inputs[0].lo, plant.inputs[0].hi
    sat = scenario.effects.saturation
    if sat > 0.0:
        lo, hi = max(lo, -sat), min(hi, sat)
    return float(lo), float(hi)


def machine_info(plant: Plant, task: Task, scenario: Scenario,
                 drawn: dict | None = None) -> MachineInfo:
    """The joints, parameters and input range the machine metrics report."""
    names = task.names
    joints = tuple((j.name, names.index(j.name)) for j in plant.joints if j.name in names)
    lo, hi = input_range(plant, scenario)
    inp = plant.inputs[0] if plant.inputs else None
    units = dict(u_unit=inp.unit, force_unit=getattr(inp, "force_unit", ""),
                 force_per_unit=getattr(inp, "force_per_unit", 1.0)) if inp is not None else {}
    return MachineInfo(joints=joints, parameters=dict(plant.parameters()), u_lo=lo, u_hi=hi,
                       drawn=dict(drawn or {}), goal_angle=scenario.task.goal_angle,
                       goal_by=scenario.task.goal_by, constraints=task.constraints, **units)


def control_every(run: "RunConfig", ctrl: Controller) -> int:
    """Physics steps per controller sample: ``run.control_period`` when given, else the
    controller's own ``sample_period`` (MPC's 20 ms), else every step."""
    period = run.control_period or ctrl.sample_period
    if period <= 0.0:
        return 1
    every = int(round(period / run.dt))
    if every < 1 or abs(every * run.dt - period) > 1e-9 * period:
        raise ScenarioError(f"control period {period:g} s (kind '{ctrl.kind}') is not a whole "
                            f"multiple of run.dt = {run.dt:g} s")
    return every


def scenario_task(scenario: Scenario, plant: Plant) -> Task:
    """The scenario's ``[task]`` on ``plant`` (the domain's defaults where it says nothing),
    with the scenario's reference, disturbance and ``effects.rail``."""
    return build_task(plant, scenario.task, scenario.effects, scenario.reference,
                      scenario.disturbance, where=scenario.path or scenario.name)


@dataclass(frozen=True)
class Prepared:
    """A plant, its task and a controller built (and so checked) before anything is run
    or written."""

    scenario: Scenario   # with what the plant decides resolved (controller.gain_sign)
    plant: Plant
    controller: Controller
    task: Task | None = None
    #: what the scenario's [randomize] drew at its seed (flat name -> value)
    drawn: dict | None = None


def prepare(scenario: Scenario, plant_kind: str | None = None,
            controller: str | None = None) -> Prepared:
    """Build the plant (model file, joint names, timestep), its task and the controller
    without running: every error a scenario can still raise surfaces here, as a
    ScenarioError.  The plant is the machine ``[randomize]`` draws at the scenario's
    seed; the controller is designed on the nominal machine (:func:`nominal_machine`,
    built once when the kind designs on a model), so it does not know the draw."""
    drawn = randomize.draw(scenario)
    plant = _built(drawn.scenario, plant_kind)
    task = scenario_task(scenario, plant)
    check_task(plant, task, scenario)
    scenario, scaled = with_input_sets(with_gain_sign(scenario, plant), plant)
    # the controller designs on the nominal machine (built in build_controller), not on
    # `plant`, the draw
    ctrl = build_controller(scenario, kind=controller)
    if scaled and ctrl.fuzzy_inputs():
        # only a controller with fuzzy input sets reads them
        warnings.warn(scaled, ModelWarning, stacklevel=2)
    return Prepared(scenario, plant, ctrl, task, drawn.values)


def steps_of(scenario: Scenario) -> int:
    return int(round(scenario.run.duration / scenario.run.dt))


def run(scenario: Scenario, sinks: Sequence[Sink] = (), keep_history: bool = True,
        plant_kind: str | None = None, block_size: int = 1000,
        stop: StopRequest | None = None,
        controller: str | None = None, prepared: Prepared | None = None,
        compiled: bool = True) -> RunResult:
    """Run the scenario's closed loop; ``sinks`` (e.g. a Rerun recorder) see every block.

    ``plant_kind`` runs the same scenario on another backend (``cartpole_ode`` for a
    MuJoCo scenario, say), which is what the cross-check does.  ``stop``, set from a
    signal handler, ends the run cleanly at the next sample (RunInterrupted is raised
    after the sinks have finished).  ``prepared``: the plant and controller of
    :func:`prepare`, built before the caller opened its outputs.  ``compiled=False`` runs
    the generic Python loop even where the compiled one applies (:mod:`tspend.loop.fastloop`;
    the results are the same).
    """
    parts = prepared or prepare(scenario, plant_kind, controller)
    scenario, plant, ctrl = parts.scenario, parts.plant, parts.controller
    steps = steps_of(scenario)
    dt = scenario.run.dt
    snap_every = int(round(scenario.run.snapshot_every / dt)) if scenario.run.snapshot_every else 0
    settings = LoopSettings(dt=dt, steps=steps, block_size=block_size, snapshot_every=snap_every,
                            state_bound=scenario.plant.state_bound,
                            control_bound=scenario.run.control_bound, compiled=compiled,
                            control_every=control_every(scenario.run, ctrl),
                            control_delay=scenario.run.control_delay)
    hook = Measurement(scenario.effects, plant, dt, scenario.run.seed) \
        if needs_hook(scenario.effects) else None
    task = parts.task if parts.task is not None else scenario_task(scenario, plant)
    loop = ClosedLoop(plant, ctrl, scenario.reference, scenario.disturbance, settings, stop,
                      hook=hook, task=task)
    metrics = MetricsAccumulator(dt, ss_start=0.5 * steps * dt, seed=scenario.run.seed,
                                 machine=machine_info(plant, task, scenario, parts.drawn))
    history = History()
    all_sinks: list[Sink] = [metrics] + ([history] if keep_history else []) + list(sinks)
    end = loop.run(run_info(scenario, plant, steps, plant_kind, ctrl, task), all_sinks)
    return RunResult(scenario, end, history.arrays(), ctrl, plant, history.info)
