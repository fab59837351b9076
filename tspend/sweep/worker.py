"""One run of a sweep, in a worker process: :func:`run_job` turns a :class:`Job` into
its row.

A worker process is reused for many runs, so the controller kernel is compiled or loaded
from numba's cache once per worker.  Nothing a run does can end the sweep: a diverged run
is a row with its metrics up to the stop, an exception is a ``failed`` row with its
message.  With ``record="failed"`` a run that did not complete is run once more with a
recorder attached; runs are deterministic, so the recording shows exactly that run.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path
from typing import Any

from tspend import __version__
from tspend.loop.metrics import METRIC_KEYS, flatten
from tspend.sweep.plan import Job

#: metric columns of a row (the seed has its own column already)
METRIC_COLUMNS = tuple(k for k in METRIC_KEYS if k != "seed")


def _seeded(job: Job):
    """The job's scenario with its seed (applied here, in parallel, not in the parent)."""
    from tspend.controllers import load
    from tspend.scenario import override

    if job.run_kind is not None:
        load(job.run_kind)  # a plug-in's [controllers.KIND] table is then known here too
    if job.seed == job.scenario.run.seed:
        return job.scenario
    return override(job.scenario, **{"run.seed": job.seed})


def _recorded_run(job: Job, path: Path):
    from tspend.recorder import RerunSink, close_recording, open_recording
    from tspend.loop.simulation import run

    path.parent.mkdir(parents=True, exist_ok=True)
    rec = open_recording(f"tspend_sweep_{job.label}", path=path)
    try:
        return run(_seeded(job), sinks=[RerunSink(rec)], keep_history=False,
                   controller=job.run_kind)
    finally:
        close_recording(rec)


def _attempt(job: Job, record_to: Path | None) -> tuple[str, str, dict]:
    from tspend.plants.registry import PLANT_KINDS
    from tspend.runtime.native_logs import mujoco_warnings

    if not PLANT_KINDS[job.scenario.plant.kind].mujoco:
        return _attempt_quietly(job, record_to)
    with mujoco_warnings() as notes:  # MuJoCo's warnings: in the row, not in a file
        status, message, metrics = _attempt_quietly(job, record_to)
    if notes:
        shown = "; ".join(notes[:5]) + (f"; and {len(notes) - 5} more" if len(notes) > 5 else "")
        message = f"{message} (MuJoCo: {shown})" if message else f"MuJoCo: {shown}"
    return status, message, metrics


def _attempt_quietly(job: Job, record_to: Path | None) -> tuple[str, str, dict]:
    from tspend.loop.simulation import run

    try:
        result = (_recorded_run(job, record_to) if record_to is not None else
                  run(_seeded(job), keep_history=False, controller=job.run_kind))
    except Exception as exc:  # a failed run is a row, never the end of the sweep
        return "failed", f"{type(exc).__name__}: {exc}", {}
    end = result.end
    return end.status, end.message, end.metrics


def run_job(job: Job) -> dict[str, Any]:
    """The row of ``job``: its identity, how it ended, every metric, where it is recorded."""
    started = time.perf_counter()
    if job.cwd and job.cwd != os.getcwd() and os.path.isdir(job.cwd):
        os.chdir(job.cwd)  # a worker started before the caller changed directory
    recording = None
    if job.record == "all":
        recording = Path(job.record_path)
        status, message, metrics = _attempt(job, recording)
    else:
        status, message, metrics = _attempt(job, None)
        if job.record == "failed" and status != "completed":
            recording = Path(job.record_path)
            _attempt(job, recording)
    return table_row(job, status, message, metrics,
                     str(recording) if recording is not None else None,
                     time.perf_counter() - started)


def finished_row(job: Job, status: str, message: str, metrics: dict, job_s: float) -> dict[str, Any]:
    """The row of ``job`` as another backend ran it (:func:`tspend.mjx.sweep.run_jobs`),
    recorded when the plan asks by the CPU run of the same job (runs are deterministic; a
    recording run that fails leaves the row without a recording, as :func:`run_job`)."""
    recording = None
    if job.record == "all" or (job.record == "failed" and status != "completed"):
        path = Path(job.record_path)
        _attempt(job, path)
        recording = str(path) if path.exists() else None
    return table_row(job, status, message, metrics, recording, job_s)


def table_row(job: Job, status: str, message: str, metrics: dict, recording: str | None,
              job_s: float) -> dict[str, Any]:
    """The sweep table's row of ``job`` (whichever backend ran it): its identity, how it
    ended, every metric, where it is recorded and how long it took."""
    row: dict[str, Any] = {"scenario": job.label}
    row.update(job.grid)
    row.update(seed=job.seed, controller=job.controller, status=status, message=message)
    row.update({k: metrics.get(k) for k in METRIC_COLUMNS})
    # the whole machine's metrics, flattened: joints.slider.max_abs, plant.M, ...
    row.update({k: v for k, v in flatten(metrics).items()
                if k not in row and k not in METRIC_KEYS})
    row.update(version=__version__, scenario_hash=job.scenario_hash, recording=recording,
               job_s=job_s, run_key=job.key)
    return row


# -- worker process set-up -----------------------------------------------------------------
def init_worker(sweep_pid: int | None = None) -> None:
    """Pool initialiser: Ctrl-C is the parent's to handle; the worker ends when its parent
    (the fork server) or the sweep ``sweep_pid`` ends, even by SIGKILL
    (:mod:`tspend.sweep.lifeline`: a parent-death signal, and a watchdog thread).

    Each worker is a session of its own: Linux's autogroup scheduler shares the CPU between
    sessions, so workers left in the sweep's session would share one session's share
    between them on a busy machine, and W workers would run no faster than one.
    """
    from tspend.sweep.lifeline import die_with_parent, watch_parent

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent(expected_parent=os.getppid())
    watch_parent((sweep_pid,) if sweep_pid else ())
    try:
        os.setsid()
    except (AttributeError, OSError):  # not POSIX, or already a session leader
        pass


def warm(_: int = 0) -> int:
    """Load the controller kernel in this worker (what the first run would otherwise pay)."""
    from tspend.scenario import load_scenario
    from tspend.loop.simulation import build_controller
    from tspend.shipped import data_root

    # the shipped file, whatever the caller's folders hold
    build_controller(load_scenario(data_root() / "scenarios" / "ex3_pendulum_ode.toml"))
    return os.getpid()
