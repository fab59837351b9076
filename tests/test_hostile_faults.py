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
        def install(self, *args, **kwargs):
            loaded = sorted(m for m in sys.modules if m.startswith({HEAVY!r}))
            print("LOADED", loaded, file=sys.stderr, flush=True)
            return real_install(self, *args, **kwargs)
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


def _in_process(capsys, *args: str) -> tuple[int, list[str]]:
    from tspend.cli.main import main

    status = main(list(args))
    return status, [l for l in capsys.readouterr().err.splitlines() if l.strip()]


@pytest.fixture()
def plugins(tmp_path, monkeypatch):
    """A user's folder holding benchmarks/hostile_inputs.py's plug-in file (Plug.py: a
    good controller and one broken in each way, item 14's among them) and two modules
    that fail as they are imported."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from hostile_inputs import PLUGIN

    (tmp_path / "Plug.py").write_text(PLUGIN)
    (tmp_path / "ExitsAtImport.py").write_text("import sys\nsys.exit(0)\n")
    (tmp_path / "OwnBaseAtImport.py").write_text("class Mine(BaseException):\n    pass\n\n\n"
                                                 "raise Mine('imported wrong')\n")
    monkeypatch.chdir(tmp_path)
    return tmp_path


RUN_PLUGIN = ("run", "ex3_pendulum_ode", "--duration", "0.05", "--out", "o.rrd", "--metrics",
              "o.json", "--controller")


@pytest.mark.parametrize("spec, status, phrase", [
    ("Plug.py:InitOwnBase", 2, "building it failed: MyBase: built wrong"),
    ("Plug.py:InitExits", 2, "building it failed: SystemExit: 0"),
    ("ExitsAtImport.py:X", 2, "importing it failed: SystemExit: 0"),
    ("OwnBaseAtImport.py:X", 2, "importing it failed: Mine: imported wrong"),
    ("Plug.py:ResetRaises", 6, "RuntimeError: reset broke"),
    ("Plug.py:ResetOwnBase", 6, "MyBase: reset broke"),
])
def test_a_plugin_failing_before_its_first_sample_is_one_line_and_writes_nothing(
        plugins, capsys, spec, status, phrase):
    """Item 14: a BaseException of the plug-in's own in ``__init__``, ``reset`` or at import
    was a traceback and exit 1, ``reset`` raising RuntimeError exit 70, and ``sys.exit(0)``
    exit 0 with nothing written (a failure looking like success).  Now building or
    importing is bad input (2), ``reset`` the controller's failure (6, docs/reliability.md),
    each one line, and no output file exists."""
    got, lines = _in_process(capsys, *RUN_PLUGIN, spec)
    assert (got, len(lines)) == (status, 1), lines
    assert phrase in lines[0]
    assert not (plugins / "o.rrd").exists() and not (plugins / "o.json").exists()


def test_a_keyboard_interrupt_a_plugin_raises_is_its_error_not_a_signal(plugins, capsys):
    """Item 14: with the CLI's handlers a real SIGINT raises their own exception, so a
    KeyboardInterrupt out of ``step`` is the plug-in's ``raise``: controller_error (6), not
    "interrupted by SIGINT" (130) with no signal sent."""
    import json

    got, lines = _in_process(capsys, *RUN_PLUGIN, "Plug.py:StepKeyboardInterrupt")
    assert got == 6, lines
    assert json.loads((plugins / "o.json").read_text())["status"] == "controller_error"
    assert not any("interrupted" in l for l in lines), lines


@pytest.mark.parametrize("scenario, model, joint, pole_joint", [
    ("double_cartpole_mujoco", "double_cartpole.xml", "hinge2", "hinge1"),
    ("double_cartpole_ode", "double_cartpole.xml", "hinge2", "hinge1"),
    ("triple_cartpole_mujoco", "triple_cartpole.xml", "hinge3", "hinge2"),
    ("rotary_double_mujoco", "rotary_double.xml", "link2", "link1"),
    ("furuta_mujoco", "furuta.xml", "pendulum", None),
    ("pendulum_mujoco", "cartpole.xml", "hinge", None),
])
def test_a_pole_made_a_slide_is_refused_when_the_model_is_read_naming_it(
        tmp_path, scenario, model, joint, pole_joint):
    """Item 20: a copy of a machine's model with a pole's hinge made a slide.  The double
    cart-pole's ran (hinge2 read as a second cart, sliding 4.95 m unwatched) and lqr refused
    it only as an uncontrollable mode naming other joints.  Every machine now refuses it
    when its model is read (building the plant, before any design), naming the joint."""
    import re

    import tspend
    from tspend.runtime.errors import ScenarioError

    text = (ROOT / "models" / model).read_text()
    changed, count = re.subn(rf'(<joint name="{joint}" type=)"hinge"', r'\1"slide"', text)
    assert count == 1
    (tmp_path / "slide.xml").write_text(changed)
    scn = tspend.override(tspend.load_scenario(scenario),
                          **{"plant.model": str(tmp_path / "slide.xml")})
    with pytest.raises(ScenarioError) as refused:
        tspend.build_plant(scn)
    assert repr(joint) in str(refused.value)
    if pole_joint is not None:  # the articulated domain says which pole carries it
        assert f"carried by the pole {pole_joint!r}" in str(refused.value)


@pytest.mark.parametrize("changes, refused", [
    ({"safety.plan_period": 1e-9}, "from the control period (0.001 s) to 1 s, got 1e-09"),
    ({"safety.plan_period": 0.0009}, "got 0.0009"),
    ({"run.control_period": 0.01, "safety.plan_period": 0.005}, "(0.01 s) to 1 s, got 0.005"),
    ({"safety.plan_period": 1.5}, "to 1 s, got 1.5"),
    ({"safety.plan_period": 0.001}, None),
    ({"run.control_period": 0.01, "safety.plan_period": 0.01}, None),
])
def test_the_mpsc_plan_period_is_bounded_by_the_control_period(changes, refused):
    """Item 15: ``--set safety.plan_period=1e-9`` was accepted and the run went on past
    150 s.  A plan interval shorter than a control sample is refused when the scenario
    is read (exit 2 on the CLI), 0 (from the machine) and one sample upwards are not."""
    import tspend
    from tspend.runtime.errors import ScenarioError

    base = tspend.load_scenario("pendulum_mujoco")
    changes = {"safety.filter": "mpsc", **changes}
    if refused is None:
        assert tspend.override(base, **changes).safety.plan_period == changes["safety.plan_period"]
        return
    with pytest.raises(ScenarioError, match=r"safety\.plan_period: must be 0") as error:
        tspend.override(base, **changes)
    assert refused in str(error.value)


def test_a_numba_code_file_swapped_for_another_functions_is_removed(tmp_path, recwarn):
    """Item 17: ``...rhs_c-1238.py311.1.nbc`` copied over ``...dynamics-9.py311.1.nbc``
    (whole pickles, another function's machine code) was loaded and the run segfaulted.
    numba writes a code file only with its index, so a listed code file that changed
    while its index did not is removed (numba compiles that function again), said in one
    warning line; a code file rewritten with its index is numba's own and stays."""
    import pickle

    from tspend.runtime import cache

    pycache = tmp_path / "__pycache__"
    pycache.mkdir()
    files = {}
    for function, line in (("dynamics", 9), ("rhs_c", 1238)):
        stem = f"tspend_articulated_abc.{function}-{line}.py311"
        files[function] = (pycache / f"{stem}.nbi", pycache / f"{stem}.1.nbc")
        files[function][0].write_bytes(pickle.dumps("0.60") + pickle.dumps(
            (("stamp", 1), {"sig": f"{stem}.1.nbc"})))
        files[function][1].write_bytes(pickle.dumps({"code": function.encode() * 500}))
    cache._write_manifest(pycache)
    assert cache.check_numba_files(pycache) == 0
    index, code = files["dynamics"]
    code.write_bytes(files["rhs_c"][1].read_bytes())            # the swap
    assert cache.check_numba_files(pycache) == 1
    assert not code.exists() and index.exists() and files["rhs_c"][1].exists()
    assert any("replaced without its index" in str(w.message) for w in recwarn)
    # numba's own save: the code and its index rewritten together, both whole: kept
    code.write_bytes(pickle.dumps({"code": b"new" * 500}))
    cache._write_manifest(pycache)
    code.write_bytes(pickle.dumps({"code": b"newer" * 500}))
    index.write_bytes(pickle.dumps("0.60") + pickle.dumps((("stamp", 2), {"s": 1})))
    assert cache.check_numba_files(pycache) == 0 and code.exists()


def test_a_cache_on_a_full_file_system_is_not_used(tmp_path, monkeypatch):
    """Item 17: ``TSPEND_CACHE_DIR`` on a full file system passed the writable check
    (creating an empty file needs no space) and the first entry written was an OSError,
    exit 70, where docs/reliability.md says the process falls back to a private folder.
    With less than MIN_CACHE_FREE_BYTES free the cache is not used."""
    import os

    from tspend.runtime import jit

    monkeypatch.setenv("TSPEND_CACHE_DIR", str(tmp_path / "cache"))
    assert jit.writable_cache("articulated") == tmp_path / "cache" / "articulated"
    real = os.statvfs(tmp_path)

    class Full:
        f_frsize, f_bavail = real.f_frsize, (jit.MIN_CACHE_FREE_BYTES // real.f_frsize) - 1

    monkeypatch.setattr(os, "statvfs", lambda path: Full)
    assert jit.writable_cache("articulated") is None


SWEEP = ("sweep", "pendulum_mujoco", "--duration", "0.05", "--seeds", "0:2")


@pytest.mark.parametrize("extra, phrase", [
    (("--precision", "float32"), "--precision float32: the cpu backend computes in float64"),
    (("--backend", "mjx", "--controller", "lqr", "--dask", "local"), "--dask: the mjx backend"),
    (("--backend", "mjx", "--controller", "lqr", "--run-timeout", "5"),
     "--run-timeout: the mjx backend"),
])
def test_a_sweep_option_its_backend_would_ignore_is_refused(tmp_path, monkeypatch, capsys,
                                                             extra, phrase):
    """Item 19: each of these ran with exit 0, the option silently ignored.  Refused now,
    before the banner, one line."""
    monkeypatch.chdir(tmp_path)
    status, lines = _in_process(capsys, *SWEEP, *extra)
    assert (status, len(lines)) == (2, 1), lines
    assert phrase in lines[0]


@pytest.mark.parametrize("safety", ["cbf", "mpsc"])
def test_mjx_refuses_a_safety_filter_before_its_banner(tmp_path, monkeypatch, capsys, safety):
    """Item 19: ``--backend mjx`` with ``safety.filter`` printed the sweep's banner, then
    refused; the refusal now comes with everything else checked before it."""
    pytest.importorskip("mujoco.mjx")
    monkeypatch.chdir(tmp_path)
    from tspend.cli.main import main

    status = main([*SWEEP, "--backend", "mjx", "--controller", "lqr", "--set",
                   f"safety.filter={safety}"])
    out, err = capsys.readouterr()
    assert status == 2 and "tspend 0.1" not in out and "sweep of" not in out, out
    assert f"safety.filter = '{safety}' is not in the mjx backend" in err


@pytest.mark.parametrize("action", ["0.5", b"1", True])
def test_the_gym_env_refuses_an_action_that_is_not_a_number(action):
    """Item 19: ``env.step("0.5")`` and ``env.step(b"1")`` were read as numbers (numpy
    parses strings), where the runner refuses a controller's string."""
    pytest.importorskip("gymnasium")
    from tspend.runtime.errors import ScenarioError
    from tspend.gym import TspendEnv

    env = TspendEnv("pendulum_mujoco")
    env.reset(seed=0)
    with pytest.raises(ScenarioError, match="not a number"):
        env.step(action)


def test_check_claims_reports_a_missing_page_as_a_fail_line(tmp_path):
    """Item 19: ``python tools/check_claims.py`` without docs/results.md was a traceback
    (FileNotFoundError); a page that is missing is a problem line like any other."""
    sys.path.insert(0, str(ROOT / "tools"))
    import check_claims

    figures, problems = check_claims.check_sections(
        [("docs/no-such-page.md", "<!-- begin -->", "<!-- end -->", lambda: "", "data")])
    assert figures == 0 and problems == [
        "docs/no-such-page.md: no section <!-- begin -->: the file is missing"]


def test_mjx_says_out_of_memory_before_the_work(monkeypatch):
    """Item 16: ``--seeds 0:1000000`` under an 8 GB address limit built machines for 227 s
    and then blamed the model ("cannot parse MJCF"); ``--duration 100000`` was a
    MemoryError (exit 70).  The memory a fleet needs is estimated first (machines, the
    reference tables, a batch's samples) and a shortfall is one line saying so."""
    pytest.importorskip("mujoco.mjx")
    import tspend
    from tspend.runtime.errors import ScenarioError
    from tspend.mjx import sweep as mjx_sweep

    scn = tspend.load_scenario("pendulum_mujoco")
    monkeypatch.setattr(mjx_sweep, "available_bytes", lambda: 8.0 * 2**30)
    mjx_sweep.check_memory(scn, 2)   # two machines fit
    with pytest.raises(ScenarioError, match=r"1000000 runs need about \d+\.\d GiB of memory"):
        mjx_sweep.check_memory(scn, 1_000_000)
    long = tspend.override(scn, **{"run.duration": 100000.0})
    with pytest.raises(ScenarioError, match=r"of tables for 100000000 steps"):
        mjx_sweep.check_memory(long, 2)


def test_an_mjx_batch_keeps_its_samples_within_a_budget():
    """Item 16: a batch of 131,072 envs returned 1000 steps of samples per block at once
    (16 GB for the cart-pole).  Now the samples never leave the device: each env folds
    :data:`CHUNK` of them at once into its figures (issue 55), so what an env takes does
    not grow with the run's length, and the memory estimate counts that chunk."""
    pytest.importorskip("mujoco.mjx")
    import tspend
    from tspend.mjx import sweep as mjx_sweep

    scn = tspend.load_scenario("pendulum_mujoco")
    need, per_env, tables, steps = mjx_sweep.memory_need(scn, 4)
    long = tspend.override(scn, **{"run.duration": 100 * scn.run.duration})
    need_l, per_env_l, tables_l, steps_l = mjx_sweep.memory_need(long, 4)
    assert steps_l > 50 * steps and per_env_l == per_env and tables_l > 50 * tables
    assert need == 4 * per_env + tables
    assert per_env >= mjx_sweep.CHUNK * 8 * 3   # a chunk of samples (state, u, keep)


def test_mjx_without_the_device_asked_for_is_one_line():
    """Item 16: ``JAX_PLATFORMS=cuda`` on a machine without a GPU was an internal error
    with an empty AssertionError; now one line naming the missing device."""
    pytest.importorskip("mujoco.mjx")
    import os

    probe = ("from tspend.runtime.errors import ScenarioError\nfrom tspend.mjx import require\n"
             "try:\n    require()\nexcept ScenarioError as exc:\n    print('REFUSED', exc)\n")
    env = dict(os.environ, JAX_PLATFORMS="no_such_platform")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          env=env, timeout=300)
    line = next((l for l in proc.stdout.splitlines() if l.startswith("REFUSED")), proc.stderr)
    assert "JAX has no device to run on with JAX_PLATFORMS='no_such_platform'" in line, line


def test_the_program_installs_its_guard_before_the_cli_loads():
    """Item 13, under load: the interpreter and ``import tspend`` alone took 0.48 s on the
    shared machine, and a SIGINT at 0.5 s still found no handler.  Run as the program
    (``python -m tspend.cli``), the guard is installed as soon as the interrupts module is
    loaded, before the CLI's own modules, and a signal then is its status."""
    probe = textwrap.dedent("""
        import runpy, sys
        from tspend.runtime import interrupts
        real_install = interrupts.SignalGuard.install
        def install(self, *args, **kwargs):
            if not getattr(interrupts, "FIRST", None):
                interrupts.FIRST = sorted(m for m in sys.modules if m.startswith("tspend.cli"))
                print("FIRST", interrupts.FIRST, file=sys.stderr, flush=True)
            return real_install(self, *args, **kwargs)
        interrupts.SignalGuard.install = install
        sys.argv = ["tspend", "show", "ex3_pendulum_ode"]
        runpy.run_module("tspend.cli", run_name="__main__", alter_sys=True)
        """)
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          cwd=ROOT, timeout=300)
    line = next(l for l in proc.stderr.splitlines() if l.startswith("FIRST"))
    assert line == "FIRST ['tspend.cli', 'tspend.cli.main']", line  # no common, no command
    assert proc.returncode == 0, proc.stderr


def test_an_interrupted_sweep_says_no_table_was_written_when_none_was(tmp_path, monkeypatch):
    """Item 19: a sweep interrupted before its first row said "0 rows kept in s.parquet",
    a file that did not exist.  What the interrupted sweep reports is what is on disk
    (``benchmarks/hostile_inputs.py -k "issue51 sweep interrupted"`` sends the signal)."""
    from tspend.cli.sweep import _kept
    from tspend.sweep import read_table

    monkeypatch.chdir(tmp_path)
    assert _kept("s.parquet", read_table) == "no run finished, s.parquet not written"
    assert _kept(None, read_table) == "nothing kept (no --out)"
    assert not (tmp_path / "s.parquet").exists()


def test_a_guard_installed_held_records_a_signal_and_raises_it_only_when_armed():
    """The program's early guard: a signal landing while its handlers are being installed
    (during tspend's imports) must not raise there, where nothing turns it into an exit
    status (CI saw exit 1 and a traceback instead of 143); it raises once armed."""
    import os
    import signal

    from tspend.runtime.interrupts import Interrupted, SignalGuard

    guard = SignalGuard().install(held=True)
    try:
        os.kill(os.getpid(), signal.SIGTERM)  # delivered at the next bytecode: no raise
        assert guard.stop.signal_name == "SIGTERM"
        with pytest.raises(Interrupted) as caught:
            guard.arm()
        assert caught.value.exit_status == 143
    finally:
        guard.restore()
