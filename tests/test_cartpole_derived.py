"""The MuJoCo cart-pole's controller-side equations come from the derivation (issue 32).

The hand-written (C1)-(C2) of tspend/studies/cartpole_greybox.py (the grey-box model
identification fits) are the oracle: the equations derived from the compiled
models/cartpole.xml, with the same numbers written into it, give the same accelerations
at random states; the derived linearisation is the hand-written one's central
difference; the ODE twin applies d as the MuJoCo plant does, and steps the same on the
compiled and the generic loop.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tspend import load_scenario, override
from tspend.loop.simulation import run
from tspend.plants.cartpole import (DOMAIN, _nominal, DerivedCartPoleODE, cartpole_machine,
                                    nominal_machine)
from tspend.studies.cartpole_greybox import (inverse_dynamics, machine_accelerations, machine_of,
                                             pole_energy)
from tspend.plants.cartpole import MujocoCartPole

from cli_harness import ROOT

MODEL = ROOT / "models" / "cartpole.xml"

#: (overrides, gear, damping and dry friction): the paper's machine, a heavier pole with
#: its own inertia and a geared motor, a light short one with damped joints and friction
MACHINES = [
    ({}, None, {}),
    ({"M": 4.0, "m": 2.5, "l": 0.7, "J": 1.9}, 3.5, {}),
    ({"M": 1.3, "m": 0.2, "l": 0.35, "g": 9.81}, 0.5,
     {"cart_damping": 0.8, "hinge_damping": 0.03, "cart_friction": 1.5, "hinge_friction": 0.02}),
]


@pytest.mark.parametrize("overrides, gear, friction", MACHINES)
def test_the_hand_written_equations_are_the_oracle_of_the_derived_ones(
        overrides, gear, friction) -> None:
    """1,000 random states: both angles over the full circle, rates to 20 rad/s (m/s),
    the cart anywhere on 10 m, u over 1.2 x the control range (the clip included), a
    disturbance: the ODE twin's derived accelerations (its smooth dry friction included)
    and the hand-written ones within 1e-12 (relative where larger than 1)."""
    plant = MujocoCartPole(MODEL, overrides=overrides, gear=gear, **friction)
    machine = cartpole_machine(plant)
    assert machine is not None
    ode = DerivedCartPoleODE(plant)
    oracle = machine_of(plant.params)
    lo, hi = plant.inputs[0].lo, plant.inputs[0].hi
    rng = np.random.default_rng(32)
    sdot, worst = np.empty(4), 0.0
    for _ in range(1000):
        s = np.array([rng.uniform(-5.0, 5.0), rng.uniform(-math.pi, math.pi),
                      rng.uniform(-20.0, 20.0), rng.uniform(-20.0, 20.0)])
        u, d = rng.uniform(1.2 * lo, 1.2 * hi), rng.uniform(-5.0, 5.0)
        ode.rhs_into(0.0, s, u, d, sdot)
        q_dd, x_dd = machine_accelerations(oracle, s[1], s[3], s[0], s[2], u, d)
        theirs = np.array([x_dd, q_dd])
        worst = max(worst, float(np.max(np.abs(sdot[2:] - theirs) / np.maximum(1.0, np.abs(theirs)))))
    print(f"cartpole {overrides} gear {gear}: derived vs hand-written, worst {worst:.1e}")
    assert worst <= 1e-12


def test_the_controllers_models_are_the_nominal_derived_machine() -> None:
    """pendulum_friction: the view's model, the full model, the linearisation leave the
    damping and dry friction out as the hand-written nominal machine does; the
    linearisation is exact (the hand-written one's central difference agrees to 1e-7)."""
    scn = load_scenario("pendulum_friction")
    plant = DOMAIN.build(scn)
    assert plant.params.cart_damping > 0 or plant.params.cart_friction > 0
    machine_ = DOMAIN.build(scn)   # the nominal machine the runner hands a controller
    nominal = machine_of(_nominal(machine_.params))
    view = DOMAIN.plant_model(scn, machine_)
    full = DOMAIN.full_model(scn, machine_)
    rng = np.random.default_rng(3)
    for _ in range(200):
        x = np.array([rng.uniform(-math.pi, math.pi), rng.uniform(-20.0, 20.0)])
        u, d = rng.uniform(-50.0, 50.0), rng.uniform(-1.0, 1.0)
        want = machine_accelerations(nominal, x[0], x[1], 0.0, 0.0, u, d)[0]
        assert view.accel(0.0, x, u, d) == pytest.approx(want, rel=1e-12, abs=1e-12)
        s = np.array([rng.uniform(-5, 5), x[0], rng.uniform(-20, 20), x[1]])
        q_dd, x_dd = machine_accelerations(nominal, s[1], s[3], s[0], s[2], u, 0.0)
        np.testing.assert_allclose(full.numeric(s, u), (x_dd, q_dd), rtol=1e-12, atol=1e-12)
        # the swing-up's energy of the pole
        assert full.energy(s) == pytest.approx(pole_energy(nominal, s[1], s[3]), rel=1e-12,
                                               abs=1e-12)
    A, B = DOMAIN.linearisation(scn, machine_)
    h = 1e-6
    A_fd, B_fd = np.zeros((4, 4)), np.zeros((4, 1))

    def f(s, u):
        q_dd, x_dd = machine_accelerations(nominal, s[1], s[3], s[0], s[2], u, 0.0)
        return np.array([s[2], s[3], x_dd, q_dd])

    for k in range(4):
        e = np.zeros(4)
        e[k] = h
        A_fd[:, k] = (f(e, 0.0) - f(-e, 0.0)) / (2 * h)
    B_fd[:, 0] = (f(np.zeros(4), h) - f(np.zeros(4), -h)) / (2 * h)
    np.testing.assert_allclose(A, A_fd, rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(B, B_fd, rtol=1e-7, atol=1e-9)
    # the nominal machine keeps the model's numbers but its dampers
    machine = cartpole_machine(plant)
    kept = nominal_machine(machine)
    for name, a, b in zip(machine.parameter_names, machine.p, kept.p):
        assert b == (0.0 if name.endswith(".damping") else a), name


def _hand_reference_force(p, scn) -> tuple[float, float, float]:
    """The task check's need from the hand-written inverse dynamics (the oracle)."""
    from tspend.task.feasibility import NEED_SAMPLES

    n = int(min(NEED_SAMPLES, max(2, round(scn.run.duration / scn.run.dt))))
    t = np.linspace(0.0, scn.run.duration, n + 1)
    r = scn.reference.derivatives(t, 2)
    d = np.asarray(scn.disturbance(t), dtype=float)
    force, v, hand = np.empty(n + 1), 0.0, machine_of(p)
    for k in range(n + 1):
        force[k], x_dd = inverse_dynamics(hand, r[k, 0], r[k, 1], r[k, 2], v, d[k])
        if k < n and math.isfinite(x_dd):
            v += x_dd * (t[k + 1] - t[k])
    k_lo, k_hi = int(np.argmin(force)), int(np.argmax(force))
    k = k_hi if abs(force[k_hi]) >= abs(force[k_lo]) else k_lo
    return float(t[k]), float(force[k_lo]), float(force[k_hi])


def test_the_ode_twin_and_the_task_check_are_derived_the_ode_scenario_too() -> None:
    scn = load_scenario("pendulum_mujoco")
    twin = DOMAIN.build(scn, "cartpole_ode")
    assert isinstance(twin, DerivedCartPoleODE)
    assert twin.parameters() == DOMAIN.build(scn).parameters()
    # the paper's Example 3 on cartpole_ode: models/cartpole.xml's derived equations with
    # the scenario's numbers written into the model
    ex3 = load_scenario("ex3_pendulum_ode")
    assert isinstance(DOMAIN.build(ex3), DerivedCartPoleODE)
    # the task check's need, from the derived and the hand-written inverse dynamics, on
    # the same machine (with its damping and dry friction on pendulum_friction)
    from tspend.task.feasibility import reference_force

    for name in ("pendulum_mujoco", "pendulum_friction", "ex3_pendulum_ode"):
        scn = load_scenario(name)
        p = DOMAIN.build(scn).params
        derived = reference_force(p, scn, cartpole_machine(DOMAIN.build(scn)))
        hand = _hand_reference_force(p, scn)
        assert derived is not None
        np.testing.assert_allclose(derived, hand, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("name", ["pendulum_mujoco", "pendulum_friction"])
def test_the_ode_twin_runs_the_same_on_the_compiled_and_the_generic_loop(name, paths) -> None:
    """With the scenario's disturbance (the hinge torque -d m l / (M + m)) and dry
    friction, bit for bit."""
    s = override(load_scenario(name), **{"run.duration": 1.0})
    fast = run(s, controller="lqr", compiled=True, plant_kind="cartpole_ode")
    slow = run(s, controller="lqr", compiled=False, plant_kind="cartpole_ode")
    assert paths == ["compiled", "generic"]
    assert fast.status == slow.status == "completed"
    for key in ("u", "x", "state"):
        np.testing.assert_array_equal(fast.history[key], slow.history[key], err_msg=key)


def _third_party() -> list:
    # the parallel hinge is refused by the cart-pole itself (tests/test_mjcf_cartpoles.py)
    return [p for p in sorted((ROOT / "tests" / "models").glob("cartpole_*.xml"))
            if p.stem != "cartpole_parallel_hinge"] + \
        sorted((ROOT / "models" / "third_party").glob("*.xml"))


@pytest.mark.parametrize("model", _third_party(), ids=lambda p: p.stem)
def test_every_cartpole_derives_and_agrees_with_c1_c2(model) -> None:
    """The test models (tilted hinge, leaning COM, reversed axis, velocity, position and
    general actuators, a joint's actuatorfrcrange, contacts, dm_control's and gymnasium's):
    the derived equations against the hand-written oracle (C1)-(C2) at 200 random states
    (the general actuator's force clamped by its joint's range at many of them), the
    linearisation finite."""
    import warnings

    from tspend.plants.mujoco_plant import guess_names

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        slide, hinge, act = guess_names(model, None, None, None)
        plant = MujocoCartPole(model, slide, hinge, act)
    machine = cartpole_machine(plant)   # every one derives (actuatorfrcrange included)
    assert machine is not None, model
    ode = DerivedCartPoleODE(plant)
    oracle = machine_of(plant.params)
    lo, hi = plant.inputs[0].lo, plant.inputs[0].hi
    if not math.isfinite(lo):
        lo, hi = -50.0, 50.0
    rng = np.random.default_rng(5)
    sdot, worst = np.empty(4), 0.0
    for _ in range(200):
        s = np.array([rng.uniform(-1.0, 1.0), rng.uniform(-math.pi, math.pi),
                      rng.uniform(-20.0, 20.0), rng.uniform(-20.0, 20.0)])
        u, d = rng.uniform(1.2 * lo, 1.2 * hi), rng.uniform(-1.0, 1.0)
        ode.rhs_into(0.0, s, u, d, sdot)
        q_dd, x_dd = machine_accelerations(oracle, s[1], s[3], s[0], s[2], u, d)
        theirs = np.array([x_dd, q_dd])
        worst = max(worst, float(np.max(np.abs(sdot[2:] - theirs) / np.maximum(1.0, np.abs(theirs)))))
    assert worst <= 1e-12, (model.stem, worst)
    A, B = machine.linearisation()
    assert np.all(np.isfinite(A)) and np.all(np.isfinite(B))


@pytest.mark.parametrize("name", ["ex3_pendulum_ode", "pendulum_mujoco"])
def test_the_papers_example_3_equation_is_the_views_model_on_the_papers_machine(name) -> None:
    """The paper's own Example 3 ODE (tspend.plants.analytic.cartpole_accel, as printed)
    against the pole's equation the model-based kinds get on the paper's machine: the
    equations derived from models/cartpole.xml, the paper's numbers written into it
    (ex3_pendulum_ode) or its own (pendulum_mujoco)."""
    from tspend.plants.analytic import cartpole_accel

    scn = load_scenario(name)
    view = DOMAIN.plant_model(scn, DOMAIN.build(scn))
    rng = np.random.default_rng(43)
    for _ in range(300):
        x = np.array([rng.uniform(-1.4, 1.4), rng.uniform(-5.0, 5.0)])
        u, d = rng.uniform(-300.0, 300.0), rng.uniform(-0.1, 0.1)
        want = cartpole_accel(0.0, x, u, d)
        assert view.accel(0.0, x, u, d) == pytest.approx(want, rel=1e-12, abs=1e-12)


def test_a_cartpole_the_derivation_refuses_is_refused_in_one_line(tmp_path, capsys) -> None:
    """A cart-pole MJCF whose equations cannot be derived (gravity compensation on the
    pole) is refused when it is built, in one line naming the cause and what to change,
    exit 2; nothing falls back to hand-written equations."""
    from tspend.cli.main import main

    text = (ROOT / "models" / "cartpole.xml").read_text()
    assert '<body name="pole" pos="0 0 0.25">' in text
    model = tmp_path / "gravcomp.xml"
    model.write_text(text.replace('<body name="pole" pos="0 0 0.25">',
                                  '<body name="pole" pos="0 0 0.25" gravcomp="1">'))
    status = main(["run", "pendulum_mujoco", "--no-record", "--duration", "0.1",
                   "--set", f"plant.model={model}"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1, err
    assert "gravity compensation (gravcomp)" in err[0] and "change the model" in err[0]
