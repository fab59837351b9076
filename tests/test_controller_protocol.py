"""Any controller behind the protocol gets the runner, metrics, history and recording.

The controller here is written in the test: a fixed-gain state feedback with a
feedforward of r^(n), declaring two diagnostics of its own.  The run is recorded and
read back from the ``.rrd`` by the diagnostics' names.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from tspend.controllers.base import Controller, Observation, diag_width, diagnostics
from tspend.recorder import RerunSink, close_recording, open_recording, read_scalar_series, series_location
from tspend.loop.runner import ClosedLoop, LoopSettings
from tspend.scenario import load_scenario
from tspend.loop.simulation import History, build_plant, run_info, steps_of
from tspend.loop.metrics import MetricsAccumulator


class FixedGain(Controller):
    """u = (r^(2) - k^T e) / b0 on the Duffing oscillator, a test-only controller."""

    kind = "fixed_gain_test"
    order = 2

    def __init__(self, k=(25.0, 10.0), b0=1.0) -> None:
        self.k = np.asarray(k)
        self.b0 = b0
        self.diagnostics = diagnostics(
            ("feedback", 1, {"panel": "control", "unit": "N"}),
            ("sliding", 1, {"panel": "sliding", "description": "s = k2 e1 + e2"}))
        self.diag = np.zeros(diag_width(self.diagnostics))
        self.resets = 0

    def reset(self, rng: np.random.Generator) -> None:
        self.resets += 1

    def step(self, obs: Observation, dt: float) -> float:
        x, ref = obs.x, obs.ref
        e = x - ref[:2]
        feedback = -float(self.k @ e)
        self.diag[0] = feedback / self.b0
        self.diag[1] = self.k[1] * e[0] + e[1]
        return (ref[2] + feedback) / self.b0

    def parameters(self) -> dict:
        return {}


def test_protocol_is_satisfied() -> None:
    assert isinstance(FixedGain(), Controller)


def test_runner_metrics_history_and_recording_by_name(tmp_path: Path) -> None:
    scenario = load_scenario("ex2_duffing")
    scenario = replace(scenario, run=replace(scenario.run, duration=2.0))
    plant = build_plant(scenario)
    ctrl = FixedGain()
    ctrl.reset(np.random.default_rng(0))
    steps = steps_of(scenario)
    dt = scenario.run.dt
    loop = ClosedLoop(plant, ctrl, scenario.reference, scenario.disturbance,
                      LoopSettings(dt=dt, steps=steps, block_size=300))
    metrics = MetricsAccumulator(dt, ss_start=0.5 * steps * dt)
    history = History()
    rrd = tmp_path / "fixed.rrd"
    rec = open_recording("tspend_test_protocol", path=rrd)
    info = run_info(scenario, plant, steps, controller=ctrl)
    assert info.controller_kind == "fixed_gain_test" and not info.model_inputs
    end = loop.run(info, [metrics, history, RerunSink(rec)])
    close_recording(rec)
    assert end.status == "completed" and end.steps_done == steps
    h = {k: np.concatenate([b[k] for b in history.blocks]) for k in history.blocks[0]}
    assert h["feedback"].shape == (steps,) and h["sliding"].shape == (steps,)
    # the runner's own keys: e = x - r, and the u the controller returned
    assert np.array_equal(h["e"], h["x"] - h["ref"][:, :2])
    assert np.allclose(h["u"], h["ref"][:, 2] + h["feedback"])
    # the metrics come from the runner's keys, so they hold for any controller
    assert np.isclose(end.metrics["rmse"], np.sqrt(np.mean(h["e"][:, 0] ** 2)), rtol=1e-12)
    assert np.isclose(end.metrics["max_abs_u"], np.abs(h["u"]).max())
    # read back by name
    for name, key in (("feedback", "feedback"), ("sliding", "sliding"), ("u", "u")):
        entity, instance = series_location(name, 2, (), diagnostics=ctrl.diagnostics)
        t, values = read_scalar_series(rrd, entity, instance)
        assert np.array_equal(values, h[key]), name
        assert np.allclose(t, h["t"], atol=1e-12)
