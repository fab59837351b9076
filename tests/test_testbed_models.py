"""Any MJCF cart-pole read as it is (issue 12), on test models of our own making.

Independent checks: the compiled joint-space mass matrix (``mj_fullM``), whose entries at
the upright are ``M + m`` (+ slide armature), ``-m l`` and ``J`` (+ hinge armature) by
(C1)-(C2); masses of geoms computed by hand from their shapes and densities; MuJoCo's
own forward dynamics for the gain sign.
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import mujoco
import numpy as np
import pytest

from tspend import load_scenario, override, run
from tspend.cli.main import main
from tspend.studies.crosscheck import failure_reason, open_loop
from tspend.runtime.errors import ScenarioError
from tspend.plants.mjcf import CartPoleParams
from tspend.runtime.errors import ModelWarning
from tspend.plants.cartpole import MujocoCartPole
from tspend.loop.simulation import build_plant

MODELS = Path(__file__).with_name("models")
REVERSED = MODELS / "cartpole_reversed.xml"
GEOM_MASSES = MODELS / "cartpole_geom_masses.xml"
GEAR_CLIPPED = MODELS / "cartpole_gear_clipped.xml"
DAMPED_LIMITED = MODELS / "cartpole_damped_limited.xml"
DAMPED = MODELS / "cartpole_damped.xml"


def mass_matrix(model: mujoco.MjModel) -> np.ndarray:
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    return full


def inspect_json(tmp_path: Path, model: Path, *extra: str) -> dict:
    out = tmp_path / f"{model.stem}.json"
    assert main(["inspect", str(model), "--metrics", str(out), *extra]) == 0
    return json.loads(out.read_text())


@pytest.mark.parametrize("model", [REVERSED, GEOM_MASSES, GEAR_CLIPPED, DAMPED_LIMITED, DAMPED])
def test_inspect_reads_the_compiled_mass_matrix(tmp_path: Path, model: Path) -> None:
    facts = inspect_json(tmp_path, model)
    for key in ("cart_mass", "pole_mass", "pole_com", "pole_inertia_pivot", "gain_sign", "gear",
                "ctrl_range", "timestep", "integrator", "departures"):
        assert key in facts
    full = mass_matrix(mujoco.MjModel.from_xml_path(str(model)))
    slide_arm, hinge_arm = facts["slide"]["armature"], facts["hinge"]["armature"]
    assert full[0, 0] == pytest.approx(facts["cart_mass"] + facts["pole_mass"] + slide_arm, rel=1e-12)
    assert abs(full[0, 1]) == pytest.approx(facts["pole_mass"] * facts["pole_com"], rel=1e-12)
    assert full[1, 1] == pytest.approx(facts["pole_inertia_pivot"] + hinge_arm, rel=1e-12)


def test_inspect_masses_from_geoms_by_hand(tmp_path: Path) -> None:
    facts = inspect_json(tmp_path, GEOM_MASSES)
    r, length = 0.045, 0.6
    pole = 1000.0 * (math.pi * r * r * length + 4.0 / 3.0 * math.pi * r ** 3)
    assert facts["cart_mass"] == pytest.approx(1000.0 * 0.4 * 0.3 * 0.2, rel=1e-9)
    assert facts["pole_mass"] == pytest.approx(pole, rel=1e-9)
    assert facts["pole_com"] == pytest.approx(0.3, rel=1e-12)
    assert any("not the uniform rod" in d for d in facts["departures"])


def test_inspect_reports_each_departure(tmp_path: Path) -> None:
    rev = inspect_json(tmp_path, REVERSED)
    assert rev["gain_sign"] == -1 and rev["theta_sign"] == -1
    assert any(d.startswith("reversed gain sign") for d in rev["departures"])
    gear = inspect_json(tmp_path, GEAR_CLIPPED)
    assert gear["gear"] == 100.0 and gear["ctrl_range"] == [-1.0, 1.0]
    assert any(d.startswith("clipped actuator") for d in gear["departures"])
    dl = inspect_json(tmp_path, DAMPED_LIMITED, "--dt", "0.001")
    text = "\n".join(dl["departures"])
    for words in ("has damping 5", "has damping 0.8", "is limited to [-2, 2]",
                  "is limited to [-0.6, 0.6]", "integrator Euler", "does not divide dt"):
        assert words in text, words
    assert dl["timestep"] == 0.002 and dl["integrator"] == "Euler"


def test_gain_sign_agrees_with_the_model_geometry() -> None:
    """Measured sign (forward dynamics) = hinge orientation (geometry) x gear sign."""
    for model, sign in ((REVERSED, -1), (GEAR_CLIPPED, 1), (GEOM_MASSES, 1)):
        plant = MujocoCartPole(model)
        assert plant.gain_sign == sign == plant.facts.theta_sign


def test_overrides_take_effect_on_a_model_with_geom_masses() -> None:
    p = CartPoleParams(M=10.0, m=1.0, l=3.0, g=9.8)
    plant = MujocoCartPole(GEOM_MASSES, overrides=p)
    full = mass_matrix(plant.model)
    assert full[0, 0] == pytest.approx(11.0, rel=1e-12)
    assert abs(full[0, 1]) == pytest.approx(3.0, rel=1e-12)
    assert full[1, 1] == pytest.approx(12.0, rel=1e-12)   # 4/3 m l^2: the rod
    # and a pole inertia other than the rod's
    plant = MujocoCartPole(GEOM_MASSES, overrides=CartPoleParams(M=5.0, m=0.5, l=1.0, J=0.9))
    assert mass_matrix(plant.model)[1, 1] == pytest.approx(0.9, rel=1e-12)
    assert plant.facts.cart_mass == pytest.approx(5.0, rel=1e-12)


def test_override_that_cannot_take_effect_names_the_body(tmp_path: Path) -> None:
    text = GEOM_MASSES.read_text().replace(
        '<geom name="pole" type="capsule"',
        '<body name="tip"><geom type="sphere" size="0.05" pos="0 0 0.6"/></body>\n'
        '        <geom name="pole" type="capsule"')
    model = tmp_path / "tip_body.xml"
    model.write_text(text)
    with pytest.raises(ScenarioError, match="body 'pole'.*child bodies.*tip"):
        MujocoCartPole(model, overrides=CartPoleParams())
    with pytest.raises(ScenarioError, match="J = 1 must exceed m l\\^2 = 9"):
        MujocoCartPole(GEOM_MASSES, overrides=CartPoleParams(J=1.0))


@pytest.mark.parametrize("model, expected", [
    (REVERSED, ["reversed gain sign"]),
    (GEAR_CLIPPED, ["clipped actuator", "gear 100"]),
    (DAMPED_LIMITED, ["damping", "is limited", "integrator Euler", "2 physics steps"]),
])
def test_a_run_warns_once_per_departure(model: Path, expected: list[str]) -> None:
    dt = 0.004 if model == DAMPED_LIMITED else 0.001
    scn = override(load_scenario("pendulum_mujoco"), **{"plant.model": str(model), "run.dt": dt})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        build_plant(scn)
    lines = [str(w.message) for w in caught if issubclass(w.category, ModelWarning)]
    for words in expected:
        assert any(words in line for line in lines), (words, lines)
    assert all("\n" not in line for line in lines)


def test_cli_prints_warnings_as_one_line(capsys) -> None:
    assert main(["run", "pendulum_mujoco", "--no-record", "--set", "run.duration=0.01",
                 "--set", f'plant.model="{GEAR_CLIPPED}"']) == 0
    err = capsys.readouterr().err
    assert "tspend: warning:" in err and "clipped actuator" in err


def test_timestep_key_and_the_dt_error_that_suggests_it() -> None:
    scn = override(load_scenario("pendulum_mujoco"), **{"plant.model": str(DAMPED_LIMITED),
                                                         "run.dt": 0.003})
    with pytest.raises(ScenarioError, match="plant.timestep"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            build_plant(scn)
    scn = override(scn, **{"plant.timestep": 0.001})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plant = build_plant(scn)
    assert plant.timestep == 0.001 and plant.model.opt.timestep == 0.001


def test_reversed_axis_tracks_with_the_sign_from_the_model() -> None:
    scn = override(load_scenario("pendulum_mujoco"), **{"plant.model": str(REVERSED)})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ModelWarning)
        r = run(scn)
    assert r.status == "completed"
    assert r.metrics["rmse_ss"] < 5e-4, r.metrics["rmse_ss"]
    assert r.history["p"][:, -1].max() <= -scn.controller.b_min * (1 - 1e-12)  # b <= -b_min
    # the sign given against the model: the loop is unstable
    wrong = override(scn, **{"controller.gain_sign": "positive", "run.duration": 5.0,
                             "plant.state_bound": 1.5})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ModelWarning)
        assert run(wrong).status == "diverged"


def test_damped_model_against_its_own_ode() -> None:
    scn = override(load_scenario("pendulum_mujoco"), **{"plant.model": str(DAMPED),
                                                         "plant.override_inertials": False})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ModelWarning)
        report = open_loop(scn)
    assert report["ode_params"]["cart_damping"] == 5.0
    assert report["ode_params"]["hinge_damping"] == 0.8
    assert report["ode_params"]["M"] == pytest.approx(10.5)        # armature counts as mass
    assert report["open_loop_max_dhinge"] < 1e-8
    assert report["open_loop_max_dslider"] < 1e-8


def test_failing_crosscheck_names_the_departures(capsys) -> None:
    code = main(["crosscheck", "pendulum_mujoco", "--no-record", "--set", "run.duration=0.02",
                 "--set", "run.dt=0.002", "--set", f'plant.model="{DAMPED_LIMITED}"',
                 "--open-loop-duration", "3"])
    err = capsys.readouterr().err
    assert code == 1
    assert "cross-check failed" in err and "integrator Euler" in err and "is limited" in err
    assert "no departure" in failure_reason({"departures": []})


def test_inspect_bad_input_is_one_line_and_status_2(tmp_path: Path, capsys) -> None:
    assert main(["inspect", str(tmp_path / "none.xml")]) == 2
    # a cart with a ball joint: neither the cart-pole's ODE nor a derived chain of hinges
    ball = tmp_path / "ball.xml"
    ball.write_text(REVERSED.read_text().replace(
        '<joint name="hinge" type="hinge" axis="0 1 0"/>', '<joint name="hinge" type="ball"/>'))
    assert main(["inspect", str(ball)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("tspend: error:") and "ball" in err[-1]
