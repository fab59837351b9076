"""Controllers from outside the package: ``file.py:Class``, ``package.module:Class`` and
entry points, through the CLI as a user types it; bad specs exit 2 with one line.

The example's behaviour is checked against its own law recomputed from the run's
history (u = clip(-(kp e + kd e'), +/- u_max)), and the metrics JSON against the
settings given on the command line.
"""

from __future__ import annotations

import json
import os
import shutil
import textwrap
from pathlib import Path

import numpy as np
import pytest

from cli_harness import ROOT, tspend
from tspend.cli.main import main

EXAMPLE = "examples/custom_controller.py:SaturatedPD"


def in_process(capsys, *args: str) -> tuple[int, str, list[str]]:
    """``tspend ARGS`` in this process (cheap: the imports are done): status, stdout and
    the stderr lines."""
    status = main(list(args))
    captured = capsys.readouterr()
    return status, captured.out, [line for line in captured.err.splitlines() if line.strip()]


@pytest.fixture()
def workdir(tmp_path: Path) -> Path:
    """A user's directory holding a copy of the example."""
    (tmp_path / "examples").mkdir()
    shutil.copy(ROOT / "examples" / "custom_controller.py", tmp_path / "examples")
    return tmp_path


def test_example_runs_through_the_cli_and_the_metrics_say_what_ran(workdir: Path) -> None:
    r = tspend("run", "ex3_pendulum_ode", "--controller", EXAMPLE, "--metrics", "m.json",
               "--no-record", "--duration", "2", "--set", "controllers.saturated_pd.kp=2500",
               cwd=workdir)
    assert r.status == 0, r.err
    doc = json.loads((workdir / "m.json").read_text())
    assert doc["status"] == "completed"
    assert doc["controller"]["kind"] == "saturated_pd"
    assert doc["controller"]["spec"] == EXAMPLE
    assert doc["controller"]["settings"] == {"kp": 2500.0, "kd": 500.0, "k_cart": 0.0,
                                             "u_max": 300.0}


def test_example_computes_its_documented_law() -> None:
    import tspend

    old = os.getcwd()
    os.chdir(ROOT)
    try:
        res = tspend.run("ex3_pendulum_ode", controller=EXAMPLE, duration=1.0,
                         overrides={"controllers.saturated_pd.u_max": 20.0})
    finally:
        os.chdir(old)
    h = res.history
    e = h["x"] - h["ref"][:, :2]
    law = -(2000.0 * e[:, 0] + 500.0 * e[:, 1])  # k_cart = 0 by default
    np.testing.assert_allclose(h["u_unclipped"], law, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(h["u"], np.clip(law, -20.0, 20.0))
    assert np.any(np.abs(law) > 20.0)  # the clip was exercised


def test_package_module_spec_and_entry_point(tmp_path: Path, monkeypatch, capsys) -> None:
    pkg = tmp_path / "site" / "mypkg"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "ctl.py").write_text(textwrap.dedent('''
        import numpy as np

        from tspend.controllers.base import Controller

        class Zero(Controller):
            """u = 0 always."""
            kind = "zero_force"

            def __init__(self, scenario):
                self.order = len(scenario.plant.x0)
                self.diagnostics = ()
                self.diag = np.zeros(0)

            def reset(self, rng):
                pass

            def step(self, obs, dt):
                return 0.0
        '''))
    # an installed distribution's metadata, as pip would write it
    dist = tmp_path / "site" / "mypkg-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: mypkg\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[tspend.controllers]\nzero = mypkg.ctl:Zero\n")
    monkeypatch.syspath_prepend(str(tmp_path / "site"))  # importlib.metadata reads sys.path
    monkeypatch.chdir(tmp_path)
    for spec in ("mypkg.ctl:Zero", "zero"):
        out = f"{spec.replace(':', '_')}.json"
        status, _, err = in_process(capsys, "run", "ex2_duffing", "--controller", spec,
                                    "--no-record", "--duration", "0.5", "--metrics", out)
        assert status == 0, err
        doc = json.loads((tmp_path / out).read_text())
        assert doc["controller"]["kind"] == "zero_force" and doc["max_abs_u"] == 0.0
    status, listed, _ = in_process(capsys, "run", "--controller", "help")
    assert status == 0
    assert any(line.split()[0] == "zero" and "zero_force" in line for line in listed.splitlines())


@pytest.mark.parametrize("spec, words", [
    ("nothere.py:X", ["nothere.py", "no such file"]),
    ("examples/custom_controller.py:Nope", ["has no 'Nope'", "SaturatedPD"]),
    ("examples/custom_controller.py:Settings", ["not a Controller"]),
    ("json:dumps", ["building it failed"]),
    ("no_such_package_x.mod:C", ["no module named"]),
    ("numpy:pi", ["not a Controller"]),
    ("lqrr", ["unknown kind", "file.py:Class"]),
])
def test_bad_spec_exits_2_with_one_line_and_writes_nothing(workdir: Path, monkeypatch, capsys,
                                                          spec, words) -> None:
    monkeypatch.chdir(workdir)
    status, _, err = in_process(capsys, "run", "ex3_pendulum_ode", "--controller", spec,
                                "--metrics", "m.json", "--out", "r.rrd")
    assert status == 2 and len(err) == 1 and all(w in err[0] for w in words), err
    assert sorted(p.name for p in workdir.iterdir()) == ["examples"]  # nothing written


def test_plugin_setting_is_validated_like_a_builtin(workdir: Path, monkeypatch, capsys) -> None:
    monkeypatch.chdir(workdir)
    status, _, err = in_process(capsys, "run", "ex3_pendulum_ode", "--controller", EXAMPLE,
                                "--no-record", "--set", "controllers.saturated_pd.u_max=-1")
    assert status == 2 and len(err) == 1 and "u_max" in err[0], err


@pytest.mark.parametrize("command", ["run", "sweep", "compare", "figures paper"])
def test_controller_help_lists_every_kind(tmp_path: Path, monkeypatch, capsys, command) -> None:
    from tspend.controllers import KINDS

    monkeypatch.chdir(tmp_path)
    args = command.split() + (["ex2_duffing"] if command in ("sweep", "compare") else [])
    status, out, err = in_process(capsys, *args, "--controller", "help")
    assert status == 0 and not err, err
    lines = out.splitlines()
    for kind in KINDS:
        assert sum(line.split()[0] == kind for line in lines) == 1, (kind, out)
    assert all(len(line.split(maxsplit=1)) == 2 for line in lines)  # a name and a description
    assert list(tmp_path.iterdir()) == []


def test_builtin_kind_records_its_settings(tmp_path: Path, monkeypatch, capsys) -> None:
    from dataclasses import fields

    from tspend.controllers import KINDS

    monkeypatch.chdir(tmp_path)
    status, _, err = in_process(capsys, "run", "ex2_duffing", "--controller", "lqr",
                                "--duration", "0.5", "--no-record", "--metrics", "m.json",
                                "--set", "controllers.lqr.R=0.5")
    assert status == 0, err
    ctl = json.loads((tmp_path / "m.json").read_text())["controller"]
    assert ctl["kind"] == "lqr" and ctl["settings"]["R"] == 0.5
    assert set(ctl["settings"]) == {f.name for f in fields(KINDS["lqr"].Settings)}
    status, _, err = in_process(capsys, "run", "ex2_duffing", "--duration", "0.5", "--no-record",
                                "--metrics", "p.json", "--set", "controller.adaptation=first")
    ctl = json.loads((tmp_path / "p.json").read_text())["controller"]
    assert ctl["kind"] == "first_type" and ctl["settings"]["adaptation"] == "first"


def test_compare_runs_a_plugin_and_names_it_by_its_kind(workdir: Path, monkeypatch,
                                                       capsys) -> None:
    import pandas as pd

    monkeypatch.chdir(workdir)
    status, out, err = in_process(capsys, "compare", "ex2_duffing", "--seeds", "0:3",
                                  "--controller", f"{EXAMPLE},pd", "--duration", "0.5",
                                  "--jobs", "1", "--resamples", "100", "--out", "c.parquet",
                                  # the plug-in's settings travel to the worker processes
                                  "--set", "controllers.saturated_pd.u_max=250")
    assert status == 0, err
    assert "saturated_pd" in out
    table = pd.read_parquet(workdir / "c.parquet")  # the sweep's rows, by kind
    assert sorted(set(table["controller"])) == ["pd", "saturated_pd"]
    assert (table["status"] == "completed").all() and len(table) == 6


def test_list_prints_every_scenario_with_its_whole_description(tmp_path: Path) -> None:
    from tspend.scenario import available_scenarios, load_scenario

    r = tspend("list", cwd=tmp_path, env={**os.environ, "COLUMNS": "100"})
    assert r.status == 0
    paths = available_scenarios()
    listing, _, searched = r.out.partition("\n\nsearched, in order")
    assert str(tmp_path / "scenarios") in searched  # the search path closes the listing
    lines = listing.splitlines()
    # a scenario's first line starts with its name; its description's rest is indented
    assert [line.split()[0] for line in lines if not line.startswith(" ")] == [
        p.stem for p in paths]
    assert all(len(line) <= 100 for line in lines)
    words = " ".join(r.out.split())
    for p in paths:
        assert " ".join(load_scenario(p).description.split()) in words.replace(
            " (default) ", " ")


def test_installed_plant_domain_runs_like_a_builtin(tmp_path: Path) -> None:
    """A package registers a domain under ``tspend.plants``: a scenario names its kind.

    The domain here is Duffing's physics under another name, so its run must give
    Duffing's metrics exactly; a clashing registration is left out with a warning.
    """
    site = tmp_path / "site"
    (site / "myplants").mkdir(parents=True)
    (site / "myplants" / "__init__.py").write_text(textwrap.dedent('''
        from tspend.plants.analytic import DUFFING, ChainDomain, duffing_accel

        MY_DUFFING = ChainDomain("my_duffing", duffing_accel, 2, True, 20.0, DUFFING.labels)
        CLASH = ChainDomain("duffing", duffing_accel, 2, True, 20.0, DUFFING.labels)
        '''))
    dist = site / "myplants-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: myplants\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(
        "[tspend.plants]\nmy_duffing = myplants:MY_DUFFING\nclash = myplants:CLASH\n")
    text = (ROOT / "scenarios" / "ex2_duffing.toml").read_text()
    assert 'kind = "duffing"' in text
    (tmp_path / "mine.toml").write_text(text.replace('kind = "duffing"', 'kind = "my_duffing"'))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(site), str(ROOT)]))
    for scenario, out in (("mine.toml", "mine.json"), ("ex2_duffing", "theirs.json")):
        r = tspend("run", scenario, "--duration", "1", "--no-record", "--metrics", out,
                   cwd=tmp_path, env=env)
        assert r.status == 0, r.err
        assert "plant plug-in left out: [tspend.plants] clash: duffing already taken" in r.err
    mine, theirs = (json.loads((tmp_path / f).read_text()) for f in ("mine.json", "theirs.json"))
    assert mine["rmse"] == theirs["rmse"] and mine["control_energy"] == theirs["control_energy"]


def test_a_plugin_without_its_order_is_bad_input(workdir: Path, monkeypatch, capsys) -> None:
    monkeypatch.chdir(workdir)
    (workdir / "examples" / "no_order.py").write_text(textwrap.dedent('''
        import numpy as np
        from tspend.controllers.base import Controller

        class NoOrder(Controller):
            kind = "no_order"
            diagnostics = ()
            diag = np.zeros(0)

            def __init__(self, scenario, settings=None):
                pass

            def reset(self, rng):
                pass

            def step(self, obs, dt):
                return 0.0
    '''))
    status, _, err = in_process(capsys, "run", "ex3_pendulum_ode", "--controller",
                                "examples/no_order.py:NoOrder", "--metrics", "m.json")
    assert status == 2 and len(err) == 1 and "'order' must be a positive int" in err[0], err
    assert not (workdir / "m.json").exists()
