"""u in a geared motor's control units, the force it applies beside it (summary, metrics,
recording, export); the paper's input sets scaled to the actuator's range (issue 44, part A)."""

import json
import re
import warnings
from pathlib import Path

import mujoco
import numpy as np
import pytest

from tspend import load_scenario, override
from tspend.cli.main import main
from tspend.loop.simulation import build_plant, prepare

MODELS = Path(__file__).parents[1] / "models" / "third_party"
#: gymnasium's double pendulum on a cart: motor gear 500, ctrlrange -1 1
DOUBLE = Path(__file__).parent / "models" / "gymnasium_double_pendulum_ranges.xml"
#: dm_control's cart-pole: motor gear 10, ctrlrange -1 1
DMC = MODELS / "dm_control_cartpole_physics.xml"
ON_DOUBLE = ["--set", f'plant.model="{DOUBLE}"', "--set", 'plant.actuator="slide"']


def _double():
    return override(load_scenario("double_cartpole_mujoco"),
                    **{"plant.model": str(DOUBLE), "plant.actuator": "slide"})


def _dmc():
    return override(load_scenario("pendulum_mujoco"),
                    **{"plant.model": str(DMC), "plant.actuator": "slide",
                       "plant.hinge_joint": "hinge_1", "plant.timestep": 0.001})


def _force_per_ctrl(plant) -> float:
    """MuJoCo's own generalised force on the driven joint for ctrl = 1 at rest (the
    oracle: qfrc_actuator, not the gear and gain the plant read)."""
    model = plant.mj_model()
    data = mujoco.MjData(model)
    data.ctrl[plant._act] = 1.0
    mujoco.mj_forward(model, data)
    return float(np.max(np.abs(data.qfrc_actuator)))


@pytest.mark.parametrize("scenario, force", [(_double, 500.0), (_dmc, 10.0)],
                         ids=["articulated gear 500", "cart-pole gear 10"])
def test_a_geared_motor_takes_ctrl_with_its_force_beside_it(scenario, force):
    plant = build_plant(scenario())
    inp = plant.inputs[0]
    assert inp.unit == "ctrl" and inp.force_unit == "N"
    assert inp.force_per_unit == pytest.approx(_force_per_ctrl(plant), rel=1e-12)
    assert inp.force_per_unit == pytest.approx(force)


def test_a_motor_whose_u_is_the_force_keeps_its_unit():
    for name, unit in (("double_cartpole_mujoco", "N"), ("pendulum_mujoco", "N"),
                       ("acrobot_mujoco", "N m")):
        plant = build_plant(load_scenario(name))
        inp = plant.inputs[0]
        assert inp.unit == unit and inp.force_unit == "" and inp.force_per_unit == 1.0
        assert _force_per_ctrl(plant) == pytest.approx(1.0)


def test_summary_metrics_recording_and_export_say_ctrl_and_the_force(tmp_path, capsys):
    m, rrd, csv = tmp_path / "m.json", tmp_path / "r.rrd", tmp_path / "r.csv"
    status = main(["run", "double_cartpole_mujoco", "--controller", "second_type",
                   "--duration", "2", "--metrics", str(m), "--out", str(rrd), *ON_DOUBLE])
    assert status != 2
    out, err = capsys.readouterr()
    metrics = json.loads(m.read_text())
    act = metrics["actuator"]
    assert act["u_unit"] == "ctrl" and act["force_unit"] == "N" and act["force_per_u"] == 500.0
    assert act["max_abs_force"] == pytest.approx(500.0 * metrics["max_abs_u"])
    assert act["max_abs_force_command"] == pytest.approx(500.0 * metrics["max_abs_u_command"])
    assert metrics["max_abs_u"] <= 1.0 + 1e-12 < metrics["max_abs_u_command"]
    assert re.search(rf"max_abs_u +{metrics['max_abs_u']:g} ctrl", out)
    assert "actuator force" in out and "N per ctrl of u at rest" in out
    # the run ends saturated: the command is a control value, never called a force
    if "saturated for the last" in err:
        assert " ctrl, applied at most 1 ctrl (500 N at rest)" in err
        assert not any(f"commanded up to {metrics['max_abs_u_command']:.4g} N" in line
                       for line in err.splitlines())
    assert main(["export", str(rrd), "--out", str(csv)]) == 0
    header = csv.read_text().splitlines()[0].split(",")
    assert "u_ctrl" in header and "u_N" not in header
    side = json.loads((tmp_path / "r.csv.json").read_text())
    assert side["u_unit"] == "ctrl" and side["force_unit"] == "N" and side["force_per_u"] == 500.0


def test_the_papers_input_sets_scale_to_the_actuators_range():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scaled = prepare(_double(), controller="second_type")
    sets = scaled.scenario.controller.u_sets
    assert (sets.lo, sets.hi) == (-1.0, 1.0)
    assert load_scenario("double_cartpole_mujoco").controller.u_sets.hi == 40.0
    assert any("controller.sets.u [-40, 40] reaches beyond actuator 'slide''s range [-1, 1] ctrl"
               in str(w.message) for w in caught)
    # sets within the range stay as written; a kind without input sets is not told
    own = prepare(load_scenario("double_cartpole_mujoco"), controller="second_type")
    assert own.scenario.controller.u_sets == load_scenario("double_cartpole_mujoco").controller.u_sets
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        prepare(_double(), controller="lqr")
    assert not any("controller.sets.u" in str(w.message) for w in caught)


def test_a_saturated_end_calls_the_command_a_control_value():
    from tspend.loop.runner import _what_else

    class Plant:
        def constraint_active(self):
            return ""

    metrics = {"saturated_at_end_s": 0.5, "max_abs_u_command": 609.7, "max_abs_u": 1.0,
               "actuator": {"u_unit": "ctrl", "force_unit": "N", "force_per_u": 500.0}}
    text = _what_else(Plant(), metrics)
    assert "commanded up to 609.7 ctrl, applied at most 1 ctrl (500 N at rest)" in text
    assert "609.7 N" not in text
    # u that is the force: its unit, no second figure
    metrics["actuator"] = {"u_unit": "N"}
    assert "commanded up to 609.7 N, applied at most 1 N)" in _what_else(Plant(), metrics)
