"""The cross-check judges each random state by its own limits and contacts, says how many it
compared, names a differing integrator first; every MuJoCo machine takes plant.integrator;
a model of another machine is refused naming the kind that takes it; a pole must be a hinge
(issue 44, part A)."""

import json
from pathlib import Path

import mujoco
import numpy as np
import pytest

from tspend import load_scenario, override
from tspend.cli.main import main
from tspend.loop.simulation import build_plant
from tspend.studies.crosscheck import verdict
from tspend.studies.crosscheck_derived import accelerations_check

MODELS = Path(__file__).parents[1] / "models" / "third_party"
#: gymnasium's double pendulum on a cart, both hinges limited, the slide with a margin
RANGES = Path(__file__).parent / "models" / "gymnasium_double_pendulum_ranges.xml"
ON_RANGES = ["--set", f'plant.model="{RANGES}"', "--set", 'plant.actuator="slide"']


def _scenario(model: Path = RANGES, **changes):
    return override(load_scenario("double_cartpole_mujoco"),
                    **{"plant.model": str(model), "plant.actuator": "slide", **changes})


def _euler_copy(tmp_path: Path) -> Path:
    text = RANGES.read_text()
    assert 'integrator="RK4"' in text
    euler = tmp_path / "euler.xml"
    euler.write_text(text.replace('integrator="RK4"', 'integrator="Euler"'))
    return euler


def _constrained(model, q: np.ndarray) -> bool:
    """MuJoCo's own constraint rows at ``q`` (an oracle apart from the check's reading of
    joint ranges and contacts): a limit or contact row in efc_type."""
    data = mujoco.MjData(model)
    data.qpos[:] = q
    mujoco.mj_forward(model, data)
    kinds = {int(mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT)} | {
        int(getattr(mujoco.mjtConstraint, n)) for n in dir(mujoco.mjtConstraint)
        if n.startswith("mjCNSTR_CONTACT")}
    return any(int(t) in kinds for t in data.efc_type[:data.nefc])


def test_accelerations_are_judged_by_each_state_not_by_the_plants_data():
    plant = build_plant(_scenario())
    fresh = accelerations_check(plant)
    # the plant left where an open loop stops: the slide at its limit
    nv = plant.model.nv
    plant.data.qpos[:] = [0.9999, 0.0, 0.0][:nv]
    mujoco.mj_forward(plant.model, plant.data)
    assert plant.constraint_active()
    at_limit = accelerations_check(plant)
    assert at_limit == fresh
    assert fresh["accel_ok"] and fresh["accel_max_diff"] < 1e-9
    # the states skipped are exactly those where MuJoCo itself has a limit or contact row:
    # the same draws (seed 0) replayed through MuJoCo's constraint types
    rng = np.random.default_rng(0)
    machine = plant.machine
    lo, hi = machine.actuator.ctrlrange
    skipped = 0
    for _ in range(fresh["accel_drawn"]):
        q = np.array([rng.uniform(*j.range) for j in machine.tree.joints])
        rng.uniform(-20.0, 20.0, nv)
        rng.uniform(lo, hi)
        skipped += _constrained(plant.model, q)
    assert 0 < skipped == fresh["accel_skipped"]
    assert fresh["accel_states"] == fresh["accel_drawn"] - skipped


def test_too_few_states_compared_is_inconclusive():
    plant = build_plant(_scenario())
    few = accelerations_check(plant, n_states=50)
    assert few["accel_states"] <= 50 and few["accel_inconclusive"] and not few["accel_ok"]
    report = {"open_loop_ok": False, "inconclusive": True, "open_loop_compared_s": 1.0,
              "open_loop_within_tol_s": 1.0,
              "open_loop_tracked": "hinge", "open_loop_max_tracked": 0.0, **few,
              "free_tight": 1e-10, "free_loose": 1e-6, "free_within_tight_s": 1.0,
              "free_within_loose_s": 1.0, "free_compared_s": 1.0, "free_stopped_by": ""}
    text = verdict(report)
    assert f"at {few['accel_states']} of 50 random states" in text
    assert "INCONCLUSIVE: a verdict on the equations needs at least 100 states" in text


def test_cli_acceleration_figure_does_not_depend_on_the_open_loop(tmp_path, capsys):
    figures = []
    for extra in ([], ["--open-loop-duration", "0.5"]):
        js = tmp_path / f"cc{len(extra)}.json"
        assert main(["crosscheck", "double_cartpole_mujoco", "--no-record", "--duration", "0.2",
                     "--metrics", str(js), *ON_RANGES, *extra]) == 0
        report = json.loads(js.read_text())
        figures.append(report)
        assert "random states" in report["verdict"]
        assert f"at {report['accel_states']} of 1000 random states" in report["verdict"]
    a, b = figures
    # the 10 s open loop stops at a joint's limit, the 0.5 s one before it
    assert a["open_loop_stopped_by"] and not b["open_loop_stopped_by"]
    assert abs(a["accel_max_diff"] - b["accel_max_diff"]) <= 1e-9
    assert a["accel_states"] == b["accel_states"] < 1000


def test_an_euler_model_names_its_integrator_first_and_plant_integrator_fixes_it(tmp_path, capsys):
    euler = _euler_copy(tmp_path)
    model = ["--set", f'plant.model="{euler}"', "--set", 'plant.actuator="slide"']
    js = tmp_path / "e.json"
    assert main(["crosscheck", "double_cartpole_mujoco", "--no-record", "--duration", "0.2",
                 "--metrics", str(js), *model]) == 1
    report = json.loads(js.read_text())
    assert report["mujoco_integrator"] == "Euler"
    assert report["verdict"].startswith("MuJoCo steps the model with Euler, the ODE with RK4")
    assert "chaotic" not in report["verdict"]
    capsys.readouterr()
    assert main(["crosscheck", "double_cartpole_mujoco", "--no-record", "--duration", "0.2",
                 *model, "--set", 'plant.integrator="RK4"']) == 0
    assert "cross-check: open loop agrees" in capsys.readouterr().err


@pytest.mark.parametrize("scenario", ["double_cartpole_mujoco", "furuta_mujoco", "acrobot_mujoco"])
def test_every_mujoco_machine_takes_plant_integrator(scenario):
    scn = override(load_scenario(scenario), **{"plant.integrator": "Euler"})
    plant = build_plant(scn)
    assert plant.model.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
    assert build_plant(load_scenario(scenario)).model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4


def test_a_model_of_another_machine_is_refused_naming_the_kind_that_takes_it(capsys):
    assert main(["run", "pendulum_mujoco", "--no-record", "--duration", "0.1", *ON_RANGES,
                 "--set", 'plant.slide_joint="slider"']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert 'plant.kind = "articulated_mujoco" (scenario double_cartpole_mujoco' in err[0]


def test_a_slide_is_no_pole(capsys):
    assert main(["run", "double_cartpole_mujoco", "--no-record", "--duration", "0.1",
                 "--set", 'plant.poles=["slider"]']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'slider' is a slide joint, and a pole must be a hinge" in err[0]
