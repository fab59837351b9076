"""Sweeps: resumed after a kill, the same rows on every executor, diverged runs as rows.

The rows are checked against runs made directly with :func:`tspend.run` (another path to
the same numbers), recordings are read back from the ``.rrd`` files, and the table is
read back with pandas.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import tspend
from tspend.runtime.errors import ScenarioError
from tspend.sweep import plan
from tspend.sweep.table import journal_path, read_table

WALL = ["wall_s", "job_s"]


def _direct(name: str, seed: int, kind: str | None = None, **changes) -> dict:
    s = tspend.override(tspend.load_scenario(name), **{"run.seed": seed, **changes})
    return tspend.run(s, keep_history=False, controller=kind).metrics


def test_killed_sweep_restarted_ends_with_every_row_once(tmp_path):
    out = tmp_path / "t.parquet"
    seeds = 40
    cmd = [sys.executable, "-m", "tspend.cli", "sweep", "ex3_pendulum_ode", "--duration", "0.5",
           "--seeds", f"0:{seeds}", "--jobs", "1", "--record", "none", "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    journal = journal_path(out)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        # the header naming the table, then three rows
        if journal.exists() and journal.read_text().count("\n") >= 4:
            break
        time.sleep(0.01)
    os.killpg(proc.pid, signal.SIGKILL)  # no chance to tidy up: the worst case
    proc.wait()
    partial = read_table(out)
    assert 3 <= len(partial) < seeds, "the kill must land mid-way for this test to mean much"
    assert partial["run_key"].is_unique
    # a line cut short by the kill must not break the table
    with open(journal, "a") as f:
        f.write('{"scenario": "ex3_pendulum_ode", "se')

    rerun = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr
    assert "already in the table" in rerun.stderr
    table = pd.read_parquet(out)  # one plain Parquet file, journal folded in
    assert not journal.exists()
    assert sorted(table["seed"]) == list(range(seeds))
    assert table["run_key"].is_unique and (table["status"] == "completed").all()
    for seed in (0, seeds - 1):
        row = table[table["seed"] == seed].iloc[0]
        direct = _direct("ex3_pendulum_ode", seed, **{"run.duration": 0.5})
        assert row["rmse_ss"] == direct["rmse_ss"] and row["itae"] == direct["itae"]


def test_local_pool_and_dask_local_give_identical_rows(tmp_path):
    pytest.importorskip("dask.distributed")
    args = dict(grid={"controller.gamma": [0.8, 1.6]}, seeds="0:3",
                controllers=["second_type", "first_type"])
    scn = tspend.override(tspend.load_scenario("ex2_duffing"), **{"run.duration": 0.5})
    local = tspend.sweep(scn, jobs=1, out=tmp_path / "local.parquet", **args)
    dask = tspend.sweep(scn, jobs=2, dask="local", **args)
    assert len(local) == 2 * 3 * 2 and (local["status"] == "completed").all()
    pd.testing.assert_frame_equal(local.drop(columns=WALL), dask.drop(columns=WALL),
                                  check_exact=True)
    row = local[(local["seed"] == 2) & (local["controller"] == "first_type")
                & (local["controller.gamma"] == 0.8)].iloc[0]
    assert row["rmse_ss"] == _direct("ex2_duffing", 2, "first_type", **{
        "run.duration": 0.5, "controller.gamma": 0.8})["rmse_ss"]


def test_grid_where_some_runs_diverge_completes_with_those_rows_marked(tmp_path):
    from tspend.recorder import read_scalar_series

    out = tmp_path / "bound.parquet"
    # the pendulum's u peaks near 52 N: a bound of 20 N stops those runs as diverged
    table = tspend.sweep("ex3_pendulum_ode", grid={"run.control_bound": [0.0, 20.0],
                                                   "run.duration": [0.5]},
                         seeds=[0, 1], jobs=1, out=out, record="failed")
    assert len(table) == 4
    bounded = table[table["run.control_bound"] == 20.0]
    free = table[table["run.control_bound"] == 0.0]
    assert (bounded["status"] == "diverged").all()
    assert bounded["message"].str.contains("exceeds control_bound 20").all()
    assert (free["status"] == "completed").all() and free["recording"].isna().all()
    for _, row in bounded.iterrows():
        t, u = read_scalar_series(row["recording"], "series/control")
        assert len(t) == row["steps"] and np.max(np.abs(u)) > 20.0
        assert Path(row["recording"]).parent == tmp_path / "bound.recordings"
    assert bounded["recording"].is_unique


def test_broken_model_stops_before_anything_runs(tmp_path):
    # the model of each grid point is built once before the sweep starts: a missing file
    # is bad input, not a table of failed rows
    scn = tspend.override(tspend.load_scenario("pendulum_mujoco"), **{"run.duration": 0.2})
    out = tmp_path / "t.parquet"
    with pytest.raises(ScenarioError, match="missing.xml"):
        tspend.sweep(scn, grid={"plant.model": ["models/cartpole.xml",
                                                str(tmp_path / "missing.xml")]}, jobs=1, out=out)
    assert not out.exists() and not journal_path(out).exists()


def test_failed_run_is_a_row(tmp_path):
    # a controller that builds but raises while running: a failed row, the sweep goes on
    (tmp_path / "boom.py").write_text(
        "import numpy as np\n"
        "from tspend.controllers.base import Controller\n"
        "class Boom(Controller):\n"
        "    kind = 'boom'\n"
        "    def __init__(self, scenario):\n"
        "        self.order = len(scenario.plant.x0)\n"
        "        self.diagnostics = ()\n"
        "        self.diag = np.zeros(0)\n"
        "    def reset(self, rng):\n"
        "        pass\n"
        "    def step(self, obs, dt):\n"
        "        raise RuntimeError('boom at run time')\n")
    scn = tspend.override(tspend.load_scenario("ex3_pendulum_ode"), **{"run.duration": 0.2})
    table = tspend.sweep(scn, controllers=["lqr", f"{tmp_path / 'boom.py'}:Boom"], jobs=1)
    # the plug-in's own failure: its row says so (not tspend's "failed")
    assert list(table["status"]) == ["completed", "controller_error"]
    assert "boom at run time" in table["message"].iloc[1]
    assert np.isnan(table["rmse"].iloc[1]) and table["rmse"].dtype == np.float64


def test_bad_grid_value_stops_before_anything_runs(tmp_path):
    out = tmp_path / "x.parquet"
    r = subprocess.run([sys.executable, "-m", "tspend.cli", "sweep", "ex2_duffing",
                        "--grid", "controller.eta=0.1,-1", "--out", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 2
    assert "controller.eta: must be > 0, got -1" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not out.exists() and not journal_path(out).exists()


def test_grid_and_seed_parsing():
    assert plan.parse_grid(["controller.eta=0.1,1", 'plant.x0=[0.1, 0],[0.2,0]']) == {
        "controller.eta": [0.1, 1], "plant.x0": [[0.1, 0], [0.2, 0]]}
    assert plan.parse_seeds("0:3") == [0, 1, 2] and plan.parse_seeds("4,7") == [4, 7]
    for bad in ("3:1", "a", "-1"):
        with pytest.raises(ScenarioError):
            plan.parse_seeds(bad)
    with pytest.raises(ScenarioError, match="expected KEY=V1"):
        plan.parse_grid(["controller.eta"])


def test_table_refuses_another_grid(tmp_path):
    out = tmp_path / "g.parquet"
    scn = tspend.override(tspend.load_scenario("ex2_duffing"), **{"run.duration": 0.1})
    tspend.sweep(scn, grid={"controller.gamma": [1.0]}, jobs=1, out=out)
    with pytest.raises(ScenarioError, match="grid keys"):
        tspend.sweep(scn, grid={"controller.eta": [0.1]}, jobs=1, out=out)
    assert len(pd.read_parquet(out)) == 1


def test_without_dask_the_error_names_the_extra(tmp_path, monkeypatch, capsys):
    from tspend.cli.main import main

    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # as if not installed
    out = tmp_path / "d.parquet"
    status = main(["sweep", "ex2_duffing", "--duration", "0.1", "--dask", "local",
                   "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1
    assert "pip install 'tspend[dask]'" in err[0]
    assert not out.exists() and not journal_path(out).exists()


def test_a_job_whose_worker_dies_is_a_failed_row_and_the_rest_run_once():
    from concurrent.futures import Future

    from tspend.sweep import MAX_DEATHS, _execute
    from tspend.sweep.executors import WorkerDied

    jobs = plan.make_plan(tspend.override(tspend.load_scenario("ex2_duffing"),
                                          **{"run.duration": 0.01}), seeds=range(4))
    crasher = jobs[1].key

    class Executor:
        """In-process stand-in for the pool: the crasher's worker dies every time."""

        name = "local"
        restarts = 0

        def submit(self, fn, job):
            f = Future()
            f.job = job
            f.set_running_or_notify_cancel()
            return f

        def wait(self, futures, timeout):
            return set(futures)

        def result(self, f):
            if f.job.key == crasher:
                raise WorkerDied("killed")
            return {"run_key": f.job.key, "status": "completed"}

        def restart(self):
            self.restarts += 1

    executor = Executor()
    rows = list(_execute(executor, jobs, None))
    assert sorted(r["run_key"] for r in rows) == sorted(j.key for j in jobs)
    dead = next(r for r in rows if r["run_key"] == crasher)
    assert dead["status"] == "failed" and "worker process died" in dead["message"]
    # once for the death among others, then MAX_DEATHS times alone (a kill from outside is
    # not the job's fault: it is tried again before it is a failed row)
    assert executor.restarts == 1 + MAX_DEATHS


def test_a_worker_killed_mid_run_costs_nothing_but_time(tmp_path):
    import threading

    from tspend.sweep.executors import LocalPool

    out = tmp_path / "k.parquet"
    scn = tspend.override(tspend.load_scenario("ex3_pendulum_ode"), **{"run.duration": 1.0})
    with LocalPool(1) as pool:
        first = set(pool._pool._processes)  # the worker to kill (the pool's own record)

        def kill_when_a_row_is_in() -> None:
            while not (journal_path(out).exists() and journal_path(out).read_text()):
                time.sleep(0.005)
            for pid in first:
                os.kill(pid, signal.SIGKILL)

        killer = threading.Thread(target=kill_when_a_row_is_in, daemon=True)
        killer.start()
        table = tspend.sweep(scn, seeds=range(8), executor=pool, out=out)
        killer.join(timeout=5)
        assert set(pool._pool._processes).isdisjoint(first)  # a fresh pool took over
    assert sorted(table["seed"]) == list(range(8)) and table["run_key"].is_unique
    assert (table["status"] == "completed").all()
    direct = _direct("ex3_pendulum_ode", 5, **{"run.duration": 1.0})
    assert table["rmse_ss"].iloc[5] == direct["rmse_ss"]


SLEEPER = ("import time\n"
           "from tspend.controllers.base import Controller\n"
           "class Sleeps(Controller):\n"
           "    kind = 'sleeps'\n"
           "    def __init__(self, scenario, settings=None):\n"
           "        self.order = len(scenario.plant.x0)\n"
           "    def reset(self, rng):\n"
           "        pass\n"
           "    def step(self, obs, dt):\n"
           "        time.sleep(1000)\n"
           "        return 0.0\n")


def _processes_in(directory: Path) -> list[int]:
    """Processes whose working directory is ``directory`` (zombies aside)."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit() or int(entry) == os.getpid():
            continue
        try:
            if os.readlink(f"/proc/{entry}/cwd") != str(directory):
                continue
            with open(f"/proc/{entry}/stat") as f:
                if f.read().rsplit(")", 1)[1].split()[0] == "Z":
                    continue
        except OSError:
            continue
        found.append(int(entry))
    return found


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_runs_past_the_time_limit_are_timeout_rows_once_and_leave_no_process(tmp_path):
    # one worker: the second run waits for the first's kill and a fresh pool, then is
    # killed on its own (a run that could finish is the stand-in test's below: on a loaded
    # machine its worker's start alone can outlast a limit short enough for a quick test)
    (tmp_path / "sleeper.py").write_text(SLEEPER)
    out = tmp_path / "t.parquet"
    r = subprocess.run([sys.executable, "-m", "tspend.cli", "sweep", "ex3_pendulum_ode",
                        "--duration", "0.2", "--controller", "sleeper.py:Sleeps",
                        "--seeds", "0:2", "--jobs", "1", "--run-timeout", "2", "--out",
                        str(out), "--record", "none"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == 7, r.stderr  # EXIT_INCOMPLETE
    assert "2 of 2 runs did not complete: 2 timeout" in r.stderr
    assert "timeout" in r.stdout  # the summary's column
    table = read_table(out)
    assert table["run_key"].is_unique and sorted(table["seed"]) == [0, 1]
    assert (table["status"] == "timeout").all()
    assert table["message"].str.contains("longer than the run time limit of 2 s").all()
    assert table["rmse_ss"].isna().all() and (table["job_s"] >= 2).all()
    # the killed workers, the pool and its fork server are gone with the sweep
    deadline = time.monotonic() + 5.0
    while _processes_in(tmp_path) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert _processes_in(tmp_path) == []


def test_a_late_job_is_killed_once_and_the_jobs_that_shared_its_pool_run_again():
    from concurrent.futures import Future

    from tspend.sweep import _execute

    jobs = plan.make_plan(tspend.override(tspend.load_scenario("ex2_duffing"),
                                          **{"run.duration": 0.01}), seeds=range(4))
    late, first, beside, last = (j.key for j in jobs)
    began = time.monotonic()

    class Executor:
        """In-process stand-in for a pool of 2 taking jobs in order: the late job never
        finishes; ``first`` runs beside it for 0.6 s, then ``beside`` takes its worker and
        runs until the kill, which loses every job in flight (as the local pool's does)."""

        name = "local"
        workers = 2
        killed: list = []
        submitted: list = []

        def submit(self, fn, job):
            f = Future()
            f.job = job
            self.submitted.append(job.key)
            return f

        def wait(self, futures, timeout):
            time.sleep(0.01)
            done = {first: time.monotonic() - began > 0.6, beside: bool(self.killed),
                    late: False, last: True}
            return {f for f in futures if done[f.job.key]}

        def result(self, f):
            return {"run_key": f.job.key, "status": "completed"}

        def kill(self, futures):
            self.killed.append([f.job.key for f in futures])
            return True

        def restart(self):
            raise AssertionError("a timeout is no worker death")

    executor = Executor()
    rows = list(_execute(executor, jobs, None, run_timeout=1.0))
    assert sorted(r["run_key"] for r in rows) == sorted(j.key for j in jobs)  # each once
    assert [r["run_key"] for r in rows if r["status"] == "timeout"] == [late]
    assert executor.killed == [[late]]
    assert executor.submitted.count(late) == 1            # never run again
    assert executor.submitted.count(beside) == 2          # lost with the kill: run again
    assert time.monotonic() - began >= 1.0                # not before its time
