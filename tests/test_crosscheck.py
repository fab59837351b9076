"""tspend crosscheck: MuJoCo against the ODE, open and closed loop (issue 3)."""

import json

import pytest

from tspend import load_scenario, override
from tspend.cli.main import main
from tspend.studies.crosscheck import closed_loop, open_loop
from tspend.recorder import read_scalar_series, series_location

KEYS = ("open_loop_max_dhinge", "open_loop_max_dhinge_dot", "closed_loop_max_dhinge",
        "closed_loop_rmse_ss_mujoco", "closed_loop_rmse_ss_ode")


def test_cli_crosscheck_json_and_recording(tmp_path, capsys):
    js, rrd = tmp_path / "cc.json", tmp_path / "cc.rrd"
    status = main(["crosscheck", "--duration", "2", "--open-loop-duration", "10",
                   "--metrics", str(js), "--out", str(rrd)])
    assert status == 0
    report = json.loads(js.read_text())
    for key in KEYS:
        assert key in report
    assert report["open_loop_max_dhinge"] < 1e-8          # 10 s, disturbance on, RK4 at 1 ms
    assert report["closed_loop_max_dhinge"] < 1e-8
    # both backends side by side in one recording
    _, a = read_scalar_series(rrd, *series_location("x1", 2, prefix="mujoco/"))
    _, b = read_scalar_series(rrd, *series_location("x1", 2, prefix="ode/"))
    assert len(a) == len(b) == 2000
    assert abs(a - b).max() < 1e-8


@pytest.mark.parametrize("M,m,l", [(5.0, 0.5, 1.0), (20.0, 2.0, 0.5), (10.0, 1.0, 6.0)])
def test_crosscheck_holds_with_other_machines(M, m, l):
    scn = override(load_scenario("pendulum_mujoco"),
                   **{"plant.M": M, "plant.m": m, "plant.l": l, "run.duration": 2.0})
    ol = open_loop(scn, duration=10.0)
    assert ol["open_loop_max_dhinge"] < 1e-8, ol
    cl = closed_loop(scn)
    assert cl["closed_loop_max_dhinge"] < 1e-8, cl


def test_crosscheck_fails_beyond_tolerance_with_euler(capsys):
    status = main(["crosscheck", "--duration", "0.5", "--open-loop-duration", "2",
                   "--no-record", "--set", 'plant.integrator="Euler"'])
    assert status == 1
    assert "open_loop_ok" in capsys.readouterr().out


def test_crosscheck_needs_a_domain_with_both_backends(capsys):
    assert main(["crosscheck", "ex2_duffing", "--no-record"]) == 2
    assert "a MuJoCo and an analytic backend" in capsys.readouterr().err


def test_any_mjcf_cartpole_with_named_joints_runs(tmp_path):
    """Another MJCF (joints and actuator renamed, written by MjSpec) runs by naming them."""
    import mujoco

    from tspend.shipped import data_root as project_root

    spec = mujoco.MjSpec.from_file(str(project_root() / "models" / "cartpole.xml"))
    spec.joint("slider").name = "cart_x"
    spec.joint("hinge").name = "pole_angle"
    spec.actuator("force").name = "push"
    spec.actuator("push").target = "cart_x"
    (tmp_path / "mine.xml").write_text(spec.to_xml())
    scn = override(load_scenario("pendulum_mujoco"), **{
        "plant.model": str(tmp_path / "mine.xml"), "plant.slide_joint": "cart_x",
        "plant.hinge_joint": "pole_angle", "plant.actuator": "push", "run.duration": 2.0})
    assert open_loop(scn, duration=2.0)["open_loop_max_tracked"] < 1e-8
    cl = closed_loop(scn)
    # the closed-loop figures are named after the model's own joints, like the open loop's
    assert cl["closed_loop_status_mujoco"] == "completed" and cl["closed_loop_max_dpole_angle"] < 1e-8
