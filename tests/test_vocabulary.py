"""One vocabulary from install to export (issue 35, and issue 33's CSV): one name per
quantity in the metrics, the export and ``to_pandas``; one set of flags with the old
spellings kept one release; controllers as documented; missing extras named before any
work; a summary with units.  Every test runs in process on the fast ODE plant."""

from __future__ import annotations

import json
import sys
import textwrap

import numpy as np
import pandas as pd
import pytest

import tspend
from tspend.cli.main import build_parser, main
from tspend.controllers.base import Controller


class NoDiag(Controller):
    """A PD law written as docs/writing-a-controller.md says: no kind, no diagnostics, no diag."""

    def __init__(self, scenario) -> None:
        self.order = len(scenario.plant.x0)

    def reset(self, rng) -> None:
        pass

    def step(self, obs, dt: float) -> float:
        e = obs.x - obs.ref[: self.order]
        return float(-400.0 * e[0] - 100.0 * e[1])


def test_export_csv_reads_with_no_arguments_and_names_the_angle_as_metrics_and_to_pandas(
        tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["run", "ex3_pendulum_ode", "--controller", "pd", "--duration", "0.2",
                 "--out", "x.rrd", "--metrics", "m.json"]) == 0
    assert main(["export", "x.rrd", "--out", "x.csv"]) == 0
    table = pd.read_csv(tmp_path / "x.csv")  # no arguments: one header row, no comments
    metrics = json.loads((tmp_path / "m.json").read_text())
    frame = tspend.run("ex3_pendulum_ode", controller="pd", duration=0.2).to_pandas()
    # the angle: the model's joint "hinge" everywhere, its unit at the end of a column
    assert "hinge" in metrics["joints"]
    assert "hinge_rad" in table.columns and "hinge_rad" in frame.columns
    # each rate its own table (diagnostics at 50 Hz beside it): together, to_pandas' columns
    slow = pd.read_csv(tmp_path / "x.50Hz.csv")
    assert set(table.columns) | set(slow.columns) == {"t_s", *frame.columns}
    np.testing.assert_array_equal(table["hinge_rad"].to_numpy(), frame["hinge_rad"].to_numpy())
    assert abs(metrics["joints"]["hinge"]["max_abs"] - table["hinge_rad"].abs().max()) < 1e-12
    side = json.loads((tmp_path / "x.csv.json").read_text())
    assert side["scenario"] == "ex3_pendulum_ode" and side["columns"] == list(table.columns)


def test_a_controller_without_diag_runs_from_the_command_line_and_from_python(tmp_path):
    plugin = tmp_path / "mine.py"
    plugin.write_text(textwrap.dedent('''
        from tspend.controllers.base import Controller

        class Mine(Controller):
            def __init__(self, scenario):
                self.order = len(scenario.plant.x0)

            def reset(self, rng):
                pass

            def step(self, obs, dt):
                e = obs.x - obs.ref[: self.order]
                return float(-400.0 * e[0] - 100.0 * e[1])
    '''))
    assert main(["run", "ex3_pendulum_ode", "--controller", f"{plugin}:Mine", "--duration",
                 "0.2", "--no-record"]) == 0
    by_class = tspend.run("ex3_pendulum_ode", controller=NoDiag, duration=0.3)
    assert by_class.status == "completed"
    instance = NoDiag(tspend.load_scenario("ex3_pendulum_ode"))
    by_instance = tspend.run("ex3_pendulum_ode", controller=instance, duration=0.3)
    assert by_instance.controller is instance
    # the same law, so the same run, however it was named
    np.testing.assert_array_equal(by_class.history["u"], by_instance.history["u"])
    assert by_class.metrics["rmse"] < 0.2


def test_run_refuses_what_is_not_a_controller() -> None:
    from tspend.runtime.errors import ScenarioError

    with pytest.raises(ScenarioError, match="not a Controller"):
        tspend.run("ex3_pendulum_ode", controller=dict, duration=0.1)


def test_deprecated_spellings_still_work_and_warn_once(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["run", "ex3_pendulum_ode", "--duration", "0.1", "--out", "x.rrd"]) == 0
    capsys.readouterr()
    assert main(["export", "x.rrd", "--to", "x.parquet"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err == ["tspend: warning: --to is deprecated and goes in the next release; use --out"]
    assert (tmp_path / "x.parquet").exists()
    parser = build_parser()
    for argv in (["crosscheck", "--json", "c.json"], ["compare", "ex2_duffing", "--json", "c.json"],
                 ["inspect", "m.xml", "--json", "c.json"]):
        args = parser.parse_args(argv)
        assert args.metrics == "c.json" and args.deprecations, argv
    # compare's old --metrics M1,M2 (the metrics compared) is read the old way, with a warning
    from tspend.cli.compare import _old_metric_list

    args = parser.parse_args(["compare", "ex2_duffing", "--metrics", "rmse,iae"])
    _old_metric_list(args)
    assert (args.metric, args.metrics) == ("rmse,iae", None)
    assert "--metric M1,M2" in capsys.readouterr().err


def test_crosscheck_json_alias_writes_the_metrics_file(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    status = main(["crosscheck", "ex3_pendulum_ode", "--duration", "0.05",
                   "--open-loop-duration", "0.05", "--no-record", "--json", "cc.json"])
    assert status in (0, 1)
    assert "open_loop_ok" in json.loads((tmp_path / "cc.json").read_text())
    assert "--json is deprecated" in capsys.readouterr().err


@pytest.mark.parametrize("module, argv, extra", [
    ("optuna", ["tune", "ex3_pendulum_ode", "--controller", "pd", "--trials", "2", "--seeds",
                "0:1", "--out", "t.toml"], "tune"),
    ("matplotlib", ["figures", "paper", "--out", "figs"], None),
    ("dask.distributed", ["sweep", "ex2_duffing", "--dask", "local"], "dask"),
    ("onnxruntime", ["run", "ex3_pendulum_ode", "--controller", "policy"], "rl"),
])
def test_a_missing_extra_is_one_line_naming_it_before_any_work(module, argv, extra, tmp_path,
                                                                monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setitem(sys.modules, module, None)  # as if not installed
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    # an extra by its name; a core dependency (matplotlib) by its package
    assert (f"pip install 'tspend[{extra}]'" if extra else "pip install matplotlib") in err[0]
    assert list(tmp_path.iterdir()) == []  # nothing written, nothing computed


def test_errors_say_tspend_once(capsys) -> None:
    assert main(["run", "--no-such-flag"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tspend: error: ") and "tspend: error: tspend" not in err


def test_list_prints_whole_descriptions_and_help_is_plain_text(capsys, monkeypatch) -> None:
    monkeypatch.setenv("COLUMNS", "90")
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert "..." not in out.replace("(...)", "") or "seco..." not in out
    assert all(len(line) <= 90 for line in out.splitlines())
    description = tspend.load_scenario("ex1_nonaffine_case1_tuned").description
    assert " ".join(description.split())[-30:] in " ".join(out.split())
    assert main(["run", "--controller", "help"]) == 0
    assert "`" not in capsys.readouterr().out


def test_summary_prints_units_excursions_saturation_and_events(capsys) -> None:
    from tspend.cli.run import print_summary

    metrics = {"rmse": 0.01, "max_abs_u": 10.0, "max_abs_u_command": 5084.0,
               "control_energy": 3.0, "saturated_fraction": 0.9956, "caught_at_s": 2.5,
               "goal": {"angle_rad": 0.2, "by_s": 8.0, "reached_at_s": None},
               "joints": {"arm": {"max_abs": 5.1}, "pendulum": {"max_abs": 0.05}}}
    print_summary(metrics, {"e": "rad", "u": "V", "states": {"arm": "rad", "pendulum": "rad"}})
    out = capsys.readouterr().out
    assert "rmse" in out and "0.01 rad" in out and "10 V" in out and "V^2 s" in out
    assert "arm 5.1 rad, pendulum 0.05 rad" in out
    assert "saturation" in out and "99.6 %" in out and "5084 V" in out
    assert "caught_at_s" in out and "2.5 s" in out and "not reached" in out
    print_summary({"rmse": 0.01, "saturated_fraction": 0.001}, {"e": "rad", "u": "N"})
    assert "saturation" not in capsys.readouterr().out


def test_summary_says_what_the_paper_controller_leaves_free_and_what_mpsc_counted(capsys):
    """Issue 51, items 9 and 10: the default run's "largest |joint| slider 42.79 m" says the
    paper's controller regulates the pole only and how to keep the cart; a full-state
    controller gets no such line. The mpsc counts say what each one counts."""
    from tspend.cli.run import print_summary

    assert main(["run", "--duration", "0.05", "--no-record"]) == 0
    out = capsys.readouterr().out
    note = out.split("largest |joint|", 1)[1].splitlines()[1]
    assert "slider not regulated: second_type, the paper's controller, regulates hinge" in note
    assert "--controller lqr" in note and "effects.rail" in note
    assert main(["run", "--duration", "0.05", "--no-record", "--controller", "lqr"]) == 0
    assert "not regulated" not in capsys.readouterr().out
    safety = {"filter": "mpsc", "solver": "hpipm", "samples": 20000, "intervention_share": 0.68,
              "mean_abs_du": 1.0, "qp_ms": {"median": 0.46}, "fallbacks": 4490, "no_plan": 3,
              "infeasible_samples": 6}
    print_summary({"rmse": 0.01, "safety_filter": safety}, {"e": "rad", "u": "N"})
    out = capsys.readouterr().out
    assert "4490 samples on the last certified plan" in out
    assert "3 on an uncertified recovery plan" in out and "6 plan QPs that failed" in out
