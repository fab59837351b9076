"""Plant domains and kinds: the one map from a scenario's ``plant.kind`` to its domain.

Each domain lives in its own module under ``tspend/plants/`` (:mod:`.cartpole`,
:mod:`.furuta`, the paper's chains in :mod:`.analytic`) and declares its plant kinds,
each with its configuration class and builder (:class:`~tspend.plants.domain.Domain`).
A new domain is one module and one entry in :data:`DOMAINS`; nothing else names it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from tspend.config import PlantConfig
from tspend.plants import analytic, cartpole, furuta
from tspend.plants.base import Plant
from tspend.plants.domain import Domain, Drawing

if TYPE_CHECKING:
    from tspend.config import Scenario

__all__ = ["DOMAINS", "PLANT_KINDS", "PlantKind", "build", "domain_of", "drawing", "reset",
           "resolve_model_path"]

#: domain name -> domain
DOMAINS: dict[str, Domain] = {d.name: d for d in (*analytic.DOMAINS, cartpole.DOMAIN,
                                                    furuta.DOMAIN)}


@dataclass(frozen=True)
class PlantKind:
    """One plant kind: its domain, the order of its task's view, its configuration class
    and its builder."""

    domain: Domain
    order: int
    config: type[PlantConfig]
    build: Callable[[PlantConfig, Path], Plant]
    #: True when the kind steps an MJCF
    mujoco: bool = False


#: plant kind -> its domain, order, configuration class and builder
PLANT_KINDS: dict[str, PlantKind] = {
    kind: PlantKind(d, d.order, backend.config, backend.build, backend.mujoco)
    for d in DOMAINS.values() for kind, backend in d.kinds.items()}


def domain_of(kind: str) -> Domain:
    """The domain of plant kind ``kind`` (KeyError for an unknown kind)."""
    return PLANT_KINDS[kind].domain


def resolve_model_path(scenario: "Scenario") -> Path:
    """The MJCF of a scenario's domain (:meth:`Domain.model_path`)."""
    return domain_of(scenario.plant.kind).model_path(scenario)


def build(scenario: "Scenario", kind: str | None = None) -> Plant:
    """The scenario's plant, or the same machine on backend ``kind`` of its domain, not yet
    reset.  The ODE of a MuJoCo scenario is the compiled model's, so both backends
    describe one machine."""
    return domain_of(scenario.plant.kind).build(scenario, kind)


def drawing(plant: Plant, scenario: "Scenario") -> Drawing | None:
    """What a recorder draws of ``plant`` (None: nothing in 3D)."""
    return domain_of(scenario.plant.kind).drawing(plant, scenario)


def reset(plant: Plant, scenario: "Scenario") -> Plant:
    plant.reset(np.asarray(scenario.plant.x0, dtype=float))
    return plant
