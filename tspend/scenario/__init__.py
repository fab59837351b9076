"""Scenario files: TOML onto the frozen configuration of :mod:`tspend.config`, validated.

Every problem is a :class:`ScenarioError` whose message names the file, the key and
what is allowed, e.g. ``scenarios/x.toml: controller.eta: must be > 0, got -1``.
Validation happens before anything runs; what needs the model file (joint names, the
MuJoCo timestep) is checked when the plant is built, still before the first step.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import tomllib
from pathlib import Path
from typing import Any, Callable


from tspend.config import signals
from tspend.shipped import scenario_search_path
from tspend.runtime.bounds import (MAX_FILE_BYTES, MAX_LIST, MAX_NAME, MAX_NESTING, MAX_SEED,
    MAX_STEPS, MAX_TERMS)
from tspend.config import (BoxConstraint, ConstraintsConfig, ControllerConfig, EffectsConfig,
    LinearConstraint, OuterLoopConfig, ParameterChange, PlantConfig, RunConfig, SafetyConfig,
    Scenario, TaskConfig)
from tspend.controllers import SAFETY_CHOICES, settings_classes
from tspend.controllers.settings import PAPER_KINDS, parse_kind_tables, read_settings
from tspend.runtime.errors import ScenarioError
from tspend.config.tables import Table, read_fields
from tspend.plants.randomize import read_randomize
from tspend.plants.registry import PLANT_KINDS, resolve_model_path

#: plant kinds and their order n
PLANT_ORDERS = {kind: k.order for kind, k in PLANT_KINDS.items()}

REFERENCE_KINDS: dict[str, type] = {
    "sine": signals.Sine, "sum_of_sines": signals.SumOfSines,
    "exp_approach": signals.ExpApproach, "constant": signals.Constant,
    "steps": signals.StepSequence, "csv": signals.CsvReference,
}
DISTURBANCE_KINDS: dict[str, type] = {
    "square": signals.SquareWave, "zero": signals.NoDisturbance, "sine": signals.SineDisturbance,
}

TOP_KEYS = ("name", "description", "run", "plant", "reference", "disturbance", "controller",
            "controllers", "effects", "task", "randomize", "safety")


def scenario_dirs() -> list[Path]:
    """The existing folders of the scenario search path, each once, in search order
    (:func:`tspend.shipped.scenario_search_path`)."""
    seen: list[Path] = []
    for d in scenario_search_path():
        if d.is_dir() and d.resolve() not in [s.resolve() for s in seen]:
            seen.append(d)
    return seen


def available_scenarios() -> list[Path]:
    """Every scenario file, by name, the first found on the search path (scenario_dirs)."""
    found: dict[str, Path] = {}
    for d in scenario_dirs():
        for p in sorted(d.glob("*.toml")):
            found.setdefault(p.stem, p)
    return [found[k] for k in sorted(found)]


def find_scenario(name_or_path: str | Path) -> Path:
    """A scenario file from a path, or from a bare name such as ``ex2_duffing``.

    Raises
    ------
    ScenarioError
        not a string or path, or no such scenario.
    """
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise ScenarioError(f"scenario: expected a name or a path, got "
                            f"{type(name_or_path).__name__} {name_or_path!r:.80}")
    p = Path(name_or_path)
    if "\x00" in str(p):
        raise ScenarioError(f"{str(p)!r}: a scenario name or path cannot contain a NUL byte")
    try:
        if p.is_file():
            return p
        for d in scenario_dirs():
            for cand in (d / p.name, d / f"{p.name}.toml"):
                if cand.is_file():
                    return cand
    except OSError as exc:  # e.g. a name longer than the file system allows
        raise ScenarioError(f"{str(p)[:200]}: cannot look for a scenario file there: "
                            f"{exc.strerror or exc}") from None
    names = [s.stem for s in available_scenarios()]
    hint = difflib.get_close_matches(p.stem, names, n=1)
    did = f" (did you mean '{hint[0]}'?)" if hint else ""
    raise ScenarioError(f"{name_or_path}: no such scenario file{did}; available: "
                        f"{', '.join(names) or 'none'}")


# -- small typed readers ---------------------------------------------------------------
# -- sections --------------------------------------------------------------------------
def _run(r: Table) -> RunConfig:
    r.check_keys(tuple(f.name for f in dataclasses.fields(RunConfig)))
    d = RunConfig()
    cfg = RunConfig(
        duration=r.number("duration", d.duration, low=0.0, strict=True),
        dt=r.number("dt", d.dt, low=0.0, strict=True),
        seed=r.integer("seed", d.seed, low=0, high=MAX_SEED),
        snapshot_every=r.number("snapshot_every", d.snapshot_every, low=0.0),
        control_bound=r.number("control_bound", d.control_bound, low=0.0),
        control_period=_control_period(r),
        control_delay=r.integer("control_delay", d.control_delay, low=0),
        controller=_default_kind(r),
    )
    if not cfg.duration / cfg.dt <= MAX_STEPS:
        # too many steps (1e308 s has no integer count): the scenario's own check refuses
        # it below with its message; the delay check here has nothing to compare against
        return cfg
    steps = int(round(cfg.duration / cfg.dt))
    if cfg.control_delay >= steps:
        # the controller's output would never reach the plant: nothing of it would be run
        raise r.error("control_delay", f"{cfg.control_delay} steps of {cfg.dt:g} s is not "
                                       f"shorter than the run ({steps} steps, {cfg.duration:g} s): "
                                       f"no computed u would ever be applied")
    return cfg


def _default_kind(r: Table) -> str:
    """``run.controller``: a controller kind, or "" for the paper's."""
    if not r.has("controller"):
        return ""
    from tspend.controllers import KINDS

    return r.string("controller", None, tuple(KINDS))


def _control_period(r: Table) -> float:
    """``run.control_period``: 0 or a whole multiple of ``run.dt``."""
    period = r.number("control_period", 0.0, low=0.0)
    dt = r.number("dt", RunConfig().dt, low=0.0, strict=True)
    if period > 0.0:
        ratio = period / dt
        if ratio < 1.0 - 1e-9 or abs(ratio - round(ratio)) > 1e-9 * ratio:
            raise r.error("control_period", f"must be a whole multiple of run.dt = {dt:g} s "
                                            f"(or 0 = every step), got {period:g}")
    return period


def _plant(r: Table) -> PlantConfig:
    """``[plant]`` onto the kind's own configuration class (tspend.plants.registry)."""
    kind = r.string("kind", None, tuple(PLANT_KINDS))
    cls = PLANT_KINDS[kind].config
    values = read_fields(r, cls, f"for plant kind '{kind}'", skip=("kind", "x0"))
    n = PLANT_ORDERS[kind]
    return cls(kind=kind, x0=r.numbers("x0", n, (0.0,) * n), **values)


def _effects(r: Table, n: int) -> EffectsConfig:
    values = read_fields(r, EffectsConfig, "in [effects]", skip=("change", "outer_loop"))
    if any(v < 0 for v in values.get("noise_std", ())):
        raise r.error("noise_std", "standard deviations must be >= 0")
    if "noise_std" in values and len(values["noise_std"]) != n:
        raise r.error("noise_std", f"must have {n} entries (one per state), got "
                                   f"{len(values['noise_std'])}")
    if r.has("change"):
        c = r.table_of("change")
        values["change"] = ParameterChange(**read_fields(c, ParameterChange, "in [effects.change]"))
    if r.has("outer_loop"):
        o = r.table_of("outer_loop")
        values["outer_loop"] = OuterLoopConfig(**read_fields(o, OuterLoopConfig,
                                                         "in [effects.outer_loop]"))
    return EffectsConfig(**values)


def _signal(r: Table, kinds: dict[str, type], default_kind: str) -> Any:
    """A reference or disturbance: ``kind`` picks the class, the other keys its fields."""
    kind = r.string("kind", default_kind, tuple(kinds))
    cls = kinds[kind]
    fields = {f.name: f for f in dataclasses.fields(cls)}
    r.check_keys(("kind",) + tuple(fields), f"for kind '{kind}'")
    values = {}
    for name, f in fields.items():
        if not r.has(name):
            if f.default is dataclasses.MISSING:
                raise r.error(name, f"missing (required for kind '{kind}')")
            continue
        if isinstance(f.default, str) or f.type in ("str", str):
            values[name] = r.string(name)
        else:
            values[name] = r.numbers(name) if name.endswith("s") else r.number(name)
    if kind == "sum_of_sines":
        lengths = {len(values[k]) for k in ("amplitudes", "omegas", "phases")}
        if len(lengths) != 1:
            raise r.error("amplitudes", "amplitudes, omegas and phases must have the same length")
    if kind in ("steps", "csv"):
        problem = cls.validate(values, r.path)
        if problem:
            raise r.error(problem[0], problem[1])
    if kind == "square" and values.get("period", 1.0) <= 0.0:
        raise r.error("period", f"must be > 0, got {values['period']:g}")
    return cls(**values)


def _controller(r: Table, n: int) -> ControllerConfig:
    """``[controller]``: the paper's kinds' settings, read like every kind's
    ``[controllers.KIND]`` table (their settings class in the one registry of kinds)."""
    from tspend.controllers import KINDS

    return read_settings(r, KINDS[PAPER_KINDS[0]].Settings, n)


# -- entry points ----------------------------------------------------------------------
def _task(r: Table, n: int) -> TaskConfig:
    """``[task]``: names are checked against the plant's states when the run is built
    (:func:`tspend.task.build_task`), the shapes and numbers here."""
    r.check_keys(tuple(f.name for f in dataclasses.fields(TaskConfig)), "in [task]")
    d = TaskConfig()
    view = r.strings("view", d.view)
    if view and len(view) != n:
        raise r.error("view", f"must name {n} states (the tracked output and its "
                              f"derivatives, one per state of the plant's order), got {len(view)}")
    fall = r.number("fall_angle", low=0.0) if r.has("fall_angle") else d.fall_angle
    bounds = r.table_of("state_bounds")
    goal_angle = r.number("goal_angle", d.goal_angle, low=0.0)
    goal_by = r.number("goal_by", d.goal_by, low=0.0)
    if goal_by > 0.0 and goal_angle == 0.0:
        raise r.error("goal_by", "needs task.goal_angle > 0 (the goal it is the deadline of)")
    return TaskConfig(view=view, fall_angle=fall,
                      joint_limits=r.boolean("joint_limits", d.joint_limits),
                      state_bounds=tuple((str(k), bounds.number(k, low=0.0, strict=True))
                                         for k in bounds.table),
                      goal_angle=goal_angle, goal_by=goal_by,
                      constraints=_constraints(r.table_of("constraints")))


def _constraints(r: Table) -> ConstraintsConfig:
    """``[task.constraints]``: the names are checked against the plant's states and input
    when the run is built (:func:`tspend.task.constraints.build_constraints`), the numbers here."""
    r.check_keys(("defaults", "box", "linear"), "in [task.constraints]")
    boxes = []
    box_r = r.table_of("box")
    for name in box_r.table:
        b = box_r.table_of(name)
        b.check_keys(("lo", "hi", "hard"), "in a box {lo, hi, hard}")
        lo = b.number("lo", -math.inf) if b.has("lo") else -math.inf
        hi = b.number("hi", math.inf) if b.has("hi") else math.inf
        if not (b.has("lo") or b.has("hi")):
            raise box_r.error(name, "give lo, hi or both (the box's ends)")
        if not lo < hi:
            raise b.error("hi", f"must be > lo ({lo:g}), got {hi:g}")
        boxes.append((str(name), BoxConstraint(lo, hi, b.boolean("hard", False))))
    linear = []
    lin_r = r.table_of("linear")
    for label in lin_r.table:
        c = lin_r.table_of(label)
        c.check_keys(("terms", "min", "max"), "in a linear constraint {terms, min, max}")
        terms_r = c.table_of("terms", required=True)
        terms = tuple((str(k), terms_r.number(k)) for k in terms_r.table)
        if not terms or all(v == 0.0 for _, v in terms):
            raise c.error("terms", "name at least one state or input with a nonzero coefficient, "
                                   "e.g. {slider = 1.0, slider_dot = 0.5}")
        if not (c.has("min") or c.has("max")):
            raise lin_r.error(label, "give min, max or both (sum of terms within them)")
        lo = c.number("min") if c.has("min") else -math.inf
        hi = c.number("max") if c.has("max") else math.inf
        if not lo < hi:
            raise c.error("max", f"must be > min ({lo:g}), got {hi:g}")
        linear.append((str(label), LinearConstraint(terms, lo, hi)))
    return ConstraintsConfig(defaults=r.boolean("defaults", True), boxes=tuple(boxes),
                             linear=tuple(linear))


def parse_scenario(text: str, path: str = "<string>", name: str | None = None,
                   overrides: tuple[tuple[str, Any], ...] = ()) -> Scenario:
    """A validated :class:`Scenario` from TOML text (``path`` is used in messages).

    ``overrides`` are ``(dotted.key, value)`` pairs applied to the parsed TOML before
    validation, so an override is checked exactly like a key of the file.
    """
    raw = parse_toml(text, path)
    where = path
    for key, value in overrides:
        set_dotted(raw, key, value, path)
        where = f"{path} (with overrides)"
    top = Table(where, raw, "")
    top.check_keys(TOP_KEYS)
    _check_name(top)
    plant_r = top.table_of("plant", required=True)
    plant = _plant(plant_r)
    n = PLANT_ORDERS[plant.kind]
    run = _run(top.table_of("run"))
    ref = _signal(top.table_of("reference", required=True), REFERENCE_KINDS, "sine")
    dist = _signal(top.table_of("disturbance"), DISTURBANCE_KINDS, "zero")
    ctrl = _controller(top.table_of("controller", required=True), n)
    kind_settings = parse_kind_tables(top.table_of("controllers"), n, settings_classes())
    effects = _effects(top.table_of("effects"), n)
    task = _task(top.table_of("task"), n)
    randomize = read_randomize(top.table_of("randomize"), plant)
    if run.dt > run.duration:
        raise top.error("run.dt", f"dt ({run.dt:g}) must not exceed duration ({run.duration:g})")
    if run.duration / run.dt > MAX_STEPS:
        raise top.error("run.dt", f"duration / dt = {run.duration / run.dt:.3g} samples is more "
                                  f"than {MAX_STEPS:.0e}; use a larger dt or a shorter duration")
    if run.snapshot_every and not run.dt <= run.snapshot_every <= MAX_STEPS * run.dt:
        raise top.error("run.snapshot_every", f"must be 0 (no snapshots) or from dt ({run.dt:g}) "
                                              f"to {MAX_STEPS:.0e} dt, got {run.snapshot_every:g}")
    return Scenario(
        name=top.string("name", name or Path(path).stem),
        description=top.string("description", ""),
        run=run, plant=plant, reference=ref, disturbance=dist, controller=ctrl,
        effects=effects, task=task,
        path=str(path), text=text, overrides=tuple(overrides), controllers=kind_settings,
        randomize=randomize,
        safety=_safety(top.table_of("safety"), run.control_period or run.dt))


def _safety(r: Table, control_period_s: float) -> SafetyConfig:
    """``[safety]`` onto :class:`SafetyConfig` (docs/safety.md); ``control_period_s``: how
    often the controller runs (``run.control_period``, else ``run.dt``)."""
    values = read_fields(r, SafetyConfig, "in [safety]")
    values["filter"] = r.string("filter", "off", SAFETY_CHOICES)  # the registry's names
    if not values.get("margin", 0.0) < 1.0:
        raise r.error("margin", f"must be from 0 to below 1 (a share of each box's "
                                f"half-width), got {values['margin']:g}")
    # every size a user sets is bounded: the plan's QP grows with them
    for key, high in (("horizon", 200), ("substeps", 50)):
        if values.get(key, 0) > high:
            raise r.error(key, f"must be at most {high}, got {values[key]}")
    period = values.get("plan_period", 0.0)
    # the plan's first interval is one control sample and the rest are plan periods: one
    # shorter than a sample plans a horizon of nanoseconds, at any cost (1e-9: 150 s, issue 51)
    if period and not control_period_s <= period <= 1.0:
        raise r.error("plan_period", f"must be 0 (from the machine) or from the control period "
                                     f"({control_period_s:g} s) to 1 s, got {period:g}")
    if not values.get("budget_ms", 0.0) <= 1000.0:
        raise r.error("budget_ms", f"must be at most 1000 ms, got {values['budget_ms']:g}")
    return SafetyConfig(**values)


def parse_toml(text: str, path: str) -> dict:
    """TOML text as a dict, within :data:`MAX_NESTING`; every failure a ScenarioError."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML: {exc}") from None
    except RecursionError:
        raise ScenarioError(f"{path}: tables or arrays nested more than {MAX_NESTING} "
                            f"levels deep") from None
    except ValueError as exc:  # e.g. an integer of more digits than Python converts
        raise ScenarioError(f"{path}: not valid TOML: {str(exc).splitlines()[0][:200]}") from None
    check_nesting(raw, path)
    return raw


def check_nesting(value: Any, where: str, limit: int = MAX_NESTING) -> None:
    """Raise ScenarioError if tables/arrays in ``value`` nest deeper than ``limit``."""
    level: list[tuple[Any, int]] = [(value, 0)]
    while level:
        node, depth = level.pop()
        if depth > limit:
            raise ScenarioError(f"{where}: tables or arrays nested more than {limit} levels deep")
        children = node.values() if isinstance(node, dict) else node if isinstance(node, list) else ()
        level.extend((c, depth + 1) for c in children if isinstance(c, (dict, list)))


def _check_name(top: Table) -> None:
    for key in ("name", "description"):
        v = top.table.get(key)
        if not isinstance(v, str):
            continue  # the typed readers report it
        bad = next((c for c in v if (ord(c) < 32 and (key == "name" or c not in "\n\t"))
                    or 127 <= ord(c) < 160), None)
        if bad is not None:
            raise top.error(key, f"contains the control character {bad!r}; use printable text")
    name = top.table.get("name")
    if isinstance(name, str) and not 0 < len(name) <= MAX_NAME:
        raise top.error("name", f"must be 1 to {MAX_NAME} characters, got {len(name)}")


def set_dotted(raw: dict, key: str, value: Any, path: str) -> None:
    from tspend.runtime.bounds import MAX_KEY

    if not isinstance(key, str):
        raise ScenarioError(f"{path}: override {key!r:.80}: a key is a dotted string such as "
                            f"controller.eta")
    if len(key) > MAX_KEY:
        raise ScenarioError(f"{path}: override '{key[:80]}...': the key is {len(key)} "
                            f"characters long, more than {MAX_KEY}")
    parts = key.split(".", MAX_NESTING + 1)
    if len(parts) > MAX_NESTING:
        raise ScenarioError(f"{path}: override '{key[:80]}': more than {MAX_NESTING} levels")
    check_nesting(value, f"{path}: override '{key[:80]}'")
    if not all(parts):
        raise ScenarioError(f"{path}: override '{key}': expected a dotted key such as "
                            f"controller.eta")
    node = raw
    for part in parts[:-1]:
        nxt = node.setdefault(part, {})
        if not isinstance(nxt, dict):
            raise ScenarioError(f"{path}: override '{key}': '{part}' is not a table")
        node = nxt
    node[parts[-1]] = _plain(value)


def _plain(value: Any) -> Any:
    """Python values as TOML would give them (tuples become lists, dataclasses tables)."""
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {k: _plain(v) for k, v in dataclasses.asdict(value).items()}
    return value


def load_scenario(name_or_path: str | Path) -> Scenario:
    """Load and validate a scenario by path or by name (``ex3_pendulum_ode``).

    Raises
    ------
    ScenarioError
        not a name or path, no such scenario, unreadable, larger than
        :data:`~tspend.runtime.bounds.MAX_FILE_BYTES`, not TOML, or any value out of
        its bounds (the message names the file and the key).
    """
    path = find_scenario(name_or_path)
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_FILE_BYTES + 1)
        if len(data) > MAX_FILE_BYTES:
            raise ScenarioError(f"{_display(path)}: larger than {MAX_FILE_BYTES} bytes; a "
                                f"scenario file is a few kB")
        text = data.decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"{_display(path)}: cannot read: {exc}") from None
    return parse_scenario(text, _display(path))


def _display(path: Path) -> str:
    """The path as a user would type it: relative to the cwd when it is below it."""
    try:
        return str(path.resolve().relative_to(Path.cwd()))
    except ValueError:
        return str(path)


def override(scenario: Scenario, **changes: Any) -> Scenario:
    """A copy with keys replaced, validated like the file: ``override(s, **{"run.duration": 5})``.

    Keys are the scenario file's dotted keys (``controller.eta``, ``plant.M``,
    ``controller.sets.u``, ``reference.amplitude``); the new scenario remembers them in
    ``overrides`` so a recording says exactly what ran.

    Raises
    ------
    ScenarioError
        ``scenario`` is not a :class:`~tspend.config.Scenario`, a key is unknown, longer
        than :data:`~tspend.runtime.bounds.MAX_KEY` or nested too deep, or a value is
        invalid there.
    """
    if not isinstance(scenario, Scenario):
        raise ScenarioError(f"override: expected a Scenario (from load_scenario), got "
                            f"{type(scenario).__name__}")
    merged = dict(scenario.overrides)
    merged.update(changes)
    return parse_scenario(scenario.text, scenario.path, scenario.name, tuple(merged.items()))
