"""Constraints of a task: boxes and linear inequalities over a plant's named states and input.

Every constraint is a few rows of one linear inequality over ``z = [s, u]`` (the full state
``s`` in the plant's ``state_names`` order, then the input ``u``)::

    A z <= b                                                                    (C1)

and its *margin* at a sample is ``min_rows (b - A z)`` (its unit: the constrained
quantity's; negative outside).  A box ``lo <= v <= hi`` is the two rows ``v <= hi`` and
``-v <= -lo``; a linear constraint ``min <= sum c_i v_i <= max`` the two rows of its sum.

Where they come from (``[task.constraints]``, :class:`tspend.config.ConstraintsConfig`):

* the domain's defaults (``defaults = true``): every bound the task ends a run on except
  the fall angle (the rail ``rail``, a joint's range ``<joint>_range``, the rig's stop,
  ``task.state_bounds`` as ``<state>_bound``), *hard*; the actuator's range, tightened by
  ``effects.saturation``, as ``<input>_range``, *soft* (the actuator clips the command;
  a command outside is counted);
* ``[task.constraints.box] NAME = {lo, hi, hard}`` on a state or the input;
* ``[task.constraints.linear] LABEL = {terms = {NAME = c, ..}, min, max}``.

A hard constraint ends the run as the task's other bounds do (status ``constraint``; only
a state's box can be hard, so the compiled loops' one bound check covers it); a soft one
is measured (:mod:`tspend.loop.metrics`: samples outside, time outside, largest depth,
smallest margin).  A controller sees the set as ``Observation.constraints``; the safety
filter (:mod:`tspend.controllers.safety`) keeps the state ones invariant.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, TYPE_CHECKING

import numpy as np

from tspend.config import ConstraintsConfig, EffectsConfig
from tspend.runtime.errors import ScenarioError

if TYPE_CHECKING:
    from tspend.plants.base import Plant

__all__ = ["Constraint", "ConstraintSet", "build_constraints", "OUTSIDE_TOLERANCE", "U_ALIAS"]

#: the input may always be named ``u`` besides its own name (``force``, ``motor``)
U_ALIAS = "u"

#: a sample is outside a constraint only when its margin is below ``-OUTSIDE_TOLERANCE x
#: (1 + the constraint's largest |b|)`` (1e-9 of a 2000 N range: 2e-6 N): a solver's
#: rounding (a force 1.6e-10 N past its range) is not a violation (docs/safety.md)
OUTSIDE_TOLERANCE = 1e-9


@dataclass(frozen=True, eq=False)
class Constraint:
    """``A [s, u] <= b`` (C1): one named constraint of one or more rows."""

    name: str
    A: np.ndarray
    b: np.ndarray
    hard: bool
    unit: str = ""
    #: where it was declared, for messages ("the rail (effects.rail)", "task.constraints.box.x")
    source: str = ""

    def __post_init__(self) -> None:
        # a controller is handed these: none may change what the run is measured against
        for a in (self.A, self.b):
            a.flags.writeable = False

    @property
    def on_input(self) -> bool:
        """Whether any row involves the input (then no barrier: a bound on u itself)."""
        return bool(np.any(self.A[:, -1] != 0.0))

    def margin(self, state: np.ndarray, u: float) -> float:
        """``min (b - A [s, u])``: > 0 inside, < 0 outside (NaN stays NaN)."""
        z = np.append(np.asarray(state, dtype=float), float(u))
        return float(np.min(self.b - self.A @ z))


@dataclass(frozen=True, eq=False)
class ConstraintSet:
    """The task's constraints over ``names`` (the full state's, then the input's)."""

    names: tuple[str, ...]
    constraints: tuple[Constraint, ...]
    #: every row stacked (R, N+1), (R,), and the constraint each row belongs to
    A: np.ndarray = field(init=False)
    b: np.ndarray = field(init=False)
    owner: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        N1 = len(self.names)
        rows = [c.A for c in self.constraints]
        object.__setattr__(self, "A", np.vstack(rows) if rows else np.zeros((0, N1)))
        object.__setattr__(self, "b", np.concatenate([c.b for c in self.constraints])
                           if rows else np.zeros(0))
        object.__setattr__(self, "owner", np.repeat(np.arange(len(rows), dtype=np.intp),
                                                    [c.A.shape[0] for c in self.constraints]))
        for a in (self.A, self.b):
            a.flags.writeable = False

    def __len__(self) -> int:
        return len(self.constraints)

    @property
    def tolerances(self) -> np.ndarray:
        """(C,): each constraint's :data:`OUTSIDE_TOLERANCE` in its own unit."""
        return np.array([OUTSIDE_TOLERANCE * (1.0 + float(np.abs(c.b).max(initial=0.0)))
                         for c in self.constraints])

    def __iter__(self):
        return iter(self.constraints)

    def __getitem__(self, name: str) -> Constraint:
        for c in self.constraints:
            if c.name == name:
                return c
        raise KeyError(f"no constraint named {name!r} (constraints: "
                       f"{', '.join(c.name for c in self.constraints) or 'none'})")

    @property
    def constraint_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.constraints)

    def margins(self, states: np.ndarray, u: np.ndarray, xp: Any = np) -> np.ndarray:
        """(k, C): every constraint's margin (C1) at each of k samples of full state
        ``states`` (k, N) and input ``u`` (k,), in the array namespace ``xp`` (numpy, or
        jax.numpy on the accelerator: one text for both backends)."""
        if xp is np:
            states = np.atleast_2d(np.asarray(states, dtype=float))
            u = np.asarray(u, dtype=float).reshape(-1)
        Z = xp.concatenate([states, u[:, None]], axis=1)
        slack = xp.asarray(self.b)[None, :] - Z @ xp.asarray(self.A).T      # (k, R)
        # each constraint's margin: the least slack of its rows (+inf: a constraint of none)
        rows = np.arange(len(self.constraints))[:, None] == self.owner[None, :]  # (C, R)
        return xp.min(xp.where(xp.asarray(rows)[None, :, :], slack[:, None, :], xp.inf),
                      axis=2, initial=xp.inf)

    def violated(self, state: np.ndarray, u: float) -> tuple[str, ...]:
        """The names of the constraints outside at one sample (beyond the tolerance)."""
        m = self.margins(state[None, :], np.array([u]))[0]
        return tuple(c.name for c, v, tol in zip(self.constraints, m, self.tolerances)
                     if v < -tol)


def build_constraints(plant: "Plant", cfg: ConstraintsConfig, effects: EffectsConfig,
                      bounds: list[tuple[int, float, float, str]], where: str = "") -> ConstraintSet:
    """The task's constraints on ``plant`` (module docstring).

    ``bounds`` are the task's own (state index, lo, hi, status) before any hard box of
    ``cfg`` is added, the fall angle left out: the domain's defaults.

    Raises ScenarioError (one line naming ``where``, the key and the allowed names) for a
    name the plant does not have, a hard box on the input, or two constraints of one name.
    """
    where = f"{where}: " if where else ""
    states, units = tuple(plant.state_names), tuple(plant.state_units)
    inp = plant.inputs[0] if plant.inputs else None
    u_name = inp.name if inp is not None else U_ALIAS
    names = states + (u_name,)
    N1 = len(names)
    allowed = ", ".join(states + ((u_name, U_ALIAS) if u_name != U_ALIAS else (U_ALIAS,)))

    def index(name: str, key: str) -> int:
        if name == U_ALIAS or name == u_name:
            return N1 - 1
        if name in states:
            return states.index(name)
        raise ScenarioError(f"{where}{key}: no state or input named {name!r} on plant "
                            f"{plant.name} (allowed: {allowed})")

    def box(name: str, j: int, lo: float, hi: float, hard: bool, source: str) -> Constraint:
        A, b = [], []
        if math.isfinite(hi):
            row = np.zeros(N1)
            row[j] = 1.0
            A.append(row)
            b.append(hi)
        if math.isfinite(lo):
            row = np.zeros(N1)
            row[j] = -1.0
            A.append(row)
            b.append(-lo)
        unit = units[j] if j < len(units) else (inp.unit if inp is not None else "")
        return Constraint(name, np.array(A), np.array(b, dtype=float), hard, unit, source)

    out: list[Constraint] = []
    if cfg.defaults:
        for j, lo, hi, status in bounds:
            name = {"rail_end": "rail", "state_bound": f"{states[j]}_bound"}.get(
                status, f"{states[j]}_range")
            out.append(box(name, j, lo, hi, True, f"the task's {status} bound"))
        if inp is not None:
            lo, hi = inp.lo, inp.hi
            if effects.saturation > 0.0:
                lo, hi = max(lo, -effects.saturation), min(hi, effects.saturation)
            if math.isfinite(lo) or math.isfinite(hi):
                out.append(box(f"{u_name}_range", N1 - 1, lo, hi, False, "the actuator's range"))
    for name, spec in cfg.boxes:
        key = f"task.constraints.box.{name}"
        j = index(name, key)
        if spec.hard and j == N1 - 1:
            raise ScenarioError(f"{where}{key}.hard: a box on the input cannot be hard (the "
                                f"actuator clips u; a soft box is measured and kept by the "
                                f"safety filter); allowed: false")
        out.append(box(name, j, spec.lo, spec.hi, spec.hard, key))
    for label, spec in cfg.linear:
        key = f"task.constraints.linear.{label}"
        a = np.zeros(N1)
        for name, coefficient in spec.terms:
            a[index(name, f"{key}.terms.{name}")] += coefficient
        A, b = [], []
        if math.isfinite(spec.hi):
            A.append(a)
            b.append(spec.hi)
        if math.isfinite(spec.lo):
            A.append(-a)
            b.append(-spec.lo)
        out.append(Constraint(label, np.array(A), np.array(b, dtype=float), False, "", key))
    seen: set[str] = set()
    for c in out:
        if c.name in seen:
            raise ScenarioError(f"{where}task.constraints: two constraints are named {c.name!r} "
                                f"(the domain's defaults: "
                                f"{', '.join(x.name for x in out if 'task.' not in x.source)}); "
                                f"rename one or set task.constraints.defaults = false")
        seen.add(c.name)
    return ConstraintSet(names, tuple(out))
