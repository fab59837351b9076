"""Nothing lost, nothing left behind (issue 25): the sweep table under concurrency, its
journal, processes of a killed sweep, MuJoCo's log file, bounds, and the Python API."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

import tspend
from tspend.runtime.errors import TspendError
from tspend.sweep import read_table
from tspend.sweep.table import journal_path, lock_path

from cli_harness import ROOT, spawn, tspend as cli

SWEEP = ("sweep", "ex3_pendulum_ode", "--duration", "0.05", "--jobs", "1")


def _other_schema_parquet(path: Path) -> bytes:
    pd.DataFrame({"a": pd.Series([], dtype="int64"),
                  "b": pd.Series([], dtype=object)}).to_parquet(path, index=False)
    return path.read_bytes()


def test_two_sweeps_on_one_table_keep_every_row(tmp_path):
    first = spawn(*SWEEP, "--seeds", "0:3", "--out", "T.parquet", cwd=tmp_path)
    second = spawn(*SWEEP, "--seeds", "3:6", "--out", "T.parquet", cwd=tmp_path)
    outcomes = []
    for proc, seeds in ((first, range(0, 3)), (second, range(3, 6))):
        out, err = proc.communicate(timeout=240)
        assert proc.returncode in (0, 2), err
        outcomes.append((proc.returncode, set(seeds), err))
    assert any(status == 0 for status, _, _ in outcomes)
    table = read_table(tmp_path / "T.parquet")
    assert table["run_key"].is_unique
    for status, seeds, err in outcomes:
        if status == 0:
            assert seeds <= set(table["seed"])
        else:  # refused before anything ran, naming the other sweep
            assert "another sweep (pid" in err and len(err.strip().splitlines()) == 1
    assert not lock_path(tmp_path / "T.parquet").exists()


def test_second_sweep_refused_while_table_locked_then_waits(tmp_path):
    from tspend.sweep.table import TableLock

    out = tmp_path / "T.parquet"
    with TableLock(out).acquire():
        r = cli(*SWEEP, "--seeds", "0:2", "--out", "T.parquet", cwd=tmp_path)
        assert r.status == 2
        assert f"another sweep (pid {os.getpid()})" in r.one_error_line()
        assert "tspend" not in r.out  # no banner before the refusal
        waiting = spawn(*SWEEP, "--seeds", "0:2", "--out", "T.parquet", "--wait", cwd=tmp_path)
        time.sleep(1.0)
        assert waiting.poll() is None  # waits for the holder
    _, err = waiting.communicate(timeout=240)
    assert waiting.returncode == 0, err
    assert sorted(read_table(out)["seed"]) == [0, 1]


def test_symlinked_journal_is_refused_and_its_target_unchanged(tmp_path):
    victim = tmp_path / "precious.txt"
    victim.write_text("do not append to me\n")
    os.symlink(victim, journal_path(tmp_path / "T.parquet"))
    r = cli(*SWEEP, "--seeds", "0:2", "--out", "T.parquet", cwd=tmp_path)
    assert r.status == 2 and "symbolic link" in r.one_error_line()
    assert victim.read_text() == "do not append to me\n"
    assert not (tmp_path / "T.parquet").exists()


def test_journal_of_another_table_or_corrupt_is_refused(tmp_path):
    journal = journal_path(tmp_path / "T.parquet")
    journal.write_text('{"tspend_journal": "Other.parquet"}\n')
    r = cli(*SWEEP, "--seeds", "0:2", "--out", "T.parquet", cwd=tmp_path)
    assert r.status == 2 and "Other.parquet" in r.one_error_line()
    journal.write_bytes(b'{"run_key": ["a", "list"]}\n' + os.urandom(500))
    before = journal.read_bytes()
    r = cli(*SWEEP, "--seeds", "0:2", "--out", "T.parquet", cwd=tmp_path)
    assert r.status == 2 and "corrupt" in r.one_error_line()
    assert journal.read_bytes() == before


def test_zero_row_parquet_of_another_schema_is_not_replaced(tmp_path):
    target = tmp_path / "T.parquet"
    data = _other_schema_parquet(target)
    r = cli(*SWEEP, "--seeds", "0:2", "--out", "T.parquet", cwd=tmp_path)
    assert r.status == 2 and "not a tspend sweep table" in r.one_error_line()
    assert target.read_bytes() == data
    assert sorted(p.name for p in tmp_path.iterdir()) == ["T.parquet"]


def _children(pid: int) -> list[int]:
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    if int(f.read().rsplit(")", 1)[1].split()[1]) == pid:
                        found.append(int(entry))
            except (OSError, ValueError, IndexError):
                pass
    return found


def _tree(pid: int) -> list[int]:
    todo, seen = [pid], []
    while todo:
        p = todo.pop()
        seen.append(p)
        todo += _children(p)
    return seen


def _running(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_sigkilled_sweep_leaves_no_process(tmp_path):
    proc = subprocess.Popen([sys.executable, "-m", "tspend.cli", "sweep", "pendulum_mujoco",
                             "--jobs", "2", "--seeds", "0:40", "--out", "T.parquet"],
                            cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    # kill it once its fork server and both workers run (a few seconds in)
    deadline = time.monotonic() + 180
    while len(_tree(proc.pid)) < 4 and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.2)
    time.sleep(2.0)
    procs = _tree(proc.pid)[1:]
    assert len(procs) >= 3, "the sweep's workers never started"
    proc.kill()
    proc.wait()
    deadline = time.monotonic() + 10.0
    while any(_running(p) for p in procs) and time.monotonic() < deadline:
        time.sleep(0.2)
    alive = [p for p in procs if _running(p)]
    for p in alive:  # do not leave them to the next test
        os.kill(p, signal.SIGKILL)
    assert not alive, f"processes of the killed sweep still running: {alive}"


def test_inspect_dt_nan_and_export_of_random_bytes_exit_2(tmp_path):
    r = cli("inspect", str(ROOT / "models" / "cartpole.xml"), "--dt", "nan", cwd=tmp_path)
    assert r.status == 2 and "--dt" in r.one_error_line()
    (tmp_path / "R.rrd").write_bytes(os.urandom(5000))
    r = cli("export", "R.rrd", "--out", "x.csv", cwd=tmp_path)
    assert r.status == 2 and "not a readable tspend recording" in r.one_error_line()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["R.rrd"]


def test_huge_seed_range_exits_2_at_once(tmp_path):
    started = time.monotonic()
    proc = subprocess.run(["/usr/bin/time", "-f", "%M", sys.executable, "-m", "tspend.cli",
                           "sweep", "ex3_pendulum_ode", "--seeds", "0:10000000"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=60) \
        if os.path.exists("/usr/bin/time") else None
    if proc is None:
        pytest.skip("no /usr/bin/time")
    assert proc.returncode == 2
    assert time.monotonic() - started < 15.0
    peak_kb = int(proc.stderr.strip().splitlines()[-1])
    assert peak_kb < 1_000_000
    assert "--seeds 0:10000000" in proc.stderr.splitlines()[0]


def test_no_mujoco_log_in_working_directory(tmp_path):
    text = (ROOT / "models" / "cartpole.xml").read_text()
    (tmp_path / "nan.xml").write_text(text.replace('timestep="0.001"', 'timestep="nan"'))
    r = cli("inspect", "nan.xml", cwd=tmp_path)
    assert r.status == 2 and "MuJoCo" in r.one_error_line()
    r = cli("sweep", "pendulum_mujoco", "--duration", "0.05", "--seeds", "0:2", "--jobs", "1",
            cwd=tmp_path)
    assert r.status == 0, r.err
    assert not list(tmp_path.rglob("MUJOCO_LOG.TXT"))


@pytest.mark.parametrize("call", [
    lambda: tspend.run(tspend.load_scenario("ex3_pendulum_ode"), controller="nope"),
    lambda: tspend.load_scenario("no_such_scenario"),
    lambda: tspend.override(tspend.load_scenario("ex3_pendulum_ode"), **{"run.dt": "fast"}),
    lambda: tspend.override(tspend.load_scenario("ex3_pendulum_ode"), **{"nothing.here": 1}),
    lambda: tspend.run(tspend.load_scenario("ex3_pendulum_ode"), overrides=["run.dt"]),
    lambda: tspend.run(5),
    lambda: tspend.run("ex3_pendulum_ode", bogus_option=1),
    lambda: tspend.build_plant(tspend.load_scenario("ex3_pendulum_ode"), "quantum"),
    lambda: tspend.sweep("ex3_pendulum_ode", seeds=range(10**8)),
    lambda: tspend.sweep("ex3_pendulum_ode", jobs=10**6),
    lambda: tspend.sweep("ex3_pendulum_ode", dask="not an address"),
    lambda: tspend.sweep("ex3_pendulum_ode", grid=["controller.eta"]),
], ids=["controller", "scenario", "override value", "override key", "overrides type",
        "scenario type", "option", "plant kind", "seeds", "jobs", "dask", "grid"])
def test_api_raises_tspend_errors(call):
    with pytest.raises(TspendError):
        call()


def test_compare_json_replaced_only_when_complete(tmp_path):
    from tspend.runtime.outputs import write_atomic
    from tspend.runtime.errors import OutputError

    target = tmp_path / "c.json"
    target.write_text('{"old": true}\n')

    def fails(tmp):
        Path(tmp).write_text('{"new": ')
        raise OSError(28, "No space left on device")

    with pytest.raises(OutputError):
        write_atomic(target, fails)
    assert json.loads(target.read_text()) == {"old": True}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.json"]  # no temporary file left
    write_atomic(target, lambda tmp: Path(tmp).write_text('{"new": 1}\n'))
    assert json.loads(target.read_text()) == {"new": 1}
    assert oct(target.stat().st_mode & 0o777) != oct(0o600)  # a new file's usual mode
