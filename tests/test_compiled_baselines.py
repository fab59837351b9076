"""The baselines in the compiled loops (issue 22) against their previous Python steps.

Each kind's compiled run must take the compiled path and match, over a whole run, the
numpy step the kind had before it was compiled (tests/oracles/python_baselines.py) run
by the generic loop: every recorded key to 1e-10, the same ending.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import tspend.loop.runner as runner_module
from tspend import load_scenario, override, run
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
]


@pytest.fixture
def paths(monkeypatch):
    """The loop each run took, in order ("compiled" or "generic")."""
    taken: list[str] = []
    real = runner_module.ClosedLoop._loop

    def spy(self, sinks):
        try:
            return real(self, sinks)
        finally:
            taken.append(self.path)

    monkeypatch.setattr(runner_module.ClosedLoop, "_loop", spy)
    return taken


def assert_close_runs(a, b, atol: float = 1e-10) -> None:
    assert a.status == b.status
    assert a.end.steps_done == b.end.steps_done
    assert a.history.keys() == b.history.keys()
    for key in a.history:
        np.testing.assert_allclose(a.history[key], b.history[key], rtol=0, atol=atol,
                                   err_msg=key)


@pytest.mark.parametrize("name,kind,settings", CASES)
def test_compiled_kind_matches_its_previous_python_step(name, kind, settings, paths):
    scenario = override(load_scenario(name), **{"run.duration": 3.0, **settings})
    fast = run(scenario, controller=kind)
    parts = prepare(scenario, controller=kind)
    slow = run(scenario, prepared=replace(parts, controller=oracle(parts.controller)))
    assert paths == ["compiled", "generic"]
    assert fast.status == "completed"
    assert_close_runs(fast, slow)
    for key, value in slow.controller.parameters().items():
        np.testing.assert_allclose(fast.controller.parameters()[key], value, rtol=0, atol=1e-10)
