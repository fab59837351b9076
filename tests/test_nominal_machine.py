"""Controllers are handed the nominal machine: the runner builds the plant that runs once
and, for a kind that designs on a model, the nominal machine once (issue 43); no
controller builds a plant of its own.

Counted at the plant kind's own builder (the domain's Backend), so every route that
constructs a plant of that kind is seen, whoever asks for it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import tspend
from tspend.plants.registry import domain_of


@pytest.fixture
def built(monkeypatch):
    """Every cart-pole plant built (``cartpole_mujoco``), in order."""
    domain = domain_of("cartpole_mujoco")
    backend = domain.kinds["cartpole_mujoco"]
    plants = []

    def counting(cfg, path):
        plant = backend.build(cfg, path)
        plants.append(plant)
        return plant

    monkeypatch.setitem(domain.kinds, "cartpole_mujoco", replace(backend, build=counting))
    return plants


def test_lqr_run_builds_one_plant_and_one_nominal_machine(built):
    result = tspend.run("pendulum_mujoco", controller="lqr", duration=0.05)
    assert result.status == "completed"
    # one for the plant that runs, one nominal machine for the controller to design on
    assert len(built) == 2, f"{len(built)} plant builds"
    assert built[0] is result.plant or getattr(result.plant, "plant", None) is built[0]


def test_a_kind_without_a_model_builds_no_nominal_machine(built):
    result = tspend.run("pendulum_mujoco", controller="second_type", duration=0.05)
    assert result.status == "completed"
    assert len(built) == 1, f"{len(built)} plant builds"


def test_the_controller_designs_on_the_nominal_machine_not_the_draw(built, monkeypatch):
    from tspend.loop import simulation

    handed = []
    real = simulation.build_controller_kind

    def spy(scenario, kind, machine):
        handed.append(machine)
        return real(scenario, kind, machine)

    monkeypatch.setattr(simulation, "build_controller_kind", spy)
    result = tspend.run("pendulum_mujoco_randomized", controller="lqr", seed=3, duration=0.05)
    (machine,) = handed
    runs = built[0] if built[0] is result.plant else getattr(result.plant, "plant", result.plant)
    nominal, drawn = machine.params, runs.params
    # the file's machine (models/cartpole.xml: M = 10, m = 1, l = 3) against the draw
    assert (nominal.M, nominal.m, nominal.l) == (10.0, 1.0, 3.0)
    assert not np.allclose((drawn.M, drawn.m, drawn.l), (10.0, 1.0, 3.0))
