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
