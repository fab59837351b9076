"""Time series as tables: a recording exported (tspend export) against the recording read
back and the run's own history, and the progress bar of a long run."""

from __future__ import annotations

import io
import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

import tspend
from tspend.cli.main import main
from tspend.runtime.progress import RunProgress, SweepProgress
from tspend.recorder import RerunSink, close_recording, open_recording, read_scalar_series


def recorded(tmp_path, scenario: str, duration: float = 0.3):
    rrd = tmp_path / f"{scenario}.rrd"
    scn = tspend.override(tspend.load_scenario(scenario), **{"run.duration": duration})
    rec = open_recording("test", path=rrd)
    result = tspend.run(scn, sinks=[RerunSink(rec)])
    close_recording(rec)
    return rrd, result


def export(rrd, out):
    assert main(["export", str(rrd), "--out", str(out)]) == 0  # in process: seconds saved
    if out.suffix == ".csv":
        return pd.read_csv(out)  # a plain CSV: no arguments needed
    return pd.read_parquet(out)


def full(result, name: str) -> np.ndarray:
    return result.history["state"][:, result.plant.state_names.index(name)]


def test_export_of_pendulum_mujoco_names_columns_with_units_and_equals_the_recording(tmp_path):
    rrd, result = recorded(tmp_path, "pendulum_mujoco")
    h = result.history
    for suffix in (".parquet", ".csv"):
        out = tmp_path / f"e{suffix}"
        table = export(rrd, out)
        # one name per quantity: the model's joint (hinge), as in the metrics and to_pandas
        assert list(table.columns[:8]) == ["t_s", "hinge_rad", "hinge_dot_rad_s", "ref_rad",
                                           "ref_dot_rad_s", "ref_ddot_rad_s2", "u_N", "d_N"]
        assert {"slider_m", "slider_dot_m_s", "e_hinge_rad", "u_s_share_N"} <= set(table.columns)
        assert "hinge" in result.metrics["joints"]
        assert list(result.to_pandas().reset_index().columns) == list(table.columns)
        assert not any(" " in c or "[" in c for c in table.columns)
        assert len(table) == 300
        np.testing.assert_allclose(table["t_s"], h["t"], rtol=0, atol=1e-9)  # whole ns
        # as recorded, read back by the reader of tspend.recorder ...
        _, hinge = read_scalar_series(rrd, "series/state/hinge")
        np.testing.assert_array_equal(table["hinge_rad"], hinge)
        _, ref = read_scalar_series(rrd, "series/reference")
        np.testing.assert_array_equal(table[["ref_rad", "ref_dot_rad_s", "ref_ddot_rad_s2"]], ref)
        # ... and as the run had them (the plant's full state, whatever its joints are called)
        np.testing.assert_array_equal(table["hinge_rad"], full(result, "hinge"))
        np.testing.assert_array_equal(table["hinge_dot_rad_s"], h["x"][:, 1])
        np.testing.assert_array_equal(table["slider_m"], full(result, "slider"))
        np.testing.assert_array_equal(table["slider_dot_m_s"], h["extra/cart_vel"])
        np.testing.assert_array_equal(table["u_N"], h["u"])
        np.testing.assert_array_equal(table["d_N"], h["d"])
        np.testing.assert_array_equal(table["e_hinge_rad"], h["e"][:, 0])
    meta = pq.read_schema(tmp_path / "e.parquet").metadata
    assert meta[b"scenario"] == b"pendulum_mujoco" and meta[b"seed"] == b"1"
    assert meta[b"controller"] == b"second_type"
    assert json.loads(meta[b"tspend"])[""]["plant_kind"] == "cartpole_mujoco"
    # the CSV is plain (one header row); its metadata beside it
    assert (tmp_path / "e.csv").read_text().splitlines()[0].startswith("t_s,hinge_rad,")
    side = json.loads((tmp_path / "e.csv.json").read_text())
    assert (side["scenario"], side["seed"], side["controller"]) == ("pendulum_mujoco", 1,
                                                                    "second_type")
    # an existing table is replaced by a complete one, as every command's output (issue 51)
    (tmp_path / "e.csv").write_text("old\n")
    again = subprocess.run([sys.executable, "-m", "tspend.cli", "export", str(rrd), "--out",
                            str(tmp_path / "e.csv")], capture_output=True, text=True)
    assert again.returncode == 0, again.stderr
    assert (tmp_path / "e.csv").read_text().splitlines()[0].startswith("t_s,hinge_rad,")


def test_export_gives_each_rate_its_own_table(tmp_path):
    """A default recording keeps the diagnostics at 50 Hz: the CSV of the every-sample
    series and the CSV of the 50 Hz ones each read back with no empty cell, and hold the
    recorded values at the recorded times (issue 51, item 11: most rows were empty cells)."""
    rrd = tmp_path / "r.rrd"
    assert main(["run", "pendulum_mujoco", "--duration", "0.3", "--out", str(rrd)]) == 0
    every = export(rrd, tmp_path / "r.csv")
    slow = pd.read_csv(tmp_path / "r.50Hz.csv")
    assert len(every) == 300 and every.notna().all().all()
    assert slow.notna().all().all() and "e_hinge_rad" in slow and "e_hinge_rad" not in every
    np.testing.assert_allclose(np.diff(slow["t_s"]), 0.02, atol=1e-9)
    t, e = read_scalar_series(rrd, "series/error")  # recorded at 50 Hz, on its own times
    np.testing.assert_allclose(slow["t_s"], t, atol=1e-9)
    np.testing.assert_array_equal(slow["e_hinge_rad"], e[:, 0])
    side = json.loads((tmp_path / "r.csv.json").read_text())
    assert set(side["tables"]) == {"r.csv", "r.50Hz.csv"}


def test_export_of_furuta_mujoco_names_the_arm_and_the_pendulum(tmp_path):
    rrd, result = recorded(tmp_path, "furuta_mujoco", duration=0.2)
    table = export(rrd, tmp_path / "f.parquet")
    assert list(table.columns[:8]) == ["t_s", "pendulum_rad", "pendulum_dot_rad_s", "ref_rad",
                                       "ref_dot_rad_s", "ref_ddot_rad_s2", "u_V", "d_N_m"]
    assert {"arm_rad", "arm_dot_rad_s", "e_pendulum_rad"} <= set(table.columns)
    for column, name in (("arm_rad", "arm"), ("arm_dot_rad_s", "arm_dot"),
                         ("pendulum_rad", "pendulum"), ("pendulum_dot_rad_s", "pendulum_dot")):
        np.testing.assert_array_equal(table[column], full(result, name))
        _, back = read_scalar_series(rrd, f"series/state/{name}")
        np.testing.assert_array_equal(table[column], back)
    # u_V is the input applied (the command clipped to the motor's +/-10 V), the command
    # is a column of its own
    lo, hi = result.plant.inputs[0].lo, result.plant.inputs[0].hi
    np.testing.assert_array_equal(table["u_V"], np.clip(result.history["u"], lo, hi))
    np.testing.assert_array_equal(table["u_command_V"], result.history["u"])
    meta = pq.read_schema(tmp_path / "f.parquet").metadata
    assert meta[b"scenario"] == b"furuta_mujoco" and meta[b"controller"] == b"second_type"


def test_run_to_pandas_keeps_the_stable_keys():
    scn = tspend.override(tspend.load_scenario("ex3_pendulum_ode"), **{"run.duration": 0.4})
    result = tspend.run(scn)
    with pytest.warns(FutureWarning, match="deprecated"):
        frame = result.to_pandas(units=False)
    assert frame.index.name == "t" and len(frame) == 400
    np.testing.assert_array_equal(frame[["x1", "x2"]].to_numpy(), result.history["x"])
    np.testing.assert_array_equal(frame["b_hat"].to_numpy(), result.history["p"][:, -1])
    assert {"r", "r_d1", "r_d2", "e_1", "e_2", "u", "d", "u_s", "cart_pos"} <= set(frame.columns)


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_long_run_shows_progress_on_a_terminal_only():
    scn = tspend.override(tspend.load_scenario("ex2_duffing"), **{"run.duration": 3.0})
    tty, pipe = _Terminal(), io.StringIO()
    tspend.run(scn, sinks=[RunProgress(stream=tty, after=0.0), RunProgress(stream=pipe, after=0.0)],
               keep_history=False)
    assert "ex2_duffing" in tty.getvalue() and "%" in tty.getvalue()
    assert pipe.getvalue() == ""
    quiet = _Terminal()
    tspend.run(scn, sinks=[RunProgress(stream=quiet, after=60.0)], keep_history=False)
    assert quiet.getvalue() == ""  # shorter than `after`: nothing printed


def test_sweep_progress_lines_off_a_terminal():
    pipe = io.StringIO()
    shown = SweepProgress(3, skipped=2, stream=pipe, every=0.0)
    shown.start(2, "local")
    for status in ("completed", "diverged", "failed"):
        shown.update({"status": status})
    lines = pipe.getvalue().splitlines()
    assert lines[0] == "sweep: 3 runs on 2 local workers, 2 already in the table"
    assert lines[-1].startswith("sweep: 3/3 runs (diverged 1, failed 1)")
