"""The task: what a controller tracks on a plant, and what ends a run.

A :class:`Task` is built from the scenario's ``[task]`` table (:class:`tspend.config.TaskConfig`)
and the plant's domain (:meth:`tspend.plants.base.Plant.default_task`):

* ``view``: the state names the paper's controllers see, the tracked output and its
  derivatives up to the relative degree (the cart-pole: ``("hinge", "hinge_dot")``; the
  chain plants: their whole state).  The reference ``[r, r', .., r^(n)]`` and the
  disturbance are the scenario's ``[reference]`` and ``[disturbance]``; the task holds them.
* termination, as bounds ``lo[j] < s[j] < hi[j]`` on the full state ``s`` with the
  condition each bound stands for, so the closed loops (the compiled ones too) make one
  generic check and know no plant:

  - ``fall_angle``: ``|pole| > fall_angle`` ends the run ``fell`` (the domain's pole angle,
    measured from upright; default pi/2 for balancing domains, 0 = off);
  - ``joint_limits``: a limited joint's range ends it, ``rail_end`` for a slide joint (the
    cart's rail), ``joint_limit`` for another; ``effects.rail`` overrides the slide
    joint's range with ``[-rail, rail]``;
  - ``state_bounds``: ``|value| > bound`` for a named state ends it ``state_bound``;
  - ``constraints``: a hard box of ``[task.constraints.box]`` on a state ends it
    ``constraint``; every constraint, the domain's defaults included, is measured
    (:mod:`tspend.task.constraints`, ``Task.constraints``).

A terminated run keeps its outputs up to the sample that crossed (recorded, its control
never applied), exits with status :data:`EXIT_TERMINATED` on the CLI, and its message
names the condition and the time, e.g. ``fell at t = 3.4120 s: |hinge| = 1.571 rad
exceeds fall_angle 1.571 rad``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from tspend.config import EffectsConfig, TaskConfig
from tspend.runtime.errors import ScenarioError
from tspend.plants.base import Plant

if TYPE_CHECKING:
    from tspend.task.constraints import ConstraintSet
    from tspend.config.signals import Disturbance, Reference

__all__ = ["EXIT_TERMINATED", "TERMINATIONS", "Bound", "Limit", "Task", "build_task"]

#: the statuses of a run the task ended (each exits with EXIT_TERMINATED on the CLI)
#: (``not_reached``: every bound held but the goal, ``task.goal_angle`` by ``task.goal_by``, was
#: not reached: tspend.loop.runner decides it at the end of the run)
TERMINATIONS = ("fell", "rail_end", "joint_limit", "state_bound", "not_reached", "constraint")

#: the CLI's exit status for a run the task ended (the outputs are kept up to the end)
EXIT_TERMINATED = 4


@dataclass(frozen=True)
class Limit:
    """The condition one bound stands for: the status it ends a run with and, for the
    message, what was crossed.  ``symmetric`` bounds are on ``|value|`` (a fall angle, a
    state bound, a rail) and read "|hinge| = 1.6 rad exceeds fall_angle 1.571 rad";
    others on the value ("slider = 1.002 m is beyond the end of its range [-1, 1] m")."""

    status: str
    what: str
    symmetric: bool = False


@dataclass(frozen=True)
class Bound:
    """One bounded entry of the full state, as a drawing shows it: entry ``index``
    (``name``, ``unit``) ends the run ``status`` outside ``[lo, hi]`` (+/-inf: open)."""

    index: int
    name: str
    unit: str
    lo: float
    hi: float
    status: str


@dataclass(frozen=True, eq=False)
class Task:
    """The tracked view and the termination bounds over a plant's full state."""

    #: the full state's names and units (the plant's)
    names: tuple[str, ...]
    units: tuple[str, ...]
    #: the controllers' view: names and their places in the full state
    view: tuple[str, ...]
    view_index: np.ndarray
    #: the run ends when s[j] < lo[j] or s[j] > hi[j] (+/-inf: no bound)
    lo: np.ndarray
    hi: np.ndarray
    lo_limits: tuple[Limit | None, ...]
    hi_limits: tuple[Limit | None, ...]
    reference: "Reference | None" = None
    disturbance: "Disturbance | None" = None
    #: the constraints the run is measured against (tspend/task/constraints.py; None: none built)
    constraints: "ConstraintSet | None" = None
    #: (index, lo, hi) of every bounded entry: the generic loop's per-sample check
    watched: tuple[tuple[int, float, float], ...] = field(init=False)

    def __post_init__(self) -> None:
        watched = tuple((j, float(self.lo[j]), float(self.hi[j])) for j in range(self.lo.size)
                        if self.lo[j] > -math.inf or self.hi[j] < math.inf)
        object.__setattr__(self, "watched", watched)

    def bounds(self) -> tuple[Bound, ...]:
        """The bounded entries (rail ends, joint limits, fall angle, state bounds)."""
        out = []
        for j, lo, hi in self.watched:
            limit = self.hi_limits[j] or self.lo_limits[j]
            out.append(Bound(j, self.names[j], self.units[j], lo, hi,
                             limit.status if limit is not None else ""))
        return tuple(out)

    def ended(self, state: np.ndarray) -> bool:
        """True when ``state`` (full) crosses a bound (NaN crosses none)."""
        for j, lo, hi in self.watched:
            v = state[j]
            if v < lo or v > hi:
                return True
        return False

    def termination(self, state: np.ndarray, t: float) -> tuple[str, str] | None:
        """``(status, message)`` for the first bound ``state`` crosses at time ``t``, or None."""
        for j, lo, hi in self.watched:
            v = float(state[j])
            if v < lo:
                limit = self.lo_limits[j]
            elif v > hi:
                limit = self.hi_limits[j]
            else:
                continue
            assert limit is not None
            unit = f" {self.units[j]}" if self.units[j] else ""
            name = self.names[j]
            if limit.symmetric:
                what = f"|{name}| = {abs(v):.4g}{unit} exceeds {limit.what}"
            else:
                what = f"{name} = {v:.4g}{unit} is beyond {limit.what}"
            return limit.status, f"{limit.status} at t = {t:.4f} s: {what}"
        return None


def build_task(plant: Plant, cfg: TaskConfig = TaskConfig(),
               effects: EffectsConfig = EffectsConfig(), reference: "Reference | None" = None,
               disturbance: "Disturbance | None" = None, where: str = "") -> Task:
    """The task ``cfg`` sets on ``plant`` (its domain's defaults where ``cfg`` says nothing).

    Raises ScenarioError (one line naming ``where`` and the key) for a view or a bound on
    a state the plant does not have, or a fall angle on a domain without a pole.
    """
    where = f"{where}: " if where else ""
    names, units = tuple(plant.state_names), tuple(plant.state_units)
    defaults = plant.default_task()
    allowed = ", ".join(names)

    view = tuple(cfg.view) or defaults.view
    for name in view:
        if name not in names:
            raise ScenarioError(f"{where}task.view: no state named {name!r} on plant "
                                f"{plant.name} (allowed: {allowed})")
    if len(view) != plant.order:
        raise ScenarioError(f"{where}task.view: {len(view)} states given, plant {plant.name} "
                            f"has order {plant.order} (the output and its derivatives)")

    N = len(names)
    lo, hi = np.full(N, -math.inf), np.full(N, math.inf)
    lo_limits: list[Limit | None] = [None] * N
    hi_limits: list[Limit | None] = [None] * N

    def bound(j: int, low: float, high: float, limit: Limit, override: bool = False) -> None:
        if override or low > lo[j]:
            lo[j], lo_limits[j] = low, limit
        if override or high < hi[j]:
            hi[j], hi_limits[j] = high, limit

    if cfg.joint_limits:
        for joint in plant.joints:
            if joint.range is None or joint.name not in names:
                continue
            a, b = joint.range
            status = "rail_end" if joint.kind == "slide" else "joint_limit"
            unit = f" {joint.unit}" if joint.unit else ""
            bound(names.index(joint.name), a, b,
                  Limit(status, f"the end of its range [{a:g}, {b:g}]{unit}"))
    if effects.rail > 0.0:
        # the explicit rail overrides the slide joint's own range (none: a chain plant)
        for joint in plant.joints:
            if joint.kind == "slide" and joint.name in names:
                bound(names.index(joint.name), -effects.rail, effects.rail,
                      Limit("rail_end", f"the rail's half-length (effects.rail = "
                                        f"{effects.rail:g} m)", symmetric=True), override=True)
                break

    fall = defaults.fall_angle if cfg.fall_angle is None else float(cfg.fall_angle)
    if fall > 0.0:
        if not defaults.pole:
            if cfg.fall_angle is not None:
                raise ScenarioError(f"{where}task.fall_angle: plant {plant.name} has no pole "
                                    f"angle to fall (set 0 or leave it out)")
        else:
            for pole in defaults.fallen_poles:
                bound(names.index(pole), -fall, fall,
                      Limit("fell", f"fall_angle {fall:.4g} rad", symmetric=True))

    for name, value in defaults.limits:
        if name in names and cfg.joint_limits:
            unit = f" {units[names.index(name)]}" if units[names.index(name)] else ""
            bound(names.index(name), -value, value,
                  Limit("joint_limit", f"the rig's stop at {value:g}{unit} (the domain's default "
                                       f"task)", symmetric=True))

    for name, value in cfg.state_bounds:
        if name not in names:
            raise ScenarioError(f"{where}task.state_bounds: no state named {name!r} on plant "
                                f"{plant.name} (allowed: {allowed})")
        if not (value > 0.0):
            raise ScenarioError(f"{where}task.state_bounds.{name}: must be > 0, got {value!r}")
        j = names.index(name)
        unit = f" {units[j]}" if units[j] else ""
        bound(j, -value, value, Limit("state_bound", f"task.state_bounds.{name} = {value:g}{unit}",
                                      symmetric=True))

    from tspend.task.constraints import build_constraints

    # the domain's default constraints: every bound so far but the fall angle
    own = []
    for j in range(N):
        limit = hi_limits[j] or lo_limits[j]
        if limit is not None and limit.status != "fell":
            own.append((j, float(lo[j]), float(hi[j]), limit.status))
    constraints = build_constraints(plant, cfg.constraints, effects, own, where.rstrip(": "))
    for name, box in cfg.constraints.boxes:
        if box.hard:
            j = names.index(name)  # build_constraints refused a hard box on anything else
            unit = f" {units[j]}" if units[j] else ""
            bound(j, box.lo, box.hi, Limit("constraint", f"task.constraints.box.{name} "
                                                         f"[{box.lo:g}, {box.hi:g}]{unit}"))

    return Task(names=names, units=units, view=view,
                view_index=np.array([names.index(v) for v in view], dtype=np.intp),
                lo=lo, hi=hi, lo_limits=tuple(lo_limits), hi_limits=tuple(hi_limits),
                reference=reference, disturbance=disturbance, constraints=constraints)
