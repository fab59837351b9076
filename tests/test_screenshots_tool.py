"""tools/screenshots.py without a browser: bad input exits 2 with one line, the PNG size
check reads the real IHDR, and a process group it started is ended whole."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

TOOL = Path(__file__).resolve().parents[1] / "tools" / "screenshots.py"


@pytest.fixture(scope="module")
def tool():
    spec = importlib.util.spec_from_file_location("screenshots_tool", TOOL)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_bad_input_exits_2(tool, tmp_path, capsys):
    assert tool.main([str(tmp_path), str(tmp_path / "missing.rrd")]) == 2
    assert capsys.readouterr().err.count("\n") == 1
    with pytest.raises(SystemExit) as exc:
        tool.main([str(tmp_path), str(TOOL), "--size", "1280by800"])
    assert exc.value.code == 2


def test_png_size_is_read_from_the_file(tool, tmp_path):
    matplotlib = pytest.importorskip("matplotlib")
    from matplotlib.figure import Figure
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = Figure(figsize=(3.2, 2.0), dpi=100)
    FigureCanvasAgg(fig)
    path = tmp_path / "x.png"
    fig.savefig(path)
    assert tool.png_size(path.read_bytes()) == (320, 200)
    with pytest.raises(RuntimeError, match="not the 1280x800"):
        tool.write_png(tmp_path / "y.png", path.read_bytes(), 1280, 800)
    assert not (tmp_path / "y.png").exists()


def test_a_started_group_is_ended_whole(tool):
    """A leader and its child (which ignores SIGTERM) are both gone after end_group."""
    code = ("import signal, subprocess, sys, time; "
            "child = subprocess.Popen([sys.executable, '-c', "
            "'import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); time.sleep(60)']); "
            "print(child.pid, flush=True); time.sleep(60)")
    leader = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                              start_new_session=True)
    child = int(leader.stdout.readline())
    tool.end_group(leader, grace_s=2.0)
    assert leader.poll() is not None
    for _ in range(50):
        try:
            state = Path(f"/proc/{child}/stat").read_text().split()[2]
        except FileNotFoundError:
            break
        if state == "Z":        # ended, awaiting its (ended) parent's reaper
            break
        import time
        time.sleep(0.1)
    else:
        pytest.fail(f"child {child} still runs")


def test_docs_runs_are_recorded_by_tspend_and_nothing_is_left(tool, tmp_path, capsys):
    """``--docs`` records with ``tspend`` in a group of its own; the runs it makes are the
    documentation's four (default, cross-check, swing-up, Furuta)."""
    assert [args[:2] for args in tool.DOCS_RUNS.values()] == [
        ["run", "pendulum_mujoco"], ["crosscheck", "pendulum_mujoco"], ["run", "swingup_mujoco"],
        ["run", "furuta_mujoco"]]
    rrd = tool.record("tiny", ["run", "ex2_duffing", "--duration", "0.05"], tmp_path)
    assert rrd == tmp_path / "tiny.rrd" and rrd.stat().st_size > 0
    with pytest.raises(RuntimeError, match="failed"):
        tool.record("bad", ["run", "no_such_scenario"], tmp_path)
    with pytest.raises(SystemExit) as exc:
        tool.main([str(tmp_path)])  # neither recordings nor --docs
    assert exc.value.code == 2
