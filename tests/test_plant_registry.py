"""The plant registry (issue 9): one typed configuration per kind, read by the validating
reader; the recorder gets a typed drawing object."""

from __future__ import annotations


import pytest

from tspend import load_scenario, override
from tspend.config import AnalyticPlantConfig
from tspend.plants.drawing.model import ModelDrawing
from tspend.plants.cartpole import CartPoleConfig, MujocoCartPoleConfig
from tspend.runtime.errors import ScenarioError
from tspend.plants.registry import PLANT_KINDS
from tspend.loop.simulation import build_plant, run_info


def test_each_kind_has_its_own_configuration() -> None:
    assert PLANT_KINDS["duffing"].config is AnalyticPlantConfig
    assert PLANT_KINDS["cartpole_ode"].config is CartPoleConfig
    assert PLANT_KINDS["cartpole_mujoco"].config is MujocoCartPoleConfig
    assert type(load_scenario("ex2_duffing").plant) is AnalyticPlantConfig
    assert type(load_scenario("ex3_pendulum_ode").plant) is CartPoleConfig
    assert type(load_scenario("pendulum_mujoco").plant) is MujocoCartPoleConfig


@pytest.mark.parametrize("scenario, key, value, words", [
    ("ex2_duffing", "plant.M", 3.0, "unknown key; allowed for plant kind 'duffing': kind, x0, state_bound"),
    ("ex3_pendulum_ode", "plant.model", "x.xml", "unknown key; allowed for plant kind 'cartpole_ode'"),
    ("pendulum_mujoco", "plant.timestep", -1.0, "plant.timestep: must be >= 0"),
    ("pendulum_mujoco", "plant.integrator", "RK5", "'RK5' is not allowed (did you mean 'RK4'?)"),
    ("pendulum_mujoco", "plant.override_inertials", 1, "must be true or false"),
    ("pendulum_mujoco", "plant.cart_damping", -1.0, "plant.cart_damping: must be >= 0"),
    ("pendulum_mujoco", "controller.gain_sign", "up", "allowed: plant, positive, negative"),
    ("pendulum_mujoco", "effects.noise_std", [0.1], "effects.noise_std: must have 2 entries"),
    ("pendulum_mujoco", "effects.delay", -1, "effects.delay: must be >= 0"),
    ("pendulum_mujoco", "effects.change", {"at": 1.0, "mass": 2.0}, "effects.change.mass: unknown key"),
    ("pendulum_mujoco", "effects.outer_loop", {"tau": 0.0}, "effects.outer_loop.tau: must be > 0"),
])
def test_plant_and_effect_keys_are_validated(scenario, key, value, words) -> None:
    with pytest.raises(ScenarioError, match=None) as info:
        override(load_scenario(scenario), **{key: value})
    assert words in str(info.value), str(info.value)


def test_the_recorder_gets_a_typed_drawing() -> None:
    scn = load_scenario("pendulum_mujoco")
    info = run_info(scn, build_plant(scn), 10)
    assert isinstance(info.drawing, ModelDrawing) and info.drawing.title == "cart-pole"
    assert info.drawing.machine.where.endswith("models/cartpole.xml")
    assert info.drawing.positions == {"slider": "cart_pos"}   # the cart posed by its extra
    ode = load_scenario("ex3_pendulum_ode")   # the paper's machine, drawn from its MJCF too
    assert isinstance(run_info(ode, build_plant(ode), 10).drawing, ModelDrawing)
    duffing = load_scenario("ex2_duffing")
    assert run_info(duffing, build_plant(duffing), 10).drawing is None
