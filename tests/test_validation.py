"""Bad input: each kind gives exit status 2 and a one-line message naming file and key."""

from pathlib import Path

import pytest

from tspend.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
ODE = (ROOT / "scenarios" / "ex3_pendulum_ode.toml").read_text()
MJ = (ROOT / "scenarios" / "pendulum_mujoco.toml").read_text()


def _run(tmp_path, text, capsys, *extra):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    status = main(["run", str(path), "--no-record", "--duration", "0.01", *extra])
    err = capsys.readouterr().err.strip()
    return status, err


def _replace(text, old, new):
    assert old in text, old
    return text.replace(old, new, 1)


CASES = [
    # (name, base, old, new, words that must appear in the message)
    ("unknown key", ODE, "eta = 0.006", "etaa = 0.006", ["controller.etaa", "did you mean 'eta'"]),
    ("unknown top table", ODE, "[run]", "[runn]", ["runn", "did you mean 'run'"]),
    ("wrong type", ODE, "eta = 0.006", 'eta = "fast"', ["controller.eta", "must be a number"]),
    ("wrong list type", ODE, "x0 = [0.10471975511965977, 0.0]", "x0 = 0.1", ["plant.x0", "list"]),
    ("zero dt", ODE, "dt = 0.001", "dt = 0.0", ["run.dt", "> 0"]),
    ("negative duration", ODE, "duration = 20.0", "duration = -1.0", ["run.duration", "> 0"]),
    ("not hurwitz", ODE, "lambda = [1.0, 2.0]", "lambda = [1.0, -2.0]", ["controller.lambda", "Hurwitz"]),
    ("Q not symmetric", ODE, "Q = [[10.0, 0.0], [0.0, 10.0]]", "Q = [[10.0, 1.0], [0.0, 10.0]]",
     ["controller.Q", "symmetric"]),
    ("Q not positive definite", ODE, "Q = [[10.0, 0.0], [0.0, 10.0]]",
     "Q = [[1.0, 0.0], [0.0, -1.0]]", ["controller.Q", "positive definite"]),
    ("interval lo >= hi", ODE, "u = {terms = 3, lo = -1000.0, hi = 1000.0}",
     "u = {terms = 3, lo = 1000.0, hi = -1000.0}", ["controller.sets.u.lo", "lo < hi"]),
    ("too few control points", ODE, "control_points = 9", "control_points = 2",
     ["controller.control_points", "bspline_order"]),
    ("b_min <= 0", ODE, "b_min = 0.001", "b_min = 0.0", ["controller.b_min", "> 0"]),
    ("nan", ODE, "gamma = 1.6", "gamma = nan", ["controller.gamma", "finite"]),
    ("inf in list", ODE, "x0 = [0.10471975511965977, 0.0]", "x0 = [inf, 0.0]", ["plant.x0", "finite"]),
    ("unknown plant", ODE, 'kind = "cartpole_ode"', 'kind = "cartpol_ode"',
     ["plant.kind", "did you mean 'cartpole_ode'", "allowed"]),
    ("unknown reference", ODE, 'kind = "sine"', 'kind = "sinus"', ["reference.kind", "allowed"]),
    ("unknown disturbance", ODE, 'kind = "square"', 'kind = "triangle"', ["disturbance.kind", "allowed"]),
    ("key of another plant kind", ODE, "M = 10.0", "M = 10.0\nmodel = 'x.xml'",
     ["plant.model", "cartpole_ode"]),
    ("bad TOML", ODE, "[run]", "[run", ["not valid TOML"]),
    ("missing model", MJ, 'model = "models/cartpole.xml"', 'model = "models/nope.xml"',
     ["nope.xml", "not found"]),
    ("missing joint", MJ, 'hinge_joint = "hinge"', 'hinge_joint = "pole"',
     ["no hinge joint named 'pole'", "slider, hinge"]),
    ("missing actuator", MJ, 'actuator = "force"', 'actuator = "motor"',
     ["no actuator named 'motor'"]),
    ("dt not a multiple of the timestep", MJ, "dt = 0.001", "dt = 0.0015",
     ["dt=0.0015", "multiple", "timestep"]),
]


@pytest.mark.parametrize("name,base,old,new,words", CASES, ids=[c[0] for c in CASES])
def test_bad_scenario_exit_2_with_clear_message(tmp_path, capsys, name, base, old, new, words):
    status, err = _run(tmp_path, _replace(base, old, new), capsys)
    assert status == 2, err
    assert err.startswith("tspend: error:") and "\n" not in err, err
    for w in words:
        assert w in err, (w, err)
    if name not in ("missing model", "missing joint", "missing actuator",
                    "dt not a multiple of the timestep"):
        assert "bad.toml" in err


def test_unknown_scenario_name(capsys):
    assert main(["run", "ex3_pendulum_odee", "--no-record"]) == 2
    err = capsys.readouterr().err
    assert "did you mean 'ex3_pendulum_ode'" in err


def test_bad_override(capsys):
    assert main(["run", "ex2_duffing", "--no-record", "--set", "controller.eta=-1"]) == 2
    assert "controller.eta" in capsys.readouterr().err
    assert main(["run", "ex2_duffing", "--no-record", "--set", "controller.etta=1"]) == 2
    assert "did you mean 'eta'" in capsys.readouterr().err


def test_unwritable_output_reported_before_run(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    status = main(["run", "ex2_duffing", "--duration", "0.01", "--metrics",
                   str(blocker / "sub" / "m.json"), "--no-record"])
    assert status == 2
    err = capsys.readouterr().err
    assert "is not a directory" in err and "m.json" in err


def test_debug_shows_traceback(capsys):
    assert main(["run", "nope_not_here", "--no-record", "--debug"]) == 2
    assert "Traceback" in capsys.readouterr().err


def test_unwritable_recording_reported_before_run(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    status = main(["run", "ex2_duffing", "--duration", "0.01", "--out", str(blocker / "r.rrd")])
    assert status == 2
    err = capsys.readouterr().err
    assert "--out" in err and "is not a directory" in err


def test_every_controller_field_is_a_declared_setting(tmp_path):
    """The paper's [controller] table is read like every kind's [controllers.KIND] table:
    each ControllerConfig field is declared with setting() (its key, kind and bounds), the
    sets in [controller.sets]; an unknown key is one line naming file, key and the keys
    allowed."""
    import dataclasses

    from tspend.config import ControllerConfig
    from tspend.controllers.settings import key_of
    from tspend.runtime.errors import ScenarioError
    from tspend.scenario import load_scenario

    fields = dataclasses.fields(ControllerConfig)
    assert all("kind" in f.metadata for f in fields)
    assert {key_of(f) for f in fields if f.metadata["table"] == "sets"} == {
        "states", "u", "e_delta", "x_norm"}
    text = (ROOT / "scenarios" / "ex2_duffing.toml").read_text()
    for table, bad in (("[controller]", "etta = 0.1"), ("[controller.sets]", "stats = 1")):
        path = tmp_path / f"{bad[:4]}.toml"
        path.write_text(text.replace(table, f"{table}\n{bad}", 1) if table in text
                        else text + f"\n{table}\n{bad}\n")
        with pytest.raises(ScenarioError) as err:
            load_scenario(str(path))
        key = "controller.etta" if bad.startswith("etta") else "controller.sets.stats"
        assert f"{path}: {key}: unknown key" in str(err.value), err.value
        assert ("eta" if bad.startswith("etta") else "states") in str(err.value).split("allowed")[1]
