"""Issue 51's hostile inputs and faults (items 12 to 20): each case the issue found, run as
a user would, ends as docs/reliability.md says.  The signal races themselves (a signal
half a second into a start-up) are cases of ``benchmarks/hostile_inputs.py`` (``-k
issue51``); what a test can pin down is here."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from cli_harness import ROOT, assert_intact, tspend, user_files

#: modules a signal guard installed after them would leave a start-up unguarded for
#: seconds (numba's import alone takes one): none may load before the guard
HEAVY = ("numpy", "numba", "mujoco", "rerun", "scipy", "pandas", "casadi", "jax",
         "tspend.loop", "tspend.controllers", "tspend.sweep", "tspend.plants",
         "tspend.studies")


def test_the_signal_guard_is_installed_before_any_heavy_import():
    """Item 13: the modules loaded when ``SignalGuard.install`` runs, for the program's
    own entry point: stdlib and tspend's light CLI only (before, cli/main.py imported
    every command module, cli/sweep.py the runner and numba, ahead of the guard).  Every
    command passes the same ``main`` before its own module is imported."""
    argv = ["show", "ex3_pendulum_ode"]
    probe = textwrap.dedent(f"""
        import sys
        from tspend.runtime import interrupts
        real_install = interrupts.SignalGuard.install
        def install(self):
            loaded = sorted(m for m in sys.modules if m.startswith({HEAVY!r}))
            print("LOADED", loaded, file=sys.stderr, flush=True)
            return real_install(self)
        interrupts.SignalGuard.install = install
        from tspend.cli.main import main
        sys.argv = ["tspend", *{argv!r}]
        try:
            sys.exit(main())
        except SystemExit as exc:  # --help
            sys.exit(exc.code)
        """)
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          cwd=ROOT, timeout=300)
    line = next(l for l in proc.stderr.splitlines() if l.startswith("LOADED"))
    assert line == "LOADED []", line


def test_show_reads_back_a_scenario_that_names_its_model_by_a_relative_path(tmp_path):
    """Item 12: ``tspend show`` of a user's file naming ``model = "M.xml"`` (beside it) wrote
    the model's absolute path, and the read-back check compared the two spellings: exit
    70.  Now the printed scenario runs the same model, from another folder too."""
    user_files(tmp_path)
    shown = tspend("show", "P.toml", cwd=tmp_path)
    assert shown.status == 0, shown.err
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "again.toml").write_text(shown.out)
    model = (tmp_path / "M.xml").resolve()
    assert f'model = "{model}"' in shown.out
    again = tspend("show", "again.toml", cwd=elsewhere)
    assert again.status == 0, again.err
    assert f'model = "{model}"' in again.out


def test_show_into_a_full_stdout_is_an_output_failure(tmp_path):
    """Item 12: ``tspend show NAME > /dev/full`` was an internal error (OSError, exit 70);
    the printed scenario is the command's output, so it is status 5 and one line."""
    with open("/dev/full", "w") as full:
        proc = subprocess.run([sys.executable, "-m", "tspend.cli", "show", "ex3_pendulum_ode"],
                              cwd=tmp_path, stdout=full, stderr=subprocess.PIPE, text=True,
                              timeout=120)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 5, proc.stderr
    assert len(lines) == 1 and "stdout could not be written (No space left" in lines[0]
