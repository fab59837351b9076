"""Plant domains and kinds: the one map from a scenario's ``plant.kind`` to its domain.

Each domain lives in its own module under ``tspend/plants/`` (:mod:`.cartpole`,
:mod:`.furuta`, the paper's chains in :mod:`.analytic`) and declares its plant kinds,
each with its configuration class and builder (:class:`~tspend.plants.domain.Domain`).
A new domain is one module and one entry in :data:`DOMAINS`; nothing else names it.
An installed package adds domains without touching tspend: it registers a
:class:`~tspend.plants.domain.Domain` (an instance or a class) under the entry-point
group ``tspend.plants`` (:func:`installed_domains`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from tspend.config import PlantConfig
from tspend.plants.drawing.base import Drawing
from tspend.plants import analytic, cartpole, furuta
from tspend.plants.articulated import domain as articulated
from tspend.plants.base import Plant
from tspend.plants.domain import Domain

if TYPE_CHECKING:
    from tspend.config import Scenario

__all__ = ["DOMAINS", "PLANT_KINDS", "PlantKind", "build", "domain_of", "drawing", "reset",
           "resolve_model_path"]

#: the entry-point group of installed plant domains (``name = "package.module:DOMAIN"``)
ENTRY_POINT_GROUP = "tspend.plants"


def installed_domains(builtin: tuple[Domain, ...]) -> tuple[Domain, ...]:
    """The domains installed packages register under ``tspend.plants``.

    A broken or clashing one is left out with a one-line warning, so that one bad package
    cannot stop every command.
    """
    import warnings

    from tspend.runtime.errors import ScenarioError
    from tspend.runtime import plugins

    taken = {kind for d in builtin for kind in d.kinds} | {d.name for d in builtin}
    found: list[Domain] = []
    for name in plugins.entry_point_names(ENTRY_POINT_GROUP):
        try:
            obj = plugins.load_entry_point(ENTRY_POINT_GROUP, name, f"[{ENTRY_POINT_GROUP}]")
            domain = obj() if isinstance(obj, type) and issubclass(obj, Domain) else obj
            if not isinstance(domain, Domain):
                raise ScenarioError(f"[{ENTRY_POINT_GROUP}] {name}: a {type(obj).__name__}, "
                                    f"not a tspend.plants.domain.Domain")
            clash = sorted(({domain.name} | set(domain.kinds)) & taken)
            if clash:
                raise ScenarioError(f"[{ENTRY_POINT_GROUP}] {name}: {', '.join(clash)} already "
                                    f"taken")
        except ScenarioError as exc:
            warnings.warn(f"plant plug-in left out: {exc}", stacklevel=2)
            continue
        taken |= {domain.name} | set(domain.kinds)
        found.append(domain)
    return tuple(found)


# the articulated domain last: it fits any hinge/slide MJCF, the hand-made domains first
_BUILTIN: tuple[Domain, ...] = (*analytic.DOMAINS, cartpole.DOMAIN, furuta.DOMAIN, articulated.DOMAIN)
#: domain name -> domain (the built-in ones, then the installed ones)
DOMAINS: dict[str, Domain] = {d.name: d for d in (*_BUILTIN, *installed_domains(_BUILTIN))}


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
