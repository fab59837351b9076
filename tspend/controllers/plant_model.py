"""What the model-based controller kinds know of the plant: its domain's model.

The baselines that use a model (``pd``'s nominal gain, ``lqr``, ``sliding_mode``'s nominal
model, the ``feedback_linearization`` oracle, ``wang_indirect``'s initial gain) ask the
scenario's plant domain (:meth:`tspend.plants.domain.Domain.plant_model`): the dynamics
are written once, in the domain's module, and the derived quantities (``df/du``, the
linearisation at the operating point by central differences) are
:class:`~tspend.plants.domain.PlantModel`'s.  Nothing here names a plant.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from tspend.plants.domain import FD_STEP, PlantModel
from tspend.plants.registry import domain_of

if TYPE_CHECKING:
    from tspend.config import Scenario
    from tspend.plants.base import Plant

__all__ = ["FD_STEP", "PlantModel", "plant_model"]


def plant_model(scenario: "Scenario", machine: "Plant") -> PlantModel:
    """The model of the scenario's plant (every kind the scenario loader accepts) on
    ``machine``, the nominal machine the runner built
    (:func:`tspend.loop.simulation.nominal_machine`)."""
    if machine is None:
        raise TypeError("plant_model: the kind designs on a model: pass the nominal machine")
    return domain_of(scenario.plant.kind).plant_model(scenario, machine)
