"""The baselines in the compiled loops (issue 22) against their previous Python steps.

Each kind's compiled run must take the compiled path and match, over a whole run, the
numpy step the kind had before it was compiled (tests/oracles/python_baselines.py) run
by the generic loop: every recorded key to 1e-10, the same ending.
"""

from __future__ import annotations

from dataclasses import replace
from typing import NamedTuple

import numpy as np
import pytest
from numba import njit

from tspend import load_scenario, override, run
from tspend.controllers.base import CompiledController, Controller, Observation, diagnostics
from loop_harness import ZOH_CASES, sampled_run
from tspend.loop.simulation import prepare

from tests.oracles.python_baselines import oracle

CASES = [
    ("ex3_pendulum_ode", "pd", {}),
    ("ex2_duffing", "pd", {}),
    ("ex3_pendulum_ode", "lqr", {"controllers.lqr.design": "view"}),
    ("third_order", "lqr", {}),
    ("ex3_pendulum_ode", "sliding_mode", {}),
    ("ex2_duffing", "sliding_mode", {}),
    ("ex3_pendulum_ode", "wang_indirect", {}),
    ("ex1_nonaffine_case1", "wang_indirect", {}),
    ("third_order", "wang_indirect", {}),
    # from x0 = [0.2, 0], not the scenario's [pi/30, 0]: there e_Delta = e^T P b is 0 up to
    # rounding at t = 0 (numpy's dot fuses a multiply-add), and u_s switches on its sign
    ("ex3_pendulum_ode", "wang_indirect", {
        "plant.x0": [0.2, 0.0],
        "controllers.wang_indirect.supervisory": True, "controllers.wang_indirect.f_upper": 1.0,
        "controllers.wang_indirect.g_upper": 0.03, "controllers.wang_indirect.g_lower": 0.02,
        "controllers.wang_indirect.V_bar": 0.01, "controllers.wang_indirect.f_radius": 0.5,
        "controllers.wang_indirect.g_radius": 0.2}),
    ("pendulum_mujoco", "sliding_mode", {}),
    ("ex3_pendulum_ode", "feedback_linearization", {}),
    ("ex1_nonaffine_case1", "feedback_linearization", {}),   # Newton
    ("ex2_duffing", "feedback_linearization", {}),           # the controller's own clock
    ("third_order", "feedback_linearization", {}),
    ("furuta_ode", "feedback_linearization", {}),
    ("furuta_ode", "pd", {}),
    ("swingup_mujoco", "swingup", {"run.duration": 9.0}),            # swings, then caught
    ("swingup_mujoco", "swingup", {"run.duration": 6.0, "effects.rail": 1.5}),  # brakes
    ("ex3_pendulum_ode", "swingup", {"plant.x0": [3.0, 0.0], "task.fall_angle": 0.0}),
    # the derived equations' q'' and energy through their C entry points (DerivedFull)
    ("furuta_swingup", "swingup", {"run.duration": 3.0}),
]


def assert_close_runs(a, b, atol: float = 1e-10) -> None:
    assert a.status == b.status
    assert a.end.steps_done == b.end.steps_done
    assert a.history.keys() == b.history.keys()
    for key in a.history:
        # df/du is a central difference of step 1e-6: rounding in f (1e-16) shows at 1e-10
        # (and a falling pendulum's u reaches 1e4: u = (v - f0) / (f1 - f0) cancels: relative 1e-12)
        tol = dict(rtol=1e-9, atol=0) if key == "df_du" else dict(rtol=1e-12, atol=atol)
        np.testing.assert_allclose(a.history[key], b.history[key], err_msg=key, **tol)


@pytest.mark.parametrize("name,kind,settings", CASES)
def test_compiled_kind_matches_its_previous_python_step(name, kind, settings, paths):
    scenario = override(load_scenario(name), **{"run.duration": 3.0, **settings})
    fast = run(scenario, controller=kind)
    parts = prepare(scenario, controller=kind)
    slow = run(scenario, prepared=replace(parts, controller=oracle(parts.controller)))
    assert paths == ["compiled", "generic"]
    assert fast.status == "completed" or name.startswith("furuta")  # pd falls there
    assert fast.end.steps_done > 100
    assert_close_runs(fast, slow)
    if kind == "swingup" and scenario.run.duration > 8.0:   # both modes were run
        assert fast.history["mode"][0] == 0.0 and fast.history["mode"][-1] == 1.0
    for key, value in slow.controller.parameters().items():
        np.testing.assert_allclose(fast.controller.parameters()[key], value, rtol=0, atol=1e-10)


# -- sampled control (run.control_period, run.control_delay) in the compiled loops ----------
class CountSettings(NamedTuple):
    """A compiled controller whose u is the number of times it ran (and dt in diag)."""

    unused: float


@njit(cache=False)
def count_step(settings, state, scratch, t, full, x, ref, dt, diag):
    state[0] += 1.0
    diag[0] = dt
    return state[0]


class Counter(Controller):
    """u = how many times the controller ran, in the compiled loops."""

    kind = "counter"

    def __init__(self) -> None:
        self.order = 2
        self.diagnostics = diagnostics(("dt_seen", 1))
        self.diag = np.zeros(1)
        self.calls = np.zeros(1)

    def reset(self, rng) -> None:
        self.calls[0] = 0.0

    def step(self, obs: Observation, dt: float) -> float:
        raise AssertionError("the compiled loop must run this controller")

    def compiled(self) -> CompiledController:
        return CompiledController(count_step, CountSettings(0.0), self.calls, None)


@pytest.fixture
def uncached(monkeypatch, tmp_path):
    """The compiled loops compiled for this module's Counter away from the package's disk
    cache: an index entry naming a type of a test module could not be read by a process
    that cannot import it (a sweep's worker)."""
    import numba
    from numba.core.caching import NullCache

    import tspend.loop.fastloop as fastloop
    for name in ("_analytic_samples", "_mujoco_samples", "_take_sample", "_held_sample"):
        monkeypatch.setattr(getattr(fastloop, name), "_cache", NullCache())
    # functions compiled afresh here (the controller dispatch's overload) cache in tmp_path
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path))


@pytest.mark.parametrize("every, delay, expected", ZOH_CASES)
@pytest.mark.parametrize("name", ["ex2_duffing", "pendulum_mujoco"])
def test_compiled_zero_order_hold_and_delay_by_hand(name, every, delay, expected, uncached):
    ctrl = Counter()
    loop, hist, end = sampled_run(name, ctrl, every, delay)
    assert loop.path == "compiled"
    assert end.status == "completed"
    np.testing.assert_array_equal(hist.arrays()["u"], expected)
    assert ctrl.calls[0] == len(range(0, 10, every))
    # the controller's sample time is the control period
    np.testing.assert_array_equal(hist.arrays()["dt_seen"], load_scenario(name).run.dt * every)


@pytest.mark.parametrize("name,kind", [("ex3_pendulum_ode", "second_type"),
                                       ("ex3_pendulum_ode", "pd"),
                                       ("pendulum_mujoco", "wang_indirect")])
def test_sampled_control_compiled_equals_generic(name, kind, paths):
    scenario = override(load_scenario(name), **{"run.duration": 1.0,
                                                "run.control_period": 0.005,
                                                "run.control_delay": 3})
    fast = run(scenario, controller=kind, block_size=300)
    slow = run(scenario, controller=kind, block_size=300, compiled=False)
    assert paths == ["compiled", "generic"]
    assert fast.status == slow.status == "completed"
    for key in fast.history:
        np.testing.assert_array_equal(fast.history[key], slow.history[key], err_msg=key)
    u = fast.history["u"]
    # held: u changes at most at every fifth step, the first 3 steps are 0
    assert (u[:3] == 0.0).all()
    changes = np.flatnonzero(np.diff(u)) + 1
    assert ((changes - 3) % 5 == 0).all()
