"""Hostile input: every bad input is exit 2 and one line, before anything is written;
signals from the first instant; no stray files from the native libraries.

The cases the issue found reported as "internal error", the resource bounds, signals
during start-up and during cleanup.  Each asserts the exit status, the single stderr
line and that the user's files (``cli_harness.user_files``) are byte-for-byte intact.
``benchmarks/hostile_inputs.py`` runs the 600-case sweep over every command.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rerun.chunk import RrdReader

from cli_harness import ROOT, assert_intact, snapshot, spawn, tspend, user_files
from tspend.runtime.progress import PROGRESS_PREFIX

SHORT = ("--duration", "0.05")
OUT = ("--out", "K.rrd", "--metrics", "K.json")


def _model(tmp_path: Path, timestep: str) -> None:
    text = (ROOT / "models" / "cartpole.xml").read_text()
    (tmp_path / "Q.xml").write_text(text.replace('timestep="0.001"', f'timestep="{timestep}"'))


#: (argv, setup, a phrase of the expected line); every one used to be an internal error
INTERNAL_ERROR_CASES = {
    "TOML nested 100k deep": (("run", "X.toml"), "x = " + "[" * 100_000 + "]" * 100_000,
                              "nested more than 32 levels"),
    "5000-digit seed in the file": (("run", "X.toml"), "seed", "not valid TOML"),
    "5000-digit --seed": (("run", "S.toml", "--seed", "9" * 5000), None, "argument --seed"),
    "snapshot_every=1e308": (("run", "S.toml", "--set", "run.snapshot_every=1e308"), None,
                             "run.snapshot_every"),
    "terms=10**18": (("run", "S.toml", "--set",
                      "controller.sets.u={terms=1000000000000000000, lo=-1.0, hi=1.0}"), None,
                     "controller.sets.u.terms: must be from 1 to 50"),
    "NUL in name": (("run", "S.toml", "--set", 'name="a\\u0000b"'), None,
                    "contains the control character '\\x00'"),
    "open loop -5": (("crosscheck", "P.toml", "--open-loop-duration", "-5"), None,
                     "--open-loop-duration"),
    "open loop nan": (("crosscheck", "P.toml", "--open-loop-duration", "nan"), None,
                      "--open-loop-duration"),
    "open loop 1e9": (("crosscheck", "P.toml", "--open-loop-duration", "1e9"), None,
                      "--open-loop-duration 1e+09: must be from dt"),
    "open loop 0": (("crosscheck", "P.toml", "--open-loop-duration", "0"), None,
                    "--open-loop-duration"),
    "port above 65535": (("run", "S.toml", "--connect", "rerun+http://127.0.0.1:70000/proxy"),
                         None, "the port must be a number from 1 to 65535"),
    "MJCF timestep 0": (("run", "Q.toml"), "0", "option timestep must be a positive number"),
    "MJCF timestep nan": (("run", "Q.toml"), "nan", "XML contains a 'NaN'"),
    "--out /dev/full": (("run", "S.toml", "--out", "/dev/full"), None, "must end in .rrd"),
    "--metrics /proc": (("run", "S.toml", "--metrics", "/proc/version.json"), None,
                        "cannot create a file in /proc"),
    "300-character file name": (("run", "S.toml", "--out", "x" * 296 + ".rrd"), None,
                                "the file name is 300 bytes long"),
    "--set trailing text after a newline": (("run", "S.toml", "--set", "run.seed=1\nrun.dt=9"),
                                            None, "must be one line"),
    "--set more TOML after the value": (("run", "S.toml", "--set", "run.seed=1, x=2"), None,
                                        "run.seed: must be an integer"),
}


@pytest.mark.parametrize("case", list(INTERNAL_ERROR_CASES))
def test_former_internal_errors_are_bad_input(tmp_path, case):
    argv, setup, phrase = INTERNAL_ERROR_CASES[case]
    user_files(tmp_path)
    if argv[1] == "X.toml":
        text = setup if setup != "seed" else (ROOT / "scenarios" / "ex2_duffing.toml").read_text(
            ).replace("seed = 1", "seed = " + "7" * 5000)
        (tmp_path / "X.toml").write_text(text)
    if argv[1] == "Q.toml":
        _model(tmp_path, setup)
        (tmp_path / "Q.toml").write_text((tmp_path / "P.toml").read_text().replace(
            'model = "M.xml"', 'model = "Q.xml"'))
    before = snapshot(tmp_path)
    extra = ()
    if argv[0] == "run":  # aim every output the case leaves free at the user's files
        extra = (*(("--out", "K.rrd") if "--out" not in argv else ()),
                 *(("--metrics", "K.json") if "--metrics" not in argv else ()))
    r = tspend(*argv, *SHORT, *extra, cwd=tmp_path)
    line = r.one_error_line()
    assert r.status == 2, r.err
    assert line.startswith("tspend: error: ") and phrase in line, line
    assert r.out == ""  # rejected before the banner
    assert_intact(tmp_path, before)
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


@pytest.mark.parametrize("settings,phrase", [
    (("controller.control_points=1000000",), "control_points: must be from 1 to 64"),
    (("controller.sets.u={terms=1000, lo=-1.0, hi=1.0}",), "terms: must be from 1 to 50"),
    (("controller.sets.states=[{terms=50, lo=-1.0, hi=1.0}, {terms=50, lo=-1.0, hi=1.0}]",
      "controller.sets.u={terms=5, lo=-1.0, hi=1.0}"), "would have 12500 rules, more than 10000"),
    (("run.dt=1e-7",), "more than 1e+09"),
    (("reference={kind='sum_of_sines', amplitudes=[" + ",".join(["1.0"] * 1001) +
      "], omegas=[1.0], phases=[0.0]}",), "at most 1000 entries"),
    (("controller.eta=" + "[" * 40 + "1" + "]" * 40,), "nested more than 32 levels"),
])
def test_sizes_beyond_the_documented_bounds_are_refused_at_once(tmp_path, settings, phrase):
    before = user_files(tmp_path)
    duration = ("--duration", "1000") if "run.dt" in settings[0] else SHORT
    sets = [a for item in settings for a in ("--set", item)]
    r = tspend("run", "S.toml", *duration, *OUT, *sets, cwd=tmp_path)
    assert r.status == 2 and phrase in r.one_error_line(), r.err
    assert r.out == ""
    assert_intact(tmp_path, before)


def test_an_8_gb_scenario_file_is_not_read(tmp_path):
    before = user_files(tmp_path)
    with open(tmp_path / "Big.toml", "wb") as f:
        f.truncate(8 * 2**30)  # sparse: no disk used
    before = snapshot(tmp_path)
    started = time.perf_counter()
    r = tspend("run", "Big.toml", *OUT, cwd=tmp_path)
    assert r.status == 2 and "larger than 1000000 bytes" in r.one_error_line()
    assert time.perf_counter() - started < 60
    assert_intact(tmp_path, before)


def test_names_are_sanitised_for_paths_and_terminals(tmp_path):
    user_files(tmp_path)
    text = (tmp_path / "S.toml").read_text()
    (tmp_path / "X.toml").write_text('name = "../../\\u202eevil/x"\n' + text)
    before = snapshot(tmp_path)
    r = tspend("run", "X.toml", *SHORT, cwd=tmp_path)
    assert r.status == 0, r.err
    runs = list((tmp_path / "runs").iterdir())
    assert len(runs) == 1 and runs[0].name.startswith("evil_x-")
    assert "\u202e" not in r.out and "\\u202e" in r.out
    assert_intact(tmp_path, before, allow_new=("runs/",))
    (tmp_path / "Y.toml").write_text('name = "a\\u001b[2Jb"\n' + text)
    r = tspend("run", "Y.toml", *SHORT, cwd=tmp_path)
    assert r.status == 2 and "\x1b" not in r.err and "control character" in r.one_error_line()


def test_mujoco_never_writes_its_log_into_the_working_directory(tmp_path):
    """A run that diverges on MuJoCo (MuJoCo warns of NaN in the state) exits 3, one line."""
    before = user_files(tmp_path)
    r = tspend("run", "P.toml", "--duration", "2", "--no-record", "--set", "controller.gamma=1e9",
               "--set", "run.control_bound=0.0", "--set", "plant.state_bound=0.0", cwd=tmp_path)
    assert r.status == 3, r.err
    assert "diverged" in r.one_error_line()
    assert_intact(tmp_path, before)


def test_list_into_a_reader_that_stops_early(tmp_path):
    proc = subprocess.Popen(f"{sys.executable} -m tspend.cli list | head -1", shell=True,
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out, err = proc.communicate(timeout=120)
    assert len(out.splitlines()) == 1 and err == ""
    p = subprocess.Popen([sys.executable, "-m", "tspend.cli", "list"], cwd=tmp_path,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.readline()
    p.stdout.close()
    assert p.wait(timeout=120) == 0 and p.stderr.read() == b""


# -- signals -------------------------------------------------------------------------------
def _handlers_installed(pid: int, signals: tuple[int, ...]) -> bool:
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    caught = int(next(l for l in status.splitlines() if l.startswith("SigCgt:")).split()[1], 16)
    return all(caught >> (s - 1) & 1 for s in signals)


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads /proc")
@pytest.mark.parametrize("sig,status", [(signal.SIGINT, 130), (signal.SIGTERM, 143),
                                        (signal.SIGHUP, 129)])
def test_a_signal_during_start_up_ends_the_command_cleanly(tmp_path, sig, status):
    """Sent as soon as the handlers are in, i.e. during the heavy imports: nothing written."""
    before = user_files(tmp_path)
    proc = spawn("run", "P.toml", *SHORT, *OUT, cwd=tmp_path)
    deadline = time.time() + 60
    while time.time() < deadline and not _handlers_installed(proc.pid, (signal.SIGTERM,
                                                                        signal.SIGHUP)):
        time.sleep(0.001)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == status, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert f"interrupted by {signal.Signals(sig).name} before any output was written" in err
    assert out == ""
    assert_intact(tmp_path, before)


def test_a_second_signal_does_not_cut_the_cleanup_short(tmp_path):
    before = user_files(tmp_path)
    proc = spawn("run", "pendulum_mujoco", "--duration", "600", *OUT, cwd=tmp_path)
    partial = tmp_path / ".K.partial.rrd"
    deadline = time.time() + 120
    while time.time() < deadline and (not partial.exists() or partial.stat().st_size < 300_000):
        time.sleep(0.05)
    # the first signal is SIGHUP, the lowest-numbered: Python runs the handlers of signals
    # pending together in signal-number order, so on a loaded machine, where the compiled
    # loop can hold the interpreter past any pause, a later SIGINT or SIGTERM pending with
    # it would otherwise be handled first (and a SIGTERM sent first could end as 129); with
    # SIGHUP first, the first signal sent is the first handled however late that is
    proc.send_signal(signal.SIGHUP)
    time.sleep(1.0)  # most of the others then land during the cleanup, not with the first
    deadline = time.time() + 120
    while proc.poll() is None and time.time() < deadline:  # more signals until it exits
        time.sleep(0.005)
        for sig in (signal.SIGINT, signal.SIGHUP, signal.SIGTERM):
            try:
                proc.send_signal(sig)
            except ProcessLookupError:
                break
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 129, err  # the first signal's status, not a later one's
    # one line, besides the notice a slow start prints while numba compiles (under load)
    lines = [l for l in err.strip().splitlines() if not l.startswith(PROGRESS_PREFIX)]
    assert "Traceback" not in err and len(lines) == 1
    assert "interrupted by SIGHUP" in lines[0]
    metrics = json.loads((tmp_path / "K.json").read_text())
    assert metrics["status"] == "interrupted" and metrics["steps"] > 0
    RrdReader(str(tmp_path / "K.rrd")).store()  # complete, with its footer
    assert not partial.exists()
    assert_intact(tmp_path, {k: v for k, v in before.items() if not k.startswith("K.")},
                  allow_new=("K.",))


def test_a_signal_inside_an_unraisable_callback_is_dropped_quietly(monkeypatch):
    """A signal landing in a callback Python cannot raise from (an import lock's weakref
    callback) must not print "Exception ignored": the stop is recorded and the command
    ends at its next check with its one line.  Any other unraisable error still reaches
    the hook that was there before."""
    import gc
    import sys
    import weakref

    from tspend.runtime.interrupts import Interrupted, SignalGuard

    seen: list[BaseException] = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: seen.append(u.exc_value))
    guard = SignalGuard().install()
    try:
        class Thing:
            pass

        for error in (Interrupted("SIGTERM", 143), RuntimeError("a real bug")):
            def callback(_ref, error=error):
                raise error

            thing = Thing()
            ref = weakref.ref(thing, callback)
            del thing
            gc.collect()
            assert ref() is None
    finally:
        guard.restore()
    assert [type(e) for e in seen] == [RuntimeError]


# -- issue 44 (part B): bounds at load, an interrupted solve, os._exit in a plug-in --------
ISSUE44_BAD_INPUT = {
    "plan horizon 2000 s": (("plan", "double_cartpole_swingup", "--out", "p.parquet", "--set",
                             "controllers.tvlqr.horizon=2000"), "at most 10000 intervals"),
    "plan step 1e-9": (("plan", "double_cartpole_swingup", "--out", "p.parquet", "--set",
                        "controllers.tvlqr.step=1e-9"), "RK4 steps an interval"),
    "mpc.horizon 1e6": (("run", "pendulum_mujoco", "--controller", "mpc", *SHORT, *OUT, "--set",
                         "controllers.mpc.horizon=1000000"), "must be from 1 to 1000"),
    "mpc.substeps 1e5": (("run", "pendulum_mujoco", "--controller", "mpc", *SHORT, *OUT, "--set",
                          "controllers.mpc.substeps=100000"), "must be from 1 to 100"),
    "MJCF infinite mass": (("run", "P.toml", *SHORT, *OUT), "body 'pole': mass = inf"),
}


@pytest.mark.parametrize("case", list(ISSUE44_BAD_INPUT))
def test_issue44_sizes_and_physical_values_are_refused_at_load(tmp_path, case):
    argv, phrase = ISSUE44_BAD_INPUT[case]
    user_files(tmp_path)
    (tmp_path / "p.parquet").write_bytes(b"PAR1 the user's plan")
    if case == "MJCF infinite mass":
        text = (tmp_path / "M.xml").read_text()
        (tmp_path / "M.xml").write_text(text.replace('mass="1"', 'mass="inf"'))
    before = snapshot(tmp_path)
    r = tspend(*argv, cwd=tmp_path, timeout=300)
    line = r.one_error_line()
    assert r.status == 2 and phrase in line, line
    assert_intact(tmp_path, before)
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


@pytest.mark.parametrize("sig,status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_an_interrupt_during_a_plans_solve_ends_it_and_keeps_the_old_plan(tmp_path, sig,
                                                                          status):
    (tmp_path / "p.parquet").write_bytes(b"PAR1 the user's plan")
    before = snapshot(tmp_path)
    proc = spawn("plan", "double_cartpole_swingup", "--out", "p.parquet", cwd=tmp_path)
    # the banner is printed just before the solve starts: the signal lands inside IPOPT
    assert proc.stdout.readline().startswith("planning double_cartpole_swingup")
    time.sleep(1.0)
    proc.send_signal(sig)
    sent = time.monotonic()
    out, err = proc.communicate(timeout=120)
    lines = [line for line in err.splitlines() if line.strip()]
    assert proc.returncode == status, err
    assert time.monotonic() - sent < 20.0     # not the rest of the solve, nor a second try
    assert len(lines) == 1 and "interrupted by" in lines[0] and "no plan" not in err, err
    assert_intact(tmp_path, before)


def test_a_plugin_that_ends_its_process_leaves_no_visible_partial_output(tmp_path):
    (tmp_path / "Plug.py").write_text(
        "import os\nimport numpy as np\nfrom tspend.controllers.base import Controller\n"
        "class Exits(Controller):\n    kind = 'exits'\n"
        "    def __init__(self, scenario):\n        self.order = len(scenario.plant.x0)\n"
        "        self.diagnostics = ()\n        self.diag = np.zeros(0)\n"
        "    def reset(self, rng):\n        pass\n"
        "    def step(self, obs, dt):\n        os._exit(0)\n")
    before = user_files(tmp_path)
    r = tspend("run", "ex3_pendulum_ode", *SHORT, *OUT, "--controller", "Plug.py:Exits",
               cwd=tmp_path, timeout=300)
    assert r.status == 0
    visible = [p.name for p in tmp_path.iterdir() if not p.name.startswith(".")]
    assert sorted(visible) == sorted(set(before) | {"Plug.py"}), visible
    assert_intact(tmp_path, {**before, "Plug.py": snapshot(tmp_path)["Plug.py"]},
                  allow_new=(".K.partial",))
