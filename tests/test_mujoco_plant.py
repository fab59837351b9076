"""The MuJoCo cart-pole reproduces Example 3's ODE (docs/paper-notes.md section 7).

The oracle is ``solve_ivp`` (DOP853, rtol 1e-12) restarted over each 1 ms sample with u
and d held: independent of both MuJoCo and tspend's own RK4.  The runs are open loop,
so the pole falls and spins; both models are exact rigid-body models, so they must
agree anyway.
"""

from __future__ import annotations

import dataclasses
import math
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from cartpole_oracle import ReferenceCartPole
from tspend.studies.crosscheck_openloop import OpenLoopComparison, chirp_force, open_loop_compare
from tspend.config.signals import SquareWave

_SQUARE = SquareWave(amplitude=0.05)


def square_disturbance(t: float) -> float:
    """The paper's +/-0.05 square wave of period 2 pi, at one time."""
    return float(_SQUARE(np.array([t]))[0])
from tspend.runtime.errors import DivergenceError, ScenarioError
from cartpole_oracle import CartPoleParams, cartpole_ode_plant
from tspend.plants.base import Plant
from tspend.plants.cartpole import MujocoCartPole

MODEL = Path(__file__).resolve().parents[1] / "models" / "cartpole.xml"
DURATION, DT = 10.0, 1e-3
X0 = np.array([0.05, 0.0])
TOL = 1e-8  # rad; RK4 at 1 ms actually lands near 1e-11 (docs/paper-notes.md section 7)

OVERRIDES = [CartPoleParams(5.0, 0.5, 1.0), CartPoleParams(20.0, 2.0, 0.5)]


def chirp_for(p: CartPoleParams):
    """100 N chirp for the 11 kg machine, scaled with M + m: same cart accelerations."""
    return partial(chirp_force, amplitude=100.0 * (p.M + p.m) / 11.0, f0=0.1, f1=2.0,
                   duration=DURATION)


def pole(plant: Plant) -> np.ndarray:
    """``[hinge, hinge_dot]`` of the plant's full state (the domain's task view)."""
    s = dict(zip(plant.state_names, plant.full_state()))
    return np.array((s["hinge"], s["hinge_dot"]))


def no_disturbance(t: float) -> float:
    return 0.0


def run(a: Plant, b: Plant, p: CartPoleParams, dist=square_disturbance) -> OpenLoopComparison:
    return open_loop_compare(a, b, X0, chirp_for(p), dist, DURATION, DT)


@pytest.fixture(scope="module")
def default_plant() -> MujocoCartPole:
    return MujocoCartPole(MODEL)


def test_params_read_back(default_plant: MujocoCartPole) -> None:
    assert default_plant.params == CartPoleParams(10.0, 1.0, 3.0, 9.8, J=pytest.approx(12.0, rel=1e-12),
                                                  ctrl_min=-2000.0, ctrl_max=2000.0)
    assert default_plant.timestep == pytest.approx(1e-3)
    assert isinstance(default_plant, Plant)


@pytest.mark.parametrize("overrides", [None, *OVERRIDES], ids=["default", "5-0.5-1", "20-2-0.5"])
def test_matches_solve_ivp_oracle(overrides: CartPoleParams | None) -> None:
    """(a), (c): MuJoCo RK4 vs the tight solve_ivp solution, square-wave d on, 10 s."""
    mj = MujocoCartPole(MODEL, overrides=overrides)
    p = mj.params
    if overrides is not None:
        # the model's own motor range stays; the rest is what was asked for
        assert dataclasses.replace(p, J=0.0, ctrl_min=-np.inf, ctrl_max=np.inf) == pytest.approx(overrides)
        assert p.J == pytest.approx(4.0 / 3.0 * p.m * p.l ** 2, rel=1e-12)
    r = run(mj, ReferenceCartPole(p), p)
    assert np.ptp(r.of_a("hinge")) > 1.0  # the pole really moved (it falls and swings)
    assert r.max_of("hinge") < TOL, r.max_of("hinge")
    assert r.max_of("hinge_dot") < 10 * TOL
    assert r.max_of("slider") < 10 * TOL


@pytest.mark.parametrize("overrides", [None, *OVERRIDES], ids=["default", "5-0.5-1", "20-2-0.5"])
def test_matches_analytic_rk4(overrides: CartPoleParams | None) -> None:
    """(b), (c): MuJoCo RK4 vs tspend's analytic RK4 plant built from ``params``."""
    mj = MujocoCartPole(MODEL, overrides=overrides)
    r = run(mj, cartpole_ode_plant(mj.params), mj.params)
    assert r.max_of("hinge") < TOL, r.max_of("hinge")
    assert r.max_of("slider") < 10 * TOL


def test_disturbance_has_the_odes_effect(default_plant: MujocoCartPole) -> None:
    """(d): the hinge torque standing in for d_d moves theta exactly as d_d does in the ODE."""
    p = default_plant.params
    ode = cartpole_ode_plant(p)
    on = run(default_plant, ode, p, square_disturbance)
    off = run(default_plant, ode, p, no_disturbance)
    effect_mj = on.of_a("hinge") - off.of_a("hinge")
    effect_ode = on.of_b("hinge") - off.of_b("hinge")
    assert np.max(np.abs(effect_mj)) > 1e-2  # the disturbance matters ...
    assert np.max(np.abs(effect_mj - effect_ode)) < TOL  # ... and identically in both

    # one sample from rest upright: theta'' = d / (m l - 4/3 l (M + m)), sign included
    for d in (1.0, -1.0):
        default_plant.reset(np.zeros(2))
        default_plant.step(0.0, d, DT)
        accel = d / (p.m * p.l - 4.0 / 3.0 * p.l * (p.M + p.m))
        # rel 1e-5: theta'' drifts as theta leaves 0 within the sample
        assert pole(default_plant)[1] == pytest.approx(accel * DT, rel=1e-5)


def test_push_right_tips_pole_positive(default_plant: MujocoCartPole) -> None:
    """(f): u > 0 at rest upright gives theta'' > 0 (pole leans to -x) as in the ODE."""
    p = default_plant.params
    default_plant.reset(np.zeros(2))
    default_plant.step(1.0, 0.0, DT)
    th, w = pole(default_plant)
    assert th > 0.0 and w > 0.0
    assert w == pytest.approx(DT / (4.0 / 3.0 * p.l * (p.M + p.m) - p.m * p.l), rel=1e-5)
    ode = cartpole_ode_plant(p)
    ode.reset(np.zeros(2))
    ode.step(1.0, 0.0, DT)
    assert pole(default_plant) == pytest.approx(pole(ode), rel=1e-12)
    assert default_plant.extras()["cart_vel"] > 0.0


def test_reset_state_extras(default_plant: MujocoCartPole) -> None:
    default_plant.reset(np.array([0.3, -0.2]))
    assert pole(default_plant).tolist() == [0.3, -0.2]
    assert default_plant.extras() == {"cart_pos": 0.0, "cart_vel": 0.0}
    assert default_plant.t == 0.0
    default_plant.step(5.0, 0.0, 0.01)  # 10 substeps
    assert default_plant.t == pytest.approx(0.01)
    with pytest.raises(ValueError):
        default_plant.reset(np.zeros(3))


def test_dt_must_be_a_multiple_of_the_timestep(default_plant: MujocoCartPole) -> None:
    default_plant.reset(np.zeros(2))
    with pytest.raises(ScenarioError, match=r"0\.0015.*0\.001"):
        default_plant.step(0.0, 0.0, 0.0015)


def test_non_finite_input_is_divergence_not_silent(default_plant: MujocoCartPole,
                                                   tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    # MuJoCo would zero a NaN ctrl (or reset on a NaN state) and carry on
    monkeypatch.chdir(tmp_path)  # MuJoCo logs the warning to ./MUJOCO_LOG.TXT
    default_plant.reset(np.zeros(2))
    with pytest.raises(DivergenceError):
        default_plant.step(math.nan, 0.0, DT)
    with pytest.raises(DivergenceError, match="huge input"):
        default_plant.step(1e12, 0.0, DT)
    default_plant.reset(np.array([0.1, 1e11]))  # a state past MuJoCo's 1e10 limit
    with pytest.raises(DivergenceError, match="reset the simulation"):
        default_plant.step(0.0, 0.0, DT)


def test_missing_file() -> None:
    with pytest.raises(ScenarioError, match=r"nope\.xml: model file not found"):
        MujocoCartPole(MODEL.parent / "nope.xml")


def test_unparsable_file(tmp_path: Path) -> None:
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body>\n")
    with pytest.raises(ScenarioError, match=r"bad\.xml: cannot parse MJCF"):
        MujocoCartPole(bad)


def test_missing_joint() -> None:
    with pytest.raises(ScenarioError) as exc:
        MujocoCartPole(MODEL, hinge_joint="pole")
    assert str(exc.value).endswith(
        "cartpole.xml: no hinge joint named 'pole' (joints in the model: slider, hinge)")
    with pytest.raises(ScenarioError, match="no slide joint named 'rail'.*slider, hinge"):
        MujocoCartPole(MODEL, slide_joint="rail")
    with pytest.raises(ScenarioError, match="joint 'hinge' is a hinge joint, expected a slide joint"):
        MujocoCartPole(MODEL, slide_joint="hinge")


def test_missing_actuator() -> None:
    with pytest.raises(ScenarioError, match=r"no actuator named 'push' \(actuators in the model: force\)"):
        MujocoCartPole(MODEL, actuator="push")


def test_bad_integrator_and_params() -> None:
    with pytest.raises(ScenarioError, match="unknown integrator 'RK45'.*RK4, Euler"):
        MujocoCartPole(MODEL, integrator="RK45")
    with pytest.raises(ScenarioError, match="parameter l must be positive"):
        MujocoCartPole(MODEL, overrides=CartPoleParams(l=0.0))


def test_integrator_override_changes_the_physics() -> None:
    euler = MujocoCartPole(MODEL, integrator="Euler")
    assert euler.model.opt.integrator == 0  # mjINT_EULER
    r = open_loop_compare(euler, cartpole_ode_plant(euler.params), X0, chirp_for(euler.params),
                          square_disturbance, 2.0, DT)
    assert r.max_of("hinge") > 1e-6  # first order: visibly off the RK4 solution


def test_overrides_stretch_the_pole_and_keep_a_rod() -> None:
    p = CartPoleParams(M=20.0, m=2.0, l=0.5, g=9.81)
    mj = MujocoCartPole(MODEL, overrides=p)
    m = mj.model
    pole = m.body("pole").id
    assert m.body_mass[m.body("cart").id] == pytest.approx(20.0)
    assert m.body_inertia[pole][:2] == pytest.approx([2.0 * 1.0**2 / 12.0] * 2)
    assert m.opt.gravity.tolist() == pytest.approx([0.0, 0.0, -9.81])
    assert m.geom_size[m.geom("pole").id][1] == pytest.approx(0.5)  # half-length l
    assert m.geom_pos[m.geom("pole").id].tolist() == pytest.approx([0.0, 0.0, 0.5])
    assert m.geom_pos[m.geom("tip").id].tolist() == pytest.approx([0.0, 0.0, 1.0])
    assert m.geom_size[m.geom("pivot").id].tolist() == pytest.approx([0.09, 0.2, 0.0])  # across: unchanged


def test_positive_theta_leans_the_pole_toward_minus_x(default_plant: MujocoCartPole) -> None:
    default_plant.reset(np.array([0.4, 0.0]))
    m, d = default_plant.model, default_plant.data
    # theta > 0 leans the pole toward -x: the tip is at pivot + 2l (-sin, 0, cos)
    tip = d.geom_xpos[m.geom("tip").id]
    pivot = d.xanchor[m.joint("hinge").id]
    assert tip == pytest.approx(pivot + 6.0 * np.array([-math.sin(0.4), 0.0, math.cos(0.4)]))
