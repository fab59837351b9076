"""Runs that never claim more than happened (issue 33): each verdict checked against what
was actually compared, applied and reached, and a controller's failure kept as its own.

Oracles: the recording read back, the metrics file, MuJoCo's own contact list, and the
actuator's range (numpy's clip of the recorded command).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from tspend import load_scenario, override
from tspend.runtime.errors import ScenarioError
from tspend.loop.simulation import run

from cli_harness import ROOT, tspend
from tspend.controllers.base import Controller


class _PluginBase(Controller):
    """A plug-in as a user writes one, for the tests below that need it in this module."""

    kind = "plugin_base"

    def __init__(self, scenario, settings=None):
        self.order = len(scenario.plant.x0)
        self.diag = np.zeros(0)

    def reset(self, rng):
        pass

    def step(self, obs, dt):
        return 0.0

TOUCHING = "tests/models/cartpole_touching_rails.xml"

PLUGINS = '''
import sys
import numpy as np
from tspend.controllers.base import Controller


class _Base(Controller):
    kind = "base"

    def __init__(self, scenario, settings=None):
        self.order = len(scenario.plant.x0)
        self.diag = np.zeros(0)

    def reset(self, rng):
        pass

    def step(self, obs, dt):
        return 0.0


class Mutates(_Base):
    kind = "mutates"

    def step(self, obs, dt):
        obs.state[0] = 1e9
        return 0.0


class Raises(_Base):
    kind = "raises"

    def step(self, obs, dt):
        if obs.t > 0.2:
            raise RuntimeError("a bug of mine")
        return 0.0


class Vector(_Base):
    kind = "vector"

    def step(self, obs, dt):
        return np.zeros(2)


class Word(_Base):
    kind = "word"

    def step(self, obs, dt):
        return "push"


class Exits(_Base):
    kind = "exits"

    def step(self, obs, dt):
        sys.exit(0)


class GenExit(_Base):
    kind = "generator_exit"

    def step(self, obs, dt):
        raise GeneratorExit("closed")


class Cancelled(_Base):
    kind = "cancelled"

    def step(self, obs, dt):
        import asyncio
        raise asyncio.CancelledError("cancelled")


class Mine(BaseException):
    pass


class OwnBase(_Base):
    kind = "own_base"

    def step(self, obs, dt):
        raise Mine("of my own")
'''


def test_a_crosscheck_that_compared_nothing_is_inconclusive(tmp_path: Path) -> None:
    r = tspend("crosscheck", "pendulum_mujoco", "--set", f"plant.model={TOUCHING}",
               "--set", "run.duration=1", "--metrics", str(tmp_path / "cc.json"),
               "--no-record", cwd=ROOT, timeout=300)
    assert r.status == 1, r.err
    report = json.loads((tmp_path / "cc.json").read_text())
    assert report["inconclusive"] is True and report["open_loop_ok"] is False
    assert report["open_loop_compared_s"] == 0.0
    # it opens with what was compared (nothing), and claims nothing of what was not: no
    # difference, no integrators' truncation error (issue 51, item 21)
    assert report["verdict"].startswith("open loop INCONCLUSIVE: nothing compared")
    open_loop = report["verdict"].split("derived accelerations")[0]
    assert "truncation" not in report["verdict"] and "nan" not in open_loop
    # and the contact was named before the run, as a warning
    assert "at the start" in r.err and "'rail1' and 'cart'" in r.err


def test_inspect_names_the_contacts_at_the_initial_pose(tmp_path: Path) -> None:
    import mujoco

    r = tspend("inspect", TOUCHING, "--json", str(tmp_path / "i.json"), cwd=ROOT, timeout=120)
    assert r.status == 0, r.err
    facts = json.loads((tmp_path / "i.json").read_text())
    m = mujoco.MjModel.from_xml_path(str(ROOT / TOUCHING))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    theirs = {f"{m.geom(int(c.geom[0])).name}/{m.geom(int(c.geom[1])).name}" for c in d.contact[:d.ncon]}
    assert set(facts["contacts_at_q0"]) == theirs == {"rail1/cart", "rail2/cart"}
    r = tspend("inspect", "models/cartpole.xml", "--json", str(tmp_path / "j.json"), cwd=ROOT,
               timeout=120)
    assert json.loads((tmp_path / "j.json").read_text())["contacts_at_q0"] == "none"


def test_a_failing_plugin_ends_its_run_with_its_own_status_and_keeps_the_outputs(
        tmp_path: Path) -> None:
    (tmp_path / "mine.py").write_text(PLUGINS)
    r = tspend("run", "ex3_pendulum_ode", "--controller", f"{tmp_path / 'mine.py'}:Raises",
               "--duration", "1", "--metrics", str(tmp_path / "m.json"), "--out",
               str(tmp_path / "r.rrd"), cwd=ROOT, timeout=300)
    assert r.status == 6, (r.status, r.err)
    line = r.err_lines[-1]
    # the plug-in's own file and line, not tspend's internals
    assert "controller_error" in line and "a bug of mine" in line and "mine.py" in line
    assert "internal error" not in r.err
    metrics = json.loads((tmp_path / "m.json").read_text())
    assert metrics["status"] == "controller_error" and metrics["steps"] == 201
    assert (tmp_path / "r.rrd").stat().st_size > 0


@pytest.mark.parametrize("cls,what", [("Mutates", "read-only"),
                                      ("Vector", "not one number"),
                                      ("Word", "not a number"),
                                      ("Exits", "SystemExit(0)"),
                                      ("GenExit", "GeneratorExit: closed"),
                                      ("Cancelled", "CancelledError: cancelled"),
                                      ("OwnBase", "Mine: of my own")])
def test_every_kind_of_controller_failure_is_the_controllers(tmp_path: Path, cls: str,
                                                             what: str) -> None:
    (tmp_path / "mine.py").write_text(PLUGINS)
    scn = override(load_scenario("ex3_pendulum_ode"), **{"run.duration": 0.5})
    r = run(scn, controller=f"{tmp_path / 'mine.py'}:{cls}")
    assert r.status == "controller_error" and what in r.end.message
    assert r.metrics["steps"] == 0      # the first sample failed: nothing of it is kept


def test_the_observation_cannot_change_the_plant() -> None:
    from tspend.controllers.base import Observation
    from tspend.loop.runner import _read_only

    a = np.arange(4.0)
    obs = Observation(0.0, _read_only(a), _read_only(a[:2]), _read_only(np.zeros(3)), ())
    with pytest.raises(ValueError):
        obs.state[0] = 1.0
    with pytest.raises(ValueError):
        obs.x[:] = 0.0
    assert a[0] == 0.0


def test_a_control_delay_longer_than_the_run_is_refused() -> None:
    with pytest.raises(ScenarioError, match="control_delay: .* no computed u would ever be applied"):
        override(load_scenario("ex3_pendulum_ode"), **{"run.control_delay": 5000,
                                                       "run.duration": 1.0})


def test_applied_and_commanded_effort_apart_and_both_backends_saturate_alike() -> None:
    fractions = {}
    for name in ("furuta_mujoco", "furuta_ode"):
        scn = override(load_scenario(name), **{"run.duration": 1.0, "task.joint_limits": False})
        r = run(scn, controller="second_type")
        m = r.metrics
        u = r.history["u"]
        lo, hi = r.plant.inputs[0].lo, r.plant.inputs[0].hi
        assert (lo, hi) == (-10.0, 10.0)
        assert m["max_abs_u"] == pytest.approx(np.abs(np.clip(u, lo, hi)).max())
        assert m["max_abs_u_command"] == pytest.approx(np.abs(u).max()) and m["max_abs_u_command"] > 10.0
        assert m["saturated_fraction"] == pytest.approx(np.mean((u < lo) | (u > hi)))
        fractions[name] = m["saturated_fraction"]
    assert abs(fractions["furuta_mujoco"] - fractions["furuta_ode"]) <= 0.01


def test_the_furuta_arm_stops_at_the_rigs_cable_by_default() -> None:
    r = run(override(load_scenario("furuta_mujoco"), **{"run.duration": 3.0}),
            controller="second_type")
    assert r.status == "joint_limit" and "rig's stop" in r.end.message
    state = r.history["state"]
    assert np.abs(state[:-1, 0]).max() <= 2.356 + 1e-12


def test_a_swingup_that_never_swings_up_is_not_reached() -> None:
    scn = override(load_scenario("furuta_swingup"), **{"run.duration": 3.0, "task.goal_by": 2.0})
    r = run(scn, controller="lqr")
    assert r.status == "not_reached" and r.metrics["goal"]["met"] is False
    e = r.history["e"][:, 0]
    assert np.abs(e[r.history["t"] >= 2.0]).max() > 0.1      # the oracle: the error itself
    good = run(override(load_scenario("furuta_swingup"), **{"run.duration": 6.0,
                                                             "task.goal_by": 5.0}))
    assert good.status == "completed" and good.metrics["goal"]["met"] is True
    t, e = good.history["t"], np.abs(good.history["e"][:, 0])
    reached = good.metrics["goal"]["reached_at_s"]
    assert np.all(e[t >= reached - 1e-12] <= 0.1) and e[t < reached - 1e-9][-1] > 0.1


def test_a_fall_names_what_else_was_true() -> None:
    """The third-party cart-pole resting on its rails: friction holds the cart, the motor
    saturates, the pole falls; the message says all three."""
    scn = override(load_scenario("pendulum_mujoco"), **{"plant.model": TOUCHING,
                                                        "run.duration": 4.0})
    r = run(scn, controller="lqr")
    assert r.status == "fell"
    assert "contact between geoms 'rail1' and 'cart'" in r.end.message
    assert "saturated for the last" in r.end.message
    u = r.history["u"]
    tail = np.flatnonzero(np.abs(u) <= 2000.0)
    assert r.metrics["saturated_at_end_s"] == pytest.approx((u.size - 1 - tail[-1]) * scn.run.dt)


@pytest.mark.parametrize("scenario,controller,changes", [
    ("pendulum_mujoco", "lqr", {"plant.x0": [1.0, 0.0], "task.fall_angle": 0.0}),
    ("furuta_mujoco", "second_type", {"task.joint_limits": False}),
    ("double_cartpole_mujoco", "lqr", {"plant.x0": [0.6, 0.0], "task.fall_angle": 0.0}),
])
def test_each_domains_two_backends_report_alike(scenario: str, controller: str,
                                                changes: dict) -> None:
    """The same machine on MuJoCo and on its ODE: the same metrics keys, the same input
    bounds declared, and the same saturation (within 0.01) under the same controller."""
    from tspend.plants.registry import domain_of

    scn = override(load_scenario(scenario), **{"run.duration": 1.0, **changes})
    domain = domain_of(scn.plant.kind)
    a = run(scn, controller=controller)
    b = run(scn, controller=controller, plant_kind=domain.ode_kind())
    assert set(a.metrics) == set(b.metrics)
    bound = lambda r: (r.plant.inputs[0].lo, r.plant.inputs[0].hi)  # noqa: E731
    assert bound(a) == bound(b)
    assert abs(a.metrics["saturated_fraction"] - b.metrics["saturated_fraction"]) <= 0.01
    assert a.metrics["saturated_fraction"] > 0.0      # the case saturates, so it says something


def test_the_recording_draws_the_applied_u_and_the_command_in_its_own_view(tmp_path: Path) -> None:
    from tspend.recorder import RerunSink, close_recording, open_recording
    from tspend.recorder.readback import read_scalar_series
    from tspend.recorder.series import specs_of

    scn = override(load_scenario("furuta_mujoco"), **{"run.duration": 0.5,
                                                     "task.joint_limits": False})
    path = tmp_path / "f.rrd"
    rec = open_recording("applied_u", path=path)
    try:
        r = run(scn, controller="second_type", sinks=[RerunSink(rec)])
    finally:
        close_recording(rec)
    u = r.history["u"]
    lo, hi = r.plant.inputs[0].lo, r.plant.inputs[0].hi
    assert np.abs(u).max() > 10 * hi  # the command chatters far past the motor's +/-10 V
    _, applied = read_scalar_series(path, "series/control")
    _, command = read_scalar_series(path, "series/control_command")
    np.testing.assert_allclose(applied, np.clip(u, lo, hi), rtol=0, atol=1e-6)
    np.testing.assert_allclose(command, u, rtol=1e-6)
    assert np.abs(applied).max() == pytest.approx(r.metrics["max_abs_u"])
    # the command's view is its own, not the applied u's panel
    views = {s.entity: s for s in specs_of(r.info)}
    assert "commanded" in views["series/control_command"].title
    assert "applied" in views["series/control"].title


class SleepsInItsStep(_PluginBase):
    """At its eleventh sample a SIGTERM arrives (raised by itself: delivered at once, to
    this thread, no race with a sender), then it falls asleep for a minute."""

    kind = "sleeps"

    def step(self, obs, dt):
        if obs.t > 0.0095:
            import signal

            signal.raise_signal(signal.SIGTERM)
            time.sleep(60)  # without the signal raised into its code: a minute, then 11 steps
        return 0.0


def test_a_signal_stops_a_plugin_sleeping_in_its_step() -> None:
    """The stop is checked between two samples, which a sleeping plug-in never reaches: the
    signal is raised into its code instead, and the run ends as interrupted at that sample
    (benchmarks/hostile_inputs.py sends the SIGTERM from outside, to a plug-in asleep)."""
    import tspend as tspend_api
    from tspend.loop.runner import RunInterrupted
    from tspend.runtime.interrupts import SignalGuard

    guard = SignalGuard().install()
    try:
        with guard.deferred() as stop:
            with pytest.raises(RunInterrupted) as caught:
                tspend_api.run(override(load_scenario("ex3_pendulum_ode"),
                                        **{"run.duration": 0.05}),
                               controller=SleepsInItsStep, stop=stop, keep_history=False)
    finally:
        guard.restore()
    assert caught.value.exit_status == 143
    end = caught.value.end
    assert end.status == "interrupted" and end.metrics["steps"] == 10  # the samples before
    assert stop.in_controller is False


@pytest.mark.parametrize("argv, words", [
    (("run", "ex3_pendulum_ode", "--duration", "1e308"), "duration / dt"),
    (("tune", "ex3_pendulum_ode", "--controller", "pd", "--trials", "1", "--seeds", "0:1",
      "--storage", "sqlite:///no/such/dir/x.db", "--out", "t.toml"), "--storage"),
    (("compare", "ex3_pendulum_ode", "--controller", "lqr,pd", "--seeds", "0:2",
      "--metrics", "x.txt"), "must end in .json"),
])
def test_inputs_the_hostile_benchmark_found_are_one_line_and_exit_2(tmp_path, argv, words):
    """Each once ended in an internal error (an OverflowError, an UnboundLocalError) or in
    two lines (a path read as a list of metrics)."""
    from cli_harness import tspend

    r = tspend(*argv, cwd=tmp_path)
    assert r.status == 2
    assert words in r.one_error_line()
    assert not (tmp_path / "t.toml").exists()


def test_a_sweep_of_failing_plugins_is_not_every_run_completed(tmp_path: Path) -> None:
    # a BaseException of the plug-in's own and sys.exit: rows controller_error, exit 7
    (tmp_path / "mine.py").write_text(PLUGINS)
    for cls in ("OwnBase", "Exits"):
        out = tmp_path / f"{cls}.parquet"
        r = tspend("sweep", "ex3_pendulum_ode", "--duration", "0.05", "--seeds", "0:2",
                   "--jobs", "1", "--controller", f"{tmp_path / 'mine.py'}:{cls}", "--out",
                   str(out), "--record", "none", cwd=ROOT, timeout=300)
        assert r.status == 7, (cls, r.status, r.err)
        assert "2 of 2 runs did not complete: 2 controller_error" in r.err
        assert "Traceback" not in r.err
        import pandas as pd

        assert list(pd.read_parquet(out)["status"]) == ["controller_error"] * 2


def test_the_recording_of_a_run_that_failed_at_its_first_sample_is_exported(
        tmp_path: Path) -> None:
    (tmp_path / "mine.py").write_text(PLUGINS)
    rec = tmp_path / "r.rrd"
    r = tspend("run", "ex3_pendulum_ode", "--controller", f"{tmp_path / 'mine.py'}:Vector",
               "--duration", "0.05", "--out", str(rec), cwd=ROOT, timeout=300)
    assert r.status == 6, r.err
    r = tspend("export", str(rec), "--out", str(tmp_path / "r.csv"), cwd=ROOT, timeout=300)
    assert r.status == 0, r.err
    import pandas as pd

    table = pd.read_csv(tmp_path / "r.csv")
    assert len(table) == 0 and list(table.columns[:2]) == ["t_s", "hinge_rad"]
    assert "u_N" in table.columns
    meta = json.loads((tmp_path / "r.csv.json").read_text())
    assert meta["columns"] == list(table.columns)
