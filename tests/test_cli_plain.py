"""What a new user meets outside the checkout: plain help, tspend show and list, extras named
in one line, the scenario search path, and a compact default recording that keeps every
sample of the state, the reference and the applied input."""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

from tspend.cli.main import build_parser, main

RST = ("``", ":mod:", ":class:", ":func:", ":meth:", ":data:", "%%")


def _parsers(parser: argparse.ArgumentParser, name: str = "tspend"):
    yield name, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub, child in action.choices.items():
                yield from _parsers(child, f"{name} {sub}")


def test_every_help_is_plain_text_with_every_option_explained():
    parsers = list(_parsers(build_parser()))
    assert len(parsers) >= 16  # the command, 13 subcommands, figures' three kinds
    for name, parser in parsers:
        text = parser.format_help()
        for mark in RST:
            assert mark not in text, f"{name} --help shows {mark!r}"
        words = set(text.split())
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            assert action.help and action.help.strip(), f"{name}: {action.dest} has no help"
            if action.help is argparse.SUPPRESS:
                continue
            # no word of the help is broken across two lines
            for word in (action.help % vars(action) if "%" in action.help else action.help).split():
                plain = word.replace("``", "'")
                if "`" not in plain and len(plain) > 3:
                    assert plain in words, f"{name} {action.dest}: {plain!r} broken or changed"


def test_every_subcommand_help_ends_with_examples_that_parse_and_names_files_that_exist():
    """Issue 51, item 8: every subcommand's help has the one or two commands a user needs,
    each parsed here; a document it names is a path to a file that is there (the shipped
    copy, in a wheel too: tests/test_wheel.py); possessives read plainly; an option that
    does nothing says so and warns."""
    import re
    import shlex
    from pathlib import Path

    top = build_parser()
    for name, parser in list(_parsers(top))[1:]:
        text = parser.format_help()
        assert "\nexamples:\n" in text, f"{name} --help has no example"
        examples = text.split("\nexamples:\n", 1)[1].splitlines()
        assert examples and all(line.startswith(f"  {name}") or
                                line.startswith(f"  {name.rsplit(' ', 1)[0]}")
                                for line in examples), (name, examples)
        for line in examples:
            argv = shlex.split(line.split("#")[0].split(">")[0])[1:]
            top.parse_args(argv)  # an example that does not parse fails here (UsageError)
        for named in re.findall(r"(\S*docs/[\w/.-]+\.md)", " ".join(text.split())):
            assert Path(named).is_absolute() and Path(named).is_file(), (name, named)
        assert "''s" not in text, name
    export = dict(_parsers(top))["tspend export"].format_help()
    assert "never overwritten" not in export and "complete file" in export
    paper = dict(_parsers(top))["tspend figures paper"]
    assert paper.description and "ex2_duffing" in paper.description
    args = top.parse_args(["figures", "paper", "--pdf"])
    assert "does nothing" in args.deprecations[0]


def test_show_prints_a_scenario_that_runs_the_same(tmp_path, monkeypatch, capsys):
    from tspend.scenario import available_scenarios, load_scenario, parse_scenario
    from tspend.scenario.writer import resolved_document, resolved_toml

    for path in available_scenarios():  # every shipped scenario reads back as itself
        scn = load_scenario(path)
        text = resolved_toml(scn)
        again = parse_scenario(text, str(tmp_path / "x.toml"))
        assert again.run == scn.run and again.plant == scn.plant, path.stem
        doc = resolved_document(scn)
        assert "safety" in doc and "task" in doc and "lambda" in doc["controller"]
    monkeypatch.chdir(tmp_path)
    assert main(["show", "pendulum_mujoco", "--set", "controller.eta=0.01"]) == 0
    shown = capsys.readouterr().out
    assert "# the machine as compiled from cartpole.xml" in shown
    assert "cart_mass            10.0" in shown
    (tmp_path / "mine.toml").write_text(shown)
    a = main(["run", "mine.toml", "--duration", "0.3", "--metrics", "a.json", "--no-record"])
    b = main(["run", "pendulum_mujoco", "--duration", "0.3", "--set", "controller.eta=0.01",
              "--metrics", "b.json", "--no-record"])
    assert a == b == 0
    ma, mb = (json.loads((tmp_path / f).read_text()) for f in ("a.json", "b.json"))
    for key in ("rmse", "rmse_ss", "max_abs_u", "control_energy", "steps"):
        assert ma[key] == mb[key], key


def test_show_refuses_bad_input_in_one_line(capsys):
    assert main(["show", "no_such_scenario"]) == 2
    assert main(["show", "pendulum_mujoco", "--set", "controller.eta=-1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("tspend: error:") for line in err)


def test_scenario_search_path_and_list_long(tmp_path, monkeypatch, capsys):
    from tspend.shipped import data_root

    mine = tmp_path / "lab"
    mine.mkdir()
    text = (data_root() / "scenarios" / "ex2_duffing.toml").read_text()
    (mine / "my_duffing.toml").write_text(text.replace('name = "ex2_duffing"', 'name = "my_duffing"'))
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("TSPEND_SCENARIO_PATH", raising=False)
    assert main(["--scenario-path", str(mine), "list", "--long"]) == 0
    out = capsys.readouterr().out
    assert "my_duffing" in out and "plant duffing, machine (analytic)" in out
    assert f"  {mine}\n" in out  # the search path, in order, ends the listing
    assert main(["list"]) == 0
    assert "my_duffing" not in capsys.readouterr().out  # the option held for its command only
    monkeypatch.setenv("TSPEND_SCENARIO_PATH", str(mine))
    assert main(["run", "my_duffing", "--duration", "0.05", "--no-record"]) == 0


def test_a_module_that_needs_an_extra_names_it_in_one_line():
    code = ("import sys; sys.modules['gymnasium'] = None\n"
            "try:\n    import tspend.gym\nexcept ImportError as exc:\n    print(exc)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip().splitlines() == [
        "tspend.gym needs gymnasium, an optional extra: pip install 'tspend[gym]'"]


def test_controller_help_names_only_extras_that_exist():
    import tomllib
    from pathlib import Path

    from tspend.controllers import help_text

    extras = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())
    defined = set(extras["project"]["optional-dependencies"])
    import re

    named = set(re.findall(r"tspend\[([a-z]+)\]", help_text()))
    assert named <= defined
    assert all(extras["project"]["optional-dependencies"][e] for e in defined)  # none empty


def test_compact_recording_keeps_every_sample(tmp_path, monkeypatch):
    """The default run's recording: every sample of the state, r and u as the run had them,
    the diagnostics thinned, and about a third of the full recording's size."""
    import tspend
    from tspend.recorder.timeseries import recording_table

    monkeypatch.chdir(tmp_path)
    assert main(["run", "--duration", "2", "--out", "c.rrd", "--metrics", "m.json"]) == 0
    assert main(["run", "--duration", "2", "--out", "f.rrd", "--diagnostics-hz", "0"]) == 0
    compact, full = (tmp_path / "c.rrd").stat().st_size, (tmp_path / "f.rrd").stat().st_size
    assert compact < 0.7 * full  # 2 s: the layout's fixed part weighs (20 s: 3.9 MB vs 12 MB)
    table, _ = recording_table(tmp_path / "c.rrd")
    whole, _ = recording_table(tmp_path / "f.rrd")
    ref = tspend.run("pendulum_mujoco", duration=2.0).to_pandas()
    assert len(table) == len(ref) == 2000
    for column in ("hinge_rad", "hinge_dot_rad_s", "slider_m", "slider_dot_m_s", "ref_rad", "u_N",
                   "d_N"):
        assert table[column].notna().all(), column
        np.testing.assert_array_equal(table[column].to_numpy(), whole[column].to_numpy())
        np.testing.assert_array_equal(table[column].to_numpy(), ref[column].to_numpy())
    assert table["e_hinge_rad"].notna().sum() == 100  # a diagnostic at 50 Hz


def test_mjx_is_imported_without_warps_lines():
    """MJX prints "Failed to import warp: ..." twice on stdout at its first import when
    NVIDIA Warp is missing (here it is): tspend's import of MJX, before every sweep and env
    of the mjx backend, holds them back (issue 51, item 5)."""
    pytest.importorskip("mujoco.mjx")
    code = ("from tspend.mjx import set_precision; set_precision('float64'); "
            "from mujoco import mjx; print('imported', mjx.__name__)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout == "imported mujoco.mjx\n" and "warp" not in done.stderr.lower()


def test_a_slow_step_says_what_it_is_how_long_it_takes_and_took():
    """Issue 51, item 4: a step past its delay gets one line naming it with its estimate,
    then one with the time it took; a quick step prints nothing; a failed one no "done"
    (its error says what happened). Off a terminal: whole lines, no counting in place."""
    import io
    import time

    from tspend.runtime.progress import PROGRESS_PREFIX, SlowStep

    out = io.StringIO()
    with SlowStep("designing", "about 1 s", stream=out, after=0.05):
        time.sleep(0.4)
    lines = out.getvalue().splitlines()
    assert lines[0] == f"{PROGRESS_PREFIX}designing (about 1 s)..."
    assert lines[1].startswith(f"{PROGRESS_PREFIX}designing: done in ") and len(lines) == 2
    quick = io.StringIO()
    with SlowStep("designing", "about 1 s", stream=quick, after=5.0):
        pass
    assert quick.getvalue() == ""
    failed = io.StringIO()
    with pytest.raises(ValueError), SlowStep("designing", "about 1 s", stream=failed, after=0.05):
        time.sleep(0.3)
        raise ValueError("bad")
    assert failed.getvalue().splitlines() == [f"{PROGRESS_PREFIX}designing (about 1 s)..."]
