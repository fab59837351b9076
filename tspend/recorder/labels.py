"""Physical names and units of a plant's states, control and extras, for axes and legends.

Each plant domain names its own (:attr:`tspend.plants.domain.Domain.labels`); a kind not
registered gets the paper's generic ``x1 .. xn`` without units.
"""

from __future__ import annotations

from tspend.plants.domain import PlantLabels, Quantity
from tspend.plants.registry import PLANT_KINDS

__all__ = ["PlantLabels", "Quantity", "extra_quantity", "plant_labels"]


def plant_labels(plant_kind: str, order: int, input_unit: str = "") -> PlantLabels:
    """The labels of ``plant_kind``'s domain, padded to ``order`` states with ``x<i>``;
    ``input_unit`` (the plant's own, from its model: N on a slide, N m on a hinge, V for a
    motor with back-EMF) replaces the domain's unit of ``u`` when given."""
    kind = PLANT_KINDS.get(plant_kind)
    found = kind.domain.labels if kind is not None else PlantLabels((), Quantity("u", "", "control"), {})
    if input_unit:
        found = found._replace(control=found.control._replace(unit=input_unit))
    return found.padded(order)


def extra_quantity(labels: PlantLabels, name: str) -> Quantity:
    return labels.extra(name)
