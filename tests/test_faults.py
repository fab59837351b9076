"""Divergence, interruption and recordings that survive them (issues 4 and 6)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader

from tspend import load_scenario, override, run
from tspend.cli.main import main
from tspend.recorder.timeseries import recording_table
from tspend.recorder import RerunSink, close_recording, open_recording, read_scalar_series, series_location

ROOT = Path(__file__).resolve().parents[1]


def _pole_angle(rrd: Path):
    """(t, the tracked angle) at every recorded sample (a compact recording's views are
    thinned; its exported table holds every sample)."""
    table, _ = recording_table(rrd)
    return table["t_s"].to_numpy(), table.iloc[:, 1].to_numpy()


def test_recording_equals_run_arrays_sample_for_sample(tmp_path):
    scn = override(load_scenario("pendulum_mujoco"), **{"run.duration": 2.0})
    rec = open_recording("tspend_test", path=tmp_path / "r.rrd")
    result = run(scn, sinks=[RerunSink(rec)])
    close_recording(rec)
    t, theta = _pole_angle(tmp_path / "r.rrd")
    np.testing.assert_array_equal(theta, result.history["x"][:, 0])
    np.testing.assert_allclose(t, result.history["t"], atol=1e-9)
    # the controller's inner state arrives at the snapshot rate (every 0.1 s of 2 s)
    rows = {}
    for chunk in RrdReader(tmp_path / "r.rrd").stream():
        if "sim_time" in chunk.timeline_names and chunk.entity_path.startswith("/fuzzy/"):
            rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.to_record_batch().num_rows
    for entity in ("/fuzzy/firing", "/fuzzy/consequents", "/fuzzy/compensator_firing",
                   "/fuzzy/model/in0", "/fuzzy/compensator/in1"):
        assert rows.get(entity) == 20, (entity, rows)


def test_divergence_exit_3_with_recording_and_metrics(tmp_path, capsys):
    rrd, mj = tmp_path / "div.rrd", tmp_path / "m.json"
    status = main(["run", "ex3_pendulum_ode", "--out", str(rrd), "--metrics", str(mj),
                   "--set", "controller.b_min=1.0", "--set", "plant.state_bound=1.0"])
    assert status == 3
    err = capsys.readouterr().err
    assert "diverged at t = " in err and "state_bound" in err
    m = json.loads(mj.read_text())
    assert m["status"] == "diverged" and 0 < m["steps"] < 20000
    assert m["sim_s"] == pytest.approx(m["steps"] * 0.001)
    t, theta = _pole_angle(rrd)
    assert len(theta) == m["steps"]                     # every simulated sample recorded
    assert np.abs(theta).max() < 1.0


def test_non_finite_parameter_stops_the_run():
    scn = override(load_scenario("ex1_nonaffine_case2"), **{"controller.gamma": 3.0})
    r = run(scn)
    assert r.status == "diverged"
    assert "not finite" in r.end.message or "plant failed" in r.end.message
    assert np.all(np.isfinite(r.history["u"]))          # only finite samples are kept
    assert r.metrics["steps"] == len(r.history["t"]) < 20000


def test_projection_holds_when_inputs_leave_every_interval():
    """Inputs far outside the sets: firing stays normalised, b_hat >= b_min throughout."""
    scn = override(load_scenario("ex3_pendulum_ode"), **{
        "run.duration": 1.0, "plant.x0": [0.7, 0.0],
        "controller.sets.states": [{"terms": 5, "lo": -0.01, "hi": 0.01}] * 2,
        "controller.sets.u": {"terms": 3, "lo": -0.1, "hi": 0.1},
        "controller.sets.e_delta": {"terms": 5, "lo": -0.01, "hi": 0.01}})
    r = run(scn)
    assert np.all(np.isfinite(r.history["p"]))
    assert r.history["min_b"].min() >= scn.controller.b_min
    assert r.history["p"][:, -1].min() >= scn.controller.b_min * (1 - 1e-12)


@pytest.mark.parametrize("sig,code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signal_flushes_recording(tmp_path, sig, code):
    rrd, mj = tmp_path / "s.rrd", tmp_path / "m.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "tspend.cli", "run", "pendulum_mujoco", "--duration", "3000",
         "--out", str(rrd), "--metrics", str(mj)],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 60
    # wait until the run is under way: the recording (written beside its target until
    # the run ends) holds some blocks
    partial = tmp_path / ".s.partial.rrd"
    while time.time() < deadline and (not partial.exists() or partial.stat().st_size < 200_000):
        time.sleep(0.2)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    assert "interrupted" in err
    m = json.loads(mj.read_text())
    assert m["status"] == "interrupted" and m["steps"] > 0
    t, theta = _pole_angle(rrd)
    assert len(theta) == m["steps"] and np.all(np.isfinite(theta))
    assert not partial.exists()


def test_missing_viewer_runs_headless(tmp_path, capsys):
    status = main(["run", "ex2_duffing", "--duration", "0.05", "--connect",
                   "rerun+http://127.0.0.1:9/proxy", "--out", str(tmp_path / "v.rrd")])
    assert status == 0
    assert (tmp_path / "v.rrd").stat().st_size > 0
    assert "viewer" in capsys.readouterr().err.lower()


def test_record_every_decimates_the_series(tmp_path, capsys):
    rrd = tmp_path / "d.rrd"
    assert main(["run", "ex2_duffing", "--duration", "1", "--record-every", "10",
                 "--out", str(rrd)]) == 0
    t, x1 = _pole_angle(rrd)
    assert len(x1) == 100 and t[1] - t[0] == pytest.approx(0.01)
    assert main(["run", "ex2_duffing", "--record-every", "0", "--no-record"]) == 2
    assert "--record-every" in capsys.readouterr().err
