"""What the full-state controller kinds (``lqr`` with ``design = "full"``, ``mpc``,
``swingup``) know of a plant: its domain's :class:`~tspend.plants.domain.FullModel`
(the equations, the energy, which joint is driven and which is the pendulum), bounded by
what the scenario sets.

The runner hands the nominal machine (:func:`tspend.loop.simulation.nominal_machine`);
its domain supplies the equations (:meth:`tspend.plants.domain.Domain.full_model`: those
derived from the MJCF for every MuJoCo machine, the paper's (C1)-(C2) for
``cartpole_ode``);
this module adds the bounds, generically:

* the input's range: the plant's actuator (``plant.inputs``), tightened by
  ``effects.saturation``;
* the positions' ranges: every bound the task ends a run on, except the fall angle (a
  limited joint's range, the rail ``effects.rail``, ``task.state_bounds`` on a position).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

from tspend.runtime.errors import ScenarioError
from tspend.plants.domain import FULL_STATE, FD_STEP, FullModel, wrap_angle

if TYPE_CHECKING:
    from tspend.config import Scenario
    from tspend.plants.base import Plant
    from tspend.task.constraints import ConstraintSet

__all__ = ["FullModel", "full_model", "full_model_and_constraints", "has_full_state",
           "wrap_angle", "FD_STEP"]


def full_model(scenario: "Scenario", machine: "Plant") -> FullModel:
    """The full-state model of the scenario's plant on ``machine`` (the nominal machine
    the runner built, :func:`tspend.loop.simulation.nominal_machine`) with the actuator's
    range, the rail, the joints' ranges and the task's state bounds on positions as its
    bounds."""
    return full_model_and_constraints(scenario, machine)[0]


def full_model_and_constraints(scenario: "Scenario",
                               machine: "Plant") -> "tuple[FullModel, ConstraintSet]":
    """:func:`full_model` and the run's constraint set (the task's ``constraints``, the
    one ``Observation.constraints`` carries) of the nominal ``machine`` and its task."""
    from tspend.plants import registry
    from tspend.task import build_task

    if machine is None:
        raise TypeError("full_model: the kind designs on a model: pass the nominal machine")
    kind = scenario.plant.kind
    domain = registry.domain_of(kind)
    model = domain.full_model(scenario, machine) if FULL_STATE in domain.provides else None
    if model is None:
        raise ScenarioError(f"{scenario.path}: plant '{kind}' (domain {domain.name}) has no "
                            f"full-state model to design on")
    plant = machine
    u_lo, u_hi = (plant.inputs[0].lo, plant.inputs[0].hi) if plant.inputs else (-math.inf, math.inf)
    effects = scenario.effects
    if effects.saturation > 0.0:
        u_lo, u_hi = max(u_lo, -effects.saturation), min(u_hi, effects.saturation)
    task = build_task(plant, scenario.task, effects, where=str(scenario.path))
    dof = model.dof
    q_lo, q_hi = [-math.inf] * dof, [math.inf] * dof
    for j in range(dof):
        if task.lo_limits[j] is not None and task.lo_limits[j].status != "fell":
            q_lo[j] = float(task.lo[j])
        if task.hi_limits[j] is not None and task.hi_limits[j].status != "fell":
            q_hi[j] = float(task.hi[j])
    return (replace(model, u_lo=u_lo, u_hi=u_hi, q_lo=tuple(q_lo), q_hi=tuple(q_hi)),
            task.constraints)


def has_full_state(scenario: "Scenario") -> bool:
    """Whether the scenario's domain provides a full-state model."""
    from tspend.plants.registry import domain_of

    return FULL_STATE in domain_of(scenario.plant.kind).provides
