"""Plant kinds: each with its order, its typed configuration and its builder.

The scenario reader parses ``[plant]`` into the kind's configuration class (its fields
are exactly the allowed keys); :func:`build` makes the plant.  A new plant kind is one
entry here and one configuration class in :mod:`tspend.config`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from tspend.config import AnalyticPlantConfig, CartPoleConfig, MujocoCartPoleConfig, PlantConfig
from tspend.plants import analytic
from tspend.plants.base import CartPoleDrawing, Plant
from tspend.plants.cartpole import CartPoleParams

if TYPE_CHECKING:
    from tspend.config import Scenario


@dataclass(frozen=True)
class PlantKind:
    order: int
    config: type[PlantConfig]
    build: Callable[[PlantConfig, Path], Plant]


def cartpole_params(cfg: CartPoleConfig) -> CartPoleParams:
    """The machine a cart-pole configuration describes."""
    return CartPoleParams(M=cfg.M, m=cfg.m, l=cfg.l, g=cfg.g, J=cfg.J,
                          cart_damping=cfg.cart_damping, hinge_damping=cfg.hinge_damping,
                          cart_friction=cfg.cart_friction, hinge_friction=cfg.hinge_friction)


def _mujoco(cfg: PlantConfig, model_path: Path) -> Plant:
    from tspend.plants.mujoco_plant import MujocoCartPole  # MuJoCo only when asked for

    if not isinstance(cfg, MujocoCartPoleConfig):
        cfg = MujocoCartPoleConfig(**{k: getattr(cfg, k) for k in CartPoleConfig.__dataclass_fields__})
    friction = {k: (getattr(cfg, k) or None) for k in
                ("cart_damping", "hinge_damping", "cart_friction", "hinge_friction")}
    return MujocoCartPole(model_path, slide_joint=cfg.slide_joint, hinge_joint=cfg.hinge_joint,
                          actuator=cfg.actuator,
                          overrides=cartpole_params(cfg) if cfg.override_inertials else None,
                          integrator=cfg.integrator or None, timestep=cfg.timestep or None,
                          **friction)


def _ode(cfg: PlantConfig, model_path: Path) -> Plant:
    assert isinstance(cfg, CartPoleConfig)
    return analytic.cartpole_ode_plant(cartpole_params(cfg))


def _analytic(make: Callable[[], Plant]) -> Callable[[PlantConfig, Path], Plant]:
    return lambda cfg, model_path: make()


#: plant kind -> its order, configuration class and builder
PLANT_KINDS: dict[str, PlantKind] = {
    "nonaffine": PlantKind(2, AnalyticPlantConfig, _analytic(analytic.nonaffine_plant)),
    "duffing": PlantKind(2, AnalyticPlantConfig, _analytic(analytic.duffing_plant)),
    "third_order": PlantKind(3, AnalyticPlantConfig, _analytic(analytic.third_order_plant)),
    "cartpole_ode": PlantKind(2, CartPoleConfig, _ode),
    "cartpole_mujoco": PlantKind(2, MujocoCartPoleConfig, _mujoco),
}


def build(scenario: "Scenario", kind: str | None = None) -> Plant:
    """The scenario's plant, or the same machine on backend ``kind``, not yet reset.

    The ODE of a MuJoCo scenario is the compiled model's (masses, inertia, damping, gear
    and angle sign read back), so both backends describe one machine.
    """
    from tspend.scenario import resolve_model_path

    own = scenario.plant.kind
    kind = kind or own
    if kind == "cartpole_ode" and own == "cartpole_mujoco":
        mj = PLANT_KINDS[own].build(scenario.plant, resolve_model_path(scenario))
        return analytic.cartpole_ode_plant(mj.params, mj.cart_joints)  # type: ignore[attr-defined]
    return PLANT_KINDS[kind].build(scenario.plant, resolve_model_path(scenario))


def drawing(plant: Plant, scenario: "Scenario") -> CartPoleDrawing | None:
    """What a recorder draws of ``plant`` (None: nothing in 3D)."""
    params = getattr(plant, "params", None)
    if not isinstance(params, CartPoleParams):
        return None
    from tspend.scenario import resolve_model_path

    mjcf = str(resolve_model_path(scenario)) if hasattr(plant, "model") else ""
    return CartPoleDrawing(M=params.M, m=params.m, l=params.l, g=params.g, mjcf=mjcf,
                           theta_sign=params.theta_sign)


def reset(plant: Plant, scenario: "Scenario") -> Plant:
    plant.reset(np.asarray(scenario.plant.x0, dtype=float))
    return plant
