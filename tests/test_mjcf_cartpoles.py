"""Any cart-pole MJCF read right (issue 23): its own masses, its real geometry, its
actuator and its limits, each checked against MuJoCo itself.

The models under tests/models/ are of our own making, one per case; the third-party ones
(models/third_party/) are gymnasium's inverted pendulum (a copy) and dm_control's
cart-pole (its physics, written from its numbers).  The oracle is MuJoCo: its forward
dynamics at random states (``mj_forward``'s ``qacc``) and its RK4 trajectories.
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from tspend import load_scenario, override, run
from tspend.cli.main import main
from tspend.runtime.errors import ScenarioError
from tspend.loop.simulation import prepare
from tspend.studies.cartpole_greybox import accelerations, machine_of
from tspend.plants.cartpole import MujocoCartPole
from tspend.studies.crosscheck import closed_loop, open_loop, parting, verdict

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "tests" / "models"
GYM = ROOT / "models" / "third_party" / "gymnasium_inverted_pendulum.xml"
DMC = ROOT / "models" / "third_party" / "dm_control_cartpole_physics.xml"

#: model -> (slide joint, hinge joint, actuator)
OWN = {
    "cartpole_leaning_com.xml": ("slider", "hinge", "force"),
    "cartpole_tilted_hinge.xml": ("slider", "hinge", "force"),
    "cartpole_velocity_actuator.xml": ("slider", "hinge", "drive"),
    "cartpole_position_actuator.xml": ("slider", "hinge", "servo"),
    "cartpole_general_actuator.xml": ("slider", "hinge", "drive"),
    "cartpole_limited_slide.xml": ("slider", "hinge", "force"),
    "cartpole_geom_masses.xml": ("slider", "hinge", "force"),
    "cartpole_damped.xml": ("slider", "hinge", "force"),
}
THIRD = {GYM: ("slider", "hinge", "slide"), DMC: ("slider", "hinge_1", "slide")}
ALL = {**{MODELS / k: v for k, v in OWN.items()}, **THIRD}


def scenario_on(model: Path, names: tuple[str, str, str], **more):
    slide, hinge, act = names
    return override(load_scenario("pendulum_mujoco"), **{
        "plant.model": str(model), "plant.slide_joint": slide, "plant.hinge_joint": hinge,
        "plant.actuator": act, "plant.timestep": 0.001, **more})


@pytest.mark.parametrize("model", list(ALL), ids=lambda p: p.stem)
def test_ode_accelerations_are_mujocos_at_random_states(model: Path) -> None:
    """(C1)-(C2) with the model's geometry and actuator = MuJoCo's qacc, at 200 random
    states and inputs (inputs beyond the control range too: the clipping is modelled)."""
    slide, hinge, act = ALL[model]
    plant = MujocoCartPole(model, slide, hinge, act, timestep=0.001)
    m, d = plant.model, plant.data
    p = machine_of(plant.params)
    rng = np.random.default_rng(7)
    qs, qh = m.jnt_qposadr[m.joint(slide).id], m.jnt_qposadr[m.joint(hinge).id]
    vs, vh = m.jnt_dofadr[m.joint(slide).id], m.jnt_dofadr[m.joint(hinge).id]
    lo, hi = (p.ctrl_min, p.ctrl_max) if math.isfinite(p.ctrl_min) else (-50.0, 50.0)
    span = hi - lo
    for _ in range(200):
        x = rng.uniform(-0.3, 0.3)      # inside every model's rail: no limit force
        q = rng.uniform(-1.2, 1.2)
        v, w = rng.uniform(-2, 2), rng.uniform(-3, 3)
        u = rng.uniform(lo - 0.3 * span, hi + 0.3 * span)
        d.qpos[qs], d.qpos[qh], d.qvel[vs], d.qvel[vh] = x, q, v, w
        d.ctrl[plant.model.actuator(act).id] = u
        d.qfrc_applied[:] = 0.0
        mujoco.mj_forward(m, d)
        q_dd, x_dd = accelerations(p, q, w, v, u, 0.0, x)
        scale = 1.0 + abs(d.qacc[vh]) + abs(d.qacc[vs])
        assert abs(q_dd - d.qacc[vh]) < 1e-10 * scale, (model.stem, q_dd, d.qacc[vh])
        assert abs(x_dd - d.qacc[vs]) < 1e-10 * scale, (model.stem, x_dd, d.qacc[vs])


@pytest.mark.parametrize("model", list(ALL), ids=lambda p: p.stem)
def test_crosscheck_open_loop_agrees_with_the_models_own_ode(model: Path) -> None:
    report = open_loop(scenario_on(model, ALL[model]), duration=3.0)
    worst = max(v for k, v in report.items() if k.startswith("open_loop_max_d"))
    assert worst <= 1e-8, report
    assert report["departures"] == []          # nothing the ODE leaves out
    assert report["open_loop_compared_s"] > 0.3


def test_gymnasium_balances_with_its_own_pole() -> None:
    """Must show: gymnasium's cart-pole, lqr, r = 0, 10 s: completed, rmse_ss <= 0.02 rad,
    the metrics' plant.m = the model's own 5.02 kg pole (no M, m, l written into it)."""
    scn = scenario_on(GYM, THIRD[GYM], **{"reference.amplitude": 0.0, "run.duration": 10.0})
    result = run(scn, controller="lqr", keep_history=False)
    assert result.status == "completed"
    assert result.metrics["rmse_ss"] <= 0.02
    assert result.metrics["plant"]["m"] == pytest.approx(5.018591641363306, rel=1e-12)
    assert result.plant.overridden == {}


@pytest.mark.parametrize("model", [GYM, DMC], ids=["gymnasium", "dm_control"])
def test_third_party_crosscheck_cli_exits_0(model: Path, tmp_path: Path) -> None:
    slide, hinge, act = THIRD[model]
    out = tmp_path / "cc.json"
    assert main(["crosscheck", "--no-record", "--duration", "1", "--metrics", str(out),
                 "--set", f'plant.model="{model}"', "--set", f'plant.actuator="{act}"',
                 "--set", f'plant.hinge_joint="{hinge}"', "--set", "plant.timestep=0.001"]) == 0
    import json

    report = json.loads(out.read_text())
    assert all(v <= 1e-8 for k, v in report.items() if k.startswith("open_loop_max_d"))


def test_overrides_are_explicit_and_verified() -> None:
    own = MujocoCartPole(GYM, actuator="slide")
    changed = MujocoCartPole(GYM, actuator="slide", overrides={"m": 2.0})
    assert changed.overridden == {"m": 2.0}
    assert changed.facts.pole_mass == pytest.approx(2.0, rel=1e-12)
    assert changed.facts.cart_mass == pytest.approx(own.facts.cart_mass, rel=1e-12)
    # the paper's default scenario writes nothing: models/cartpole.xml already is M, m, l
    assert prepare(load_scenario("pendulum_mujoco")).plant.overridden == {}
    with pytest.raises(ScenarioError, match="cannot override"):
        MujocoCartPole(GYM, actuator="slide", overrides={"mass": 2.0})


def test_tilted_hinge_of_the_papers_model_is_modelled_exactly(tmp_path: Path) -> None:
    tilted = tmp_path / "tilted.xml"
    tilted.write_text((ROOT / "models" / "cartpole.xml").read_text().replace(
        'axis="0 -1 0" pos="0 0 0"', 'axis="0 -1 1" pos="0 0 0"'))
    assert 'axis="0 -1 1"' in tilted.read_text()
    scn = override(load_scenario("pendulum_mujoco"), **{"plant.model": str(tilted)})
    report = open_loop(scn, duration=10.0)
    assert report["open_loop_max_tracked"] <= 1e-8
    plant = prepare(scn).plant
    assert plant.facts.gravity_coupling == pytest.approx(math.sqrt(0.5), rel=1e-12)


def test_parallel_hinge_is_refused_naming_both_axes(capsys) -> None:
    status = main(["crosscheck", "--no-record", "--set",
                   f'plant.model="{MODELS / "cartpole_parallel_hinge.xml"}"'])
    assert status == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "parallel" in err and "(1, 0, 0)" in err and "hinge 'hinge' axis" in err
    assert "slide 'slider' axis" in err


def test_actuators_as_they_are() -> None:
    vel = MujocoCartPole(MODELS / "cartpole_velocity_actuator.xml", actuator="drive").facts
    assert vel.actuator_type == "velocity" and vel.gear == 2.0 and vel.gain == 40.0
    assert vel.actuator.bias_velocity == -40.0
    assert vel.actuator.max_force_at_rest() == pytest.approx(120.0)   # 2 x clip(40 x 3, 60)
    pos = MujocoCartPole(MODELS / "cartpole_position_actuator.xml", actuator="servo").facts
    assert pos.actuator_type == "position" and pos.actuator.bias_length == -150.0
    assert pos.actuator.max_force_at_rest() == pytest.approx(75.0)    # 150 x 0.5
    gen = MujocoCartPole(MODELS / "cartpole_general_actuator.xml", actuator="drive").facts
    assert gen.actuator_type == "general" and gen.actuator.joint_force_range == (-45.0, 45.0)
    # the ranges are reported as well as applied
    assert "clipped actuator: forcerange [-60, 60] N" in vel.departures
    assert any(d.startswith("actuator 'drive' is a velocity actuator") for d in vel.departures)
    assert "clipped actuator: slide joint actuatorfrcrange [-45, 45] N" in gen.departures


def test_an_actuator_with_dynamics_is_refused_with_the_reason(tmp_path: Path) -> None:
    filtered = tmp_path / "filtered.xml"
    filtered.write_text((MODELS / "cartpole_limited_slide.xml").read_text().replace(
        '<motor name="force" joint="slider"/>',
        '<general name="force" joint="slider" dyntype="filter" dynprm="0.05"/>'))
    with pytest.raises(ScenarioError, match="activation dynamics \\(dyntype filter\\)"):
        MujocoCartPole(filtered)


def test_limited_slide_ends_the_comparison_and_the_run() -> None:
    scn = scenario_on(MODELS / "cartpole_limited_slide.xml", OWN["cartpole_limited_slide.xml"])
    report = open_loop(scn, duration=10.0)
    assert "joint 'slider' reached its range [-0.4, 0.4]" in report["open_loop_stopped_by"]
    assert 0.0 < report["open_loop_compared_s"] < 10.0
    assert report["open_loop_max_tracked"] <= 1e-8
    # the paper's controller leaves the cart free: it drifts into the end of its range
    ended = run(override(scn, **{"run.duration": 10.0}), keep_history=False)
    assert ended.status == "rail_end"
    assert "slider" in ended.end.message and "[-0.4, 0.4]" in ended.end.message


def test_contacts_are_the_ones_that_occur() -> None:
    scn = scenario_on(MODELS / "cartpole_wall_contact.xml", ("slider", "hinge", "force"))
    plant = prepare(scn).plant
    assert plant.facts.collision_pairs == ("wall_right/cart", "wall_left/cart")
    report = open_loop(scn, duration=10.0)
    assert "contact between geoms" in report["open_loop_stopped_by"]
    assert "'cart'" in report["open_loop_stopped_by"]
    assert report["open_loop_max_tracked"] <= 1e-8
    # gymnasium's geoms have contype 0: nothing can touch, nothing is reported
    gym = MujocoCartPole(GYM, actuator="slide")
    assert gym.facts.collision_pairs == () and not any("contact" in d for d in gym.departures())


def test_the_task_says_plainly_when_it_cannot_be_done() -> None:
    scn = scenario_on(DMC, THIRD[DMC])
    prepare(scn)     # (pi/30) sin t needs 1.16 N of the 10 N: it can be done
    with pytest.raises(ScenarioError, match=r"cannot be done: .* 18.1 N .* -10 \.\. 10 N"):
        prepare(override(scn, **{"reference.amplitude": 1.0}))


def test_closed_loop_parting_is_part_of_the_verdict() -> None:
    t = np.arange(5) * 0.1
    a = np.zeros((5, 2))
    b = a.copy()
    b[3:, 1] = [1e-6, 2e-3]
    assert parting(t, a, b, 1e-8) == (pytest.approx(0.3), pytest.approx(2e-3))
    assert parting(t, a, a, 1e-8) == (None, 0.0)
    # Euler in MuJoCo against RK4 in the ODE: the closed loops part, the verdict says when
    scn = override(load_scenario("pendulum_mujoco"), **{"plant.integrator": "Euler",
                                                          "run.duration": 2.0})
    report = {"open_loop_ok": False, "open_loop_tracked": "hinge", "open_loop_max_tracked": 1.0,
              "open_loop_compared_s": 1.0, "departures": ["integrator Euler, not RK4"],
              **closed_loop(scn)}
    text = verdict(report)
    assert report["closed_loop_parted_at_s"] is not None
    assert f"part at t = {report['closed_loop_parted_at_s']:.6g} s" in text
    assert "the ODE leaves out: integrator Euler" in text


def test_every_warning_once(capsys) -> None:
    assert main(["crosscheck", "--no-record", "--duration", "0.5", "--open-loop-duration", "1",
                 "--set", f'plant.model="{GYM}"', "--set", 'plant.actuator="slide"',
                 "--set", "plant.timestep=0.001"]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if "warning:" in line]
    assert warnings and len(warnings) == len(set(warnings))


@pytest.mark.parametrize("model", list(ALL), ids=lambda p: p.stem)
def test_mpc_model_is_the_general_ode_symbolically(model: Path) -> None:
    """The full-state model MPC builds over CasADi is (C1)-(C2) with the model's geometry
    and actuator, ranges clipped: = its numeric twin at random states and inputs (beyond
    the control range too), and = MuJoCo's qacc where the model has no friction (the
    full-state model leaves a rig's friction out)."""
    import casadi

    from tspend.controllers.full_model import full_model
    from tspend.loop.simulation import nominal_machine

    slide, hinge, act = ALL[model]
    scn = scenario_on(model, ALL[model])
    fm = full_model(scn, nominal_machine(scn))
    S, U = casadi.SX.sym("s", 4), casadi.SX.sym("u")
    f = casadi.Function("f", [S, U], [fm.symbolic()(S, U)])
    plant = MujocoCartPole(model, slide, hinge, act, timestep=0.001)
    p = plant.params
    rigid = p.cart_damping == p.hinge_damping == p.cart_friction == p.hinge_friction == 0.0
    m, d = plant.model, plant.data
    qs, qh = m.jnt_qposadr[m.joint(slide).id], m.jnt_qposadr[m.joint(hinge).id]
    vs, vh = m.jnt_dofadr[m.joint(slide).id], m.jnt_dofadr[m.joint(hinge).id]
    lo, hi = (p.ctrl_min, p.ctrl_max) if math.isfinite(p.ctrl_min) else (-50.0, 50.0)
    span = hi - lo
    rng = np.random.default_rng(11)
    for _ in range(50):
        s = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-1.2, 1.2),
                      rng.uniform(-2, 2), rng.uniform(-3, 3)])
        u = rng.uniform(lo - 0.3 * span, hi + 0.3 * span)
        numeric = fm.rhs(s, u)
        symbolic = np.asarray(f(s, u)).ravel()
        assert symbolic == pytest.approx(numeric, rel=1e-12, abs=1e-12), model.stem
        if rigid:
            d.qpos[qs], d.qpos[qh], d.qvel[vs], d.qvel[vh] = s
            d.ctrl[m.actuator(act).id] = u
            d.qfrc_applied[:] = 0.0
            mujoco.mj_forward(m, d)
            scale = 1.0 + abs(d.qacc[vh]) + abs(d.qacc[vs])
            assert abs(numeric[2] - d.qacc[vs]) < 1e-10 * scale, model.stem
            assert abs(numeric[3] - d.qacc[vh]) < 1e-10 * scale, model.stem


def test_relative_draws_multiply_the_models_own_values(tmp_path) -> None:
    """[randomize] on a third-party model whose [plant] leaves m, l, M at 0: the relative
    draws multiply the compiled model's own values, which the drawn plant then has."""
    from tspend.plants import randomize
    from tspend.scenario import parse_scenario

    text = (ROOT / "scenarios" / "pendulum_mujoco_randomized.toml").read_text()
    scn = override(parse_scenario(text, str(ROOT / "scenarios" / "x.toml")), **{
        "plant.model": str(GYM), "plant.actuator": "slide", "plant.timestep": 0.001})
    own = MujocoCartPole(GYM, actuator="slide").facts
    for seed in (0, 1):
        drawn = randomize.draw(override(scn, **{"run.seed": seed})).values
        assert 0.8 * own.pole_mass <= drawn["m"] <= 1.2 * own.pole_mass
        assert 0.9 * own.pole_com <= drawn["l"] <= 1.1 * own.pole_com
        assert 0.8 * own.cart_mass <= drawn["M"] <= 1.2 * own.cart_mass
        assert 0.8 * own.force_per_u <= drawn["gear"] <= 1.2 * own.force_per_u
        facts = prepare(override(scn, **{"run.seed": seed})).plant.facts
        assert (facts.pole_mass, facts.cart_mass) == pytest.approx((drawn["m"], drawn["M"]),
                                                                   rel=1e-9)
        assert facts.force_per_u == pytest.approx(drawn["gear"], rel=1e-9)
    # a relative draw on a key that is 0 on the model too is refused, one line
    bad = parse_scenario(text.replace(
        'M = {dist = "uniform"', 'cart_damping = {dist = "uniform", low = 0.5, high = 2.0, '
        'relative = true}\nM = {dist = "uniform"'), str(tmp_path / "bad.toml"))
    with pytest.raises(ScenarioError, match="randomize.cart_damping.relative.*is 0"):
        randomize.draw(bad)
