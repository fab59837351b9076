"""control_energy integrates the applied input, control_energy_command the commanded
(issue 42): a saturating run's energy is bounded by what the actuator can deliver."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cli_harness import tspend
from tspend.loop.metrics import MachineInfo, MetricsAccumulator
from tspend.loop.sinks import Block


def _block(t: np.ndarray, u: np.ndarray) -> Block:
    e = np.column_stack([0.01 * np.sin(t), np.zeros_like(t)])
    return Block(start=0, data={"t": t, "u": u, "e": e})


def test_energy_of_applied_and_commanded_input_against_numpy():
    dt = 1e-3
    t = np.arange(4000) * dt
    u = 30.0 * np.sin(7.0 * t) + 5.0                          # goes past both bounds
    acc = MetricsAccumulator(dt, ss_start=2.0, machine=MachineInfo(u_lo=-10.0, u_hi=20.0))
    for k in range(0, t.size, 1000):                          # four blocks, as the loop sends
        acc.block(_block(t[k:k + 1000], u[k:k + 1000]))
    m = acc.result()
    applied = np.clip(u, -10.0, 20.0)
    assert m["control_energy"] == pytest.approx(float(np.sum(applied ** 2) * dt), rel=1e-12)
    assert m["control_energy_command"] == pytest.approx(float(np.sum(u ** 2) * dt), rel=1e-12)
    assert m["control_energy"] < 0.6 * m["control_energy_command"]
    assert m["max_abs_u"] == pytest.approx(20.0) and m["max_abs_u_command"] == pytest.approx(35.0)
    # without an actuator range the two are the same number
    free = MetricsAccumulator(dt, ss_start=2.0)
    free.block(_block(t, u))
    assert free.result()["control_energy"] == free.result()["control_energy_command"]


def test_saturating_pd_run_energy_bounded_by_the_actuator(tmp_path):
    """The issue's command: PD at bandwidth 90 asks far more than the actuator's range."""
    r = tspend("run", "pendulum_mujoco", "--controller", "pd", "--set",
               "controllers.pd.bandwidth=90", "--duration", "5", "--metrics", "m.json",
               "--no-record", cwd=tmp_path, timeout=300)
    m = json.loads((tmp_path / "m.json").read_text())
    assert r.status in (0, 4), r.err                          # a run the task ended counts too
    assert m["max_abs_u_command"] > m["max_abs_u"]            # it did saturate
    assert m["control_energy"] <= m["max_abs_u"] ** 2 * m["sim_s"] * (1 + 1e-12)
    assert m["control_energy_command"] > m["control_energy"]
