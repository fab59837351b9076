"""Time series as tables: a run's history (RunResult.to_pandas) against its recording read
back from the .rrd (tspend export), and the progress bar of a long run."""

from __future__ import annotations

import io
import subprocess
import sys

import numpy as np
import pandas as pd

import tspend
from tspend.runtime.progress import RunProgress, SweepProgress
from tspend.recorder import RerunSink, close_recording, open_recording


def test_run_to_pandas_equals_its_exported_recording(tmp_path):
    rrd = tmp_path / "r.rrd"
    scn = tspend.override(tspend.load_scenario("ex3_pendulum_ode"), **{"run.duration": 0.4})
    rec = open_recording("test", path=rrd)
    result = tspend.run(scn, sinks=[RerunSink(rec)])
    close_recording(rec)
    frame = result.to_pandas(units=False)
    assert frame.index.name == "t" and len(frame) == 400
    np.testing.assert_array_equal(frame[["x1", "x2"]].to_numpy(), result.history["x"])
    np.testing.assert_array_equal(frame["b_hat"].to_numpy(), result.history["p"][:, -1])
    assert {"r", "r_d1", "r_d2", "e_1", "e_2", "u", "d", "u_s", "cart_pos"} <= set(frame.columns)

    for suffix in (".parquet", ".csv"):
        out = tmp_path / f"e{suffix}"
        r = subprocess.run([sys.executable, "-m", "tspend.cli", "export", str(rrd), "--to",
                            str(out)], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        exported = (pd.read_parquet(out) if suffix == ".parquet"
                    else pd.read_csv(out, index_col="t"))
        common = [c for c in exported.columns if c in frame.columns]
        assert {"r", "x1", "e_1", "u", "d", "u_s", "b_hat", "cart_pos"} <= set(common)
        np.testing.assert_allclose(exported.index.to_numpy(), frame.index.to_numpy(),
                                   rtol=0, atol=1e-9)  # the recording keeps whole ns
        np.testing.assert_array_equal(exported[common].to_numpy(), frame[common].to_numpy())
    again = subprocess.run([sys.executable, "-m", "tspend.cli", "export", str(rrd), "--to",
                            str(tmp_path / "e.csv")], capture_output=True, text=True)
    assert again.returncode == 2 and "exists" in again.stderr


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
