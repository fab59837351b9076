"""Physical names and units of a plant's states, control and extras, for axes and legends.

A plant kind names its states here (:data:`PLANT_LABELS`); a kind not listed gets the
paper's generic ``x1 .. xn`` without units.  Matching is on the kind's family
(``cartpole_mujoco`` and ``cartpole_ode`` are both cart-poles).
"""

from __future__ import annotations

from typing import NamedTuple


class Quantity(NamedTuple):
    """One physical quantity as plotted: short symbol, unit, and what it is."""

    symbol: str
    unit: str = ""
    meaning: str = ""

    def with_unit(self, text: str | None = None) -> str:
        """``"theta (rad)"``, or ``text`` with this quantity's unit."""
        text = self.symbol if text is None else text
        return f"{text} ({self.unit})" if self.unit else text


class PlantLabels(NamedTuple):
    """The states x_1 .. x_n, the control and the extras of one plant family."""

    states: tuple[Quantity, ...]
    control: Quantity
    extras: dict[str, Quantity]


_CARTPOLE = PlantLabels(
    states=(Quantity("theta", "rad", "pole angle"), Quantity("theta'", "rad/s", "pole angular velocity")),
    control=Quantity("u", "N", "force on the cart"),
    extras={"cart_pos": Quantity("x_c", "m", "cart position"),
            "cart_vel": Quantity("x_c'", "m/s", "cart velocity")},
)

#: plant family (the kind up to its first "_" backend suffix) -> labels
PLANT_LABELS: dict[str, PlantLabels] = {
    "cartpole": _CARTPOLE,
    "pendulum": _CARTPOLE,
    "duffing": PlantLabels((Quantity("x", "", "Duffing position"), Quantity("x'", "", "Duffing velocity")),
                           Quantity("u", "", "forcing control"), {}),
    "nonaffine": PlantLabels((Quantity("x1", "", "state"), Quantity("x2", "", "state")),
                             Quantity("u", "", "control"), {}),
}


def plant_labels(plant_kind: str, order: int) -> PlantLabels:
    """The labels of ``plant_kind``, padded to ``order`` states with ``x<i>``."""
    kind = plant_kind.lower().replace("-", "_")
    found = next((labels for family, labels in PLANT_LABELS.items()
                  if kind == family or kind.startswith(family)), None)
    if found is None:
        found = PlantLabels((), Quantity("u", "", "control"), {})
    states = tuple(found.states[:order]) + tuple(Quantity(f"x{i + 1}") for i in range(len(found.states), order))
    return PlantLabels(states, found.control, found.extras)


def extra_quantity(labels: PlantLabels, name: str) -> Quantity:
    return labels.extras.get(name, Quantity(name))
