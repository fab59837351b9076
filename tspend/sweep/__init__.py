"""Sweeps and Monte Carlo: many closed loops, one row each, on a local pool or Dask.

The Python API (stable; ``tspend sweep`` and ``tspend compare`` are built on it)::

    sweep(scenarios, *, grid=None, seeds=None, controllers=None, jobs=None, dask=None,
          out=None, record="none", progress=False, executor=None,
          run_timeout=None) -> pandas.DataFrame

``scenarios``
    one scenario (a name such as ``"ex2_duffing"``, a path to a ``.toml``, or a
    :class:`tspend.config.Scenario`, overrides included) or a list of them.
``grid``
    ``{"controller.eta": [0.001, 0.01], "plant.M": [5, 10]}``: any scenario key, each
    value validated like ``--set``/:func:`tspend.override` before anything runs.  The
    sweep runs the cartesian product of the grid, the seeds and the controllers.
``seeds``
    an int, an iterable of ints, or ``"A:B"`` (A to B-1); ``None``: the scenario's seed.
``controllers``
    controller kinds of :data:`tspend.controllers.KINDS` or plug-in specs
    (``file.py:Class``, ``package.module:Class``; a list, or ``"k1,k2"``);
    ``None``: the scenario's own controller.
``jobs``, ``dask``
    ``jobs`` worker processes on this machine (default: one per core), or a Dask
    cluster: ``dask="tcp://host:8786"`` or ``dask="local"`` (a ``LocalCluster`` of
    ``jobs`` workers; needs ``pip install 'tspend[dask]'``).
``out``
    a Parquet table (see :mod:`tspend.sweep.table`): rows are written as runs finish;
    rows already in it are not run again, so the same call after a kill finishes the
    sweep.  ``None``: nothing is written, the rows are only returned.
``record``
    ``"failed"``: a Rerun recording of every run that diverged or failed; ``"all"``:
    of every run; ``"none"``.  Each at its own path (``OUT.recordings/...rrd``, or
    ``runs/sweep-<time>/`` without ``out``), named in the row's ``recording`` column.
``progress``
    a progress bar on a terminal (plain lines every 10 s otherwise).
``executor``
    an executor from :func:`tspend.sweep.executors.make_executor`, reused across calls
    (its workers keep their loaded kernel); it is not closed.
``backend``
    ``"cpu"`` (the default: one process per run, as above) or ``"mjx"``: the runs of a
    scenario point and controller kind stepped together by MuJoCo's JAX engine
    (:mod:`tspend.mjx.sweep`; ``pip install 'tspend[mjx]'``; every kind whose law
    has a JAX form, :func:`tspend.mjx.control.jax_law`); ``precision`` (``"float64"``, ``"float32"``) is its float width.  An
    option the backend would not use is refused: ``precision`` other than float64 on the
    cpu backend, ``dask`` or ``run_timeout`` on the mjx one.
``run_timeout``
    seconds of wall time a run may take once a worker has started it (None: the default,
    :data:`~tspend.runtime.bounds.DEFAULT_RUN_TIMEOUT_S`, an hour, which no shipped
    scenario comes near).  A run past it is killed with its worker process and is a row of
    status ``timeout``; the others go on (those that shared the local pool with it are run
    again, see :func:`_execute`).

Returns the rows of this sweep, in plan order (scenario, grid point, seed, controller),
one per run, columns:

- ``scenario``; one column per grid key (named by the key, e.g. ``controller.eta``,
  holding the value; lists and tables as JSON text); ``seed``; ``controller`` (the kind);
- ``status`` (``completed``, ``diverged``, ``failed``, ``controller_error``, ``timeout``
  (killed past ``run_timeout``), or how the task ended it: ``fell``, ``rail_end``,
  ``joint_limit``, ``state_bound``, ``not_reached``) and ``message`` (why);
- every metric of :data:`tspend.loop.metrics.METRIC_KEYS` (``rmse_ss``, ..., ``wall_s``, the
  loop's wall time), NaN where undefined (a run that failed before its first sample);
- ``version`` (tspend's), ``scenario_hash`` (SHA-256 of the scenario's text, 16 hex
  digits), ``recording`` (path or None), ``job_s`` (the worker's whole time for the run)
  and ``run_key`` (the row's identity, used to resume).

Rows are the same bit for bit, apart from ``wall_s`` and ``job_s``, on either executor
with any number of workers: a run depends only on its scenario, seed and kind.

``tspend.sweep`` is this module, and calling it calls :func:`sweep`.
"""

from __future__ import annotations

import os
import sys
import time
import types
from collections import deque
from pathlib import Path
from typing import Any, Iterable

from tspend.runtime.errors import ScenarioError
from tspend.loop.runner import RunInterrupted, StopRequest
from tspend.runtime.bounds import DEFAULT_RUN_TIMEOUT_S, MAX_RUN_TIMEOUT_S
from tspend.sweep.executors import WorkerDied, make_executor
from tspend.sweep.plan import RECORD_MODES, Job, make_plan
from tspend.sweep.table import KEY_COLUMN, RowTable, TableLock, read_table, typed
from tspend.loop.metrics import is_machine_column
from tspend.sweep.worker import METRIC_COLUMNS, finished_row, run_job

#: columns of every row besides the grid columns, in table order around them
LEADING_COLUMNS = ("scenario",)
TRAILING_COLUMNS = ("seed", "controller", "status", "message") + METRIC_COLUMNS + (
    "version", "scenario_hash", "recording", "job_s", KEY_COLUMN)


def sweep(scenarios: Any, *, grid: dict[str, Iterable[Any]] | None = None,
          seeds: int | Iterable[int] | str | None = None,
          controllers: str | Iterable[str] | None = None, jobs: int | None = None,
          dask: str | None = None, out: str | Path | None = None, record: str = "none",
          progress: bool = False, executor: Any = None,
          stop: StopRequest | None = None, wait: bool = False, build: bool = True,
          run_timeout: float | None = None, backend: str = "cpu",
          precision: str = "float64"):
    """Run every combination of scenario, grid point, seed and controller; one row each.

    See the module docstring for the arguments and the columns.  ``stop`` (a
    :class:`tspend.loop.runner.StopRequest` set by a signal handler) ends the sweep after
    keeping every finished row; :class:`RunInterrupted` is then raised.  ``wait``: when
    another sweep holds the table ``out``, wait for it instead of refusing.  ``build``:
    build each scenario's model and controller once before anything runs (a caller that
    did so already passes False).

    Raises
    ------
    ScenarioError
        any bad input, before a single run starts: a scenario, a grid value, seeds,
        controller kinds, ``jobs``, ``record``, ``run_timeout``, more runs than
        :data:`tspend.runtime.bounds.MAX_RUNS`, a scenario whose model or controller
        cannot be built, an ``out`` that is not a tspend sweep table (or is locked by
        another sweep), a journal that is a symlink or corrupt.
    TspendError
        the worker processes could not start.
    RunInterrupted
        ``stop`` was set; the finished rows are kept in ``out``.
    """
    prepared = prepare_sweep(scenarios, grid=grid, seeds=seeds, controllers=controllers,
                             jobs=jobs, dask=dask, out=out, record=record, stop=stop, wait=wait,
                             build=build, run_timeout=run_timeout, backend=backend,
                             precision=precision)
    return prepared.run(progress=progress, executor=executor, stop=stop)


def check_jobs(jobs: Any) -> None:
    """``jobs`` is None or an integer from 1 to :func:`max_jobs` (ScenarioError)."""
    from tspend.runtime.bounds import MAX_JOBS_PER_CORE
    from tspend.sweep.executors import default_jobs

    if jobs is None:
        return
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ScenarioError(f"--jobs: must be an integer >= 1, got {jobs!r}")
    limit = MAX_JOBS_PER_CORE * default_jobs()
    if jobs > limit:
        raise ScenarioError(f"--jobs {jobs}: at most {limit} ({MAX_JOBS_PER_CORE} per core on "
                            f"this machine; each worker holds its own copy of the kernels)")


#: the status of a row whose run was killed past the sweep's ``run_timeout``
TIMEOUT = "timeout"


def check_run_timeout(seconds: Any) -> float:
    """``--run-timeout``: a number of seconds, > 0 and at most
    :data:`~tspend.runtime.bounds.MAX_RUN_TIMEOUT_S` (ScenarioError); as a float.  None:
    not given, :data:`~tspend.runtime.bounds.DEFAULT_RUN_TIMEOUT_S`."""
    import math

    if seconds is None:
        return DEFAULT_RUN_TIMEOUT_S
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or \
            not math.isfinite(seconds) or not 0 < seconds <= MAX_RUN_TIMEOUT_S:
        raise ScenarioError(f"--run-timeout: must be a number of seconds > 0 and at most "
                            f"{MAX_RUN_TIMEOUT_S:.0f}, got {seconds!r:.80}")
    return float(seconds)


class PreparedSweep:
    """A sweep checked and planned, its table locked: :meth:`run` runs it (once).

    From :func:`prepare_sweep`; a command prints its banner between the two.  The table's
    lock is released by :meth:`run` or :meth:`close`.
    """

    def __init__(self, plan: list[Job], todo: list[Job], table, lock, jobs, dask,
                 run_timeout: float = DEFAULT_RUN_TIMEOUT_S, backend: str = "cpu",
                 precision: str = "float64") -> None:
        self.plan, self.todo, self._table, self._lock = plan, todo, table, lock
        self._jobs, self._dask, self.run_timeout = jobs, dask, run_timeout
        self.backend, self.precision = backend, precision
        self.order = {job.key: job.index for job in plan}

    def close(self) -> None:
        if self._lock is not None:
            self._lock.release()
            self._lock = None

    def run(self, progress: bool = False, executor: Any = None,
            stop: StopRequest | None = None):
        import pandas as pd

        from tspend.runtime.progress import SweepProgress

        todo, table, order = self.todo, self._table, self.order
        rows: list[dict[str, Any]] = []
        shown = SweepProgress(len(todo), skipped=len(self.plan) - len(todo), enabled=progress)
        owned = executor is None and bool(todo)
        try:
            if todo and self.backend == "mjx":
                from tspend.mjx.sweep import run_jobs

                owned = False
                shown.start(1, "mjx")
                for ran in run_jobs(todo, self.precision,
                                    report=lambda line: print(line, file=sys.stderr)):
                    row = finished_row(*ran)
                    if table is not None:
                        table.append(row)
                    rows.append(row)
                    shown.update(row)
                    if stop is not None and stop.signal_name is not None:
                        raise RunInterrupted(stop.signal_name, stop.exit_status)
            elif todo:
                if executor is None:
                    executor = make_executor(self._jobs, self._dask)
                shown.start(executor.workers, executor.name)
                for row in _execute(executor, todo, stop, self.run_timeout):
                    if table is not None:
                        table.append(row)
                    rows.append(row)
                    shown.update(row)
        finally:
            try:
                shown.close()
                if owned and executor is not None:
                    executor.close(cancel=True)
                if table is not None:
                    table.close(order)
            finally:
                self.close()

        if table is not None:
            frame = read_table(table.path)
            frame = frame[frame[KEY_COLUMN].isin(order)] if len(frame) else frame
        else:
            frame = typed(pd.DataFrame.from_records(rows))
        if not len(frame):
            return frame
        frame = frame.assign(_rank=frame[KEY_COLUMN].map(order)).sort_values("_rank")
        return frame.drop(columns="_rank").reset_index(drop=True)


def prepare_sweep(scenarios: Any, *, grid: dict[str, Iterable[Any]] | None = None,
                  seeds: int | Iterable[int] | str | None = None,
                  controllers: str | Iterable[str] | None = None, jobs: int | None = None,
                  dask: str | None = None, out: str | Path | None = None,
                  record: str = "none", stop: StopRequest | None = None,
                  wait: bool = False, build: bool = True,
                  run_timeout: float | None = None, backend: str = "cpu",
                  precision: str = "float64") -> PreparedSweep:
    """Everything :func:`sweep` checks before a run starts, the plan made and ``out``
    locked; raises ScenarioError (see :func:`sweep`).  ``build``: build each scenario's
    model and each controller once now, so a broken one is one error, not a table of
    ``failed`` rows."""
    if out is not None and not isinstance(out, (str, os.PathLike)):
        raise ScenarioError(f"out: expected a path, got {out!r:.80}")
    out_path = Path(out) if out is not None else None
    if out_path is not None and (not str(out).strip() or out_path.name in ("", ".", "..")):
        raise ScenarioError(f"--out {str(out)!r:.80}: not a file name")
    check_jobs(jobs)
    check_unused_options(backend, precision, dask, run_timeout)
    run_timeout = check_run_timeout(run_timeout)
    if dask is not None:
        check_dask_address(dask)
    if record not in RECORD_MODES:
        raise ScenarioError(f"--record {record}: allowed: {', '.join(RECORD_MODES)}")
    record_dir = None
    if record != "none":
        record_dir = (out_path.with_name(out_path.stem + ".recordings") if out_path is not None
                      else Path("runs") / f"sweep-{time.strftime('%Y%m%d-%H%M%S')}")
    plan = make_plan(scenarios, grid, seeds, controllers, record, record_dir)
    if backend != "cpu":
        check_backend(backend, precision, plan)

    table = lock = None
    done_keys: set[str] = set()
    if out_path is not None:
        table = RowTable(out_path)
        table.check_writable()
        lock = TableLock(out_path).acquire(wait=wait, stop=stop)
    try:
        if out_path is not None:
            existing = read_table(out_path)
            _check_compatible(existing, plan, out_path)
            if len(existing):
                done_keys = set(existing[KEY_COLUMN])
        if build:
            build_once(plan)
    except BaseException:
        if lock is not None:
            lock.release()
        raise
    todo = [_unused_recording_path(job) for job in plan if job.key not in done_keys]
    return PreparedSweep(plan, todo, table, lock, jobs, dask, run_timeout, backend, precision)


#: where a sweep's runs are stepped
BACKENDS = ("cpu", "mjx")


def check_unused_options(backend: Any, precision: Any, dask: Any, run_timeout: Any) -> None:
    """An option the chosen backend would not use is refused (ScenarioError), never
    silently ignored: the width and the device are the mjx backend's, the workers and a
    run's time limit the cpu backend's."""
    if backend == "cpu" and precision != "float64":
        raise ScenarioError(f"--precision {str(precision)[:20]}: the cpu backend computes in "
                            f"float64 only; the float width is the mjx backend's "
                            f"(--backend mjx)")
    if backend == "mjx" and dask is not None:
        raise ScenarioError("--dask: the mjx backend steps every run in this process on JAX's "
                            "device, not on Dask workers; drop --dask or use --backend cpu")
    if backend == "mjx" and run_timeout is not None:
        raise ScenarioError("--run-timeout: the mjx backend steps every seed of a scenario at "
                            "once in this process and cannot end one run; drop it or use "
                            "--backend cpu")


def check_backend(backend: Any, precision: Any, plan: list[Job]) -> None:
    """``--backend``, ``--precision`` and what the mjx backend can run (ScenarioError)."""
    if backend not in BACKENDS:
        raise ScenarioError(f"--backend {backend!r}: allowed: {', '.join(BACKENDS)}")
    from tspend.mjx import PRECISIONS, require
    from tspend.mjx.machines import refusal
    from tspend.mjx.sweep import check_memory

    if precision not in PRECISIONS:
        raise ScenarioError(f"--precision {precision!r}: allowed: {', '.join(PRECISIONS)}")
    require()
    # each scenario point's seeds are one fleet, built whole: checked once per point (a
    # million seeds are a million jobs), out of memory said before anything is built
    points: dict[int, tuple[Any, set]] = {}
    for job in plan:
        point = points.setdefault(id(job.scenario), (job.scenario, set()))
        point[1].add(job.seed)
    for scenario, seeds in points.values():
        why = refusal(scenario)
        if why:
            raise ScenarioError(why)
        if scenario.safety.filter != "off":  # checked here: before the banner
            raise ScenarioError(f"{scenario.path or scenario.name}: safety.filter = "
                                f"{scenario.safety.filter!r} is not in the mjx backend; "
                                f"run it on the CPU backend")
        # a kind without a JAX form is refused when its law is asked for
        # (tspend.mjx.control.jax_law), after build_once built it on the CPU
        check_memory(scenario, len(seeds))


#: at most this many (scenario, grid point, controller) builds are tried before a sweep
MAX_BUILDS = 64


def build_once(plan: list[Job]) -> None:
    """Build the plant, task and controller of each scenario / grid point and each kind
    once (not per seed), so that a model that cannot be built is one ScenarioError before
    anything runs.  A plug-in whose constructor raises is bad input too."""
    from tspend.runtime.errors import TspendError
    from tspend.loop.simulation import prepare
    from tspend.runtime.native_logs import mujoco_warnings_in_errors

    seen: set[tuple[int, str | None]] = set()
    points: set[int] = set()
    kinds: set[str | None] = set()
    for job in plan:
        point = id(job.scenario)
        if (point in points and job.run_kind in kinds) or (point, job.run_kind) in seen:
            continue
        seen.add((point, job.run_kind))
        points.add(point)
        kinds.add(job.run_kind)
        try:
            with mujoco_warnings_in_errors(_uses_mujoco(job.scenario)):
                prepare(job.scenario, controller=job.run_kind)
        except TspendError:
            raise
        except (RecursionError, MemoryError) as exc:
            raise ScenarioError(f"{job.label}: cannot be built ({type(exc).__name__})") from None
        except Exception as exc:  # a plug-in's own exception: the user's input
            raise ScenarioError(f"{job.label}, controller {job.controller}: cannot be built "
                                f"({type(exc).__name__}: {exc})") from None
        if len(seen) >= MAX_BUILDS:
            break


def _uses_mujoco(scenario) -> bool:
    from tspend.plants.registry import PLANT_KINDS

    return PLANT_KINDS[scenario.plant.kind].mujoco


def check_dask_address(address: Any) -> None:
    """``local`` or ``[tcp://|tls://|ws://|wss://|inproc://]HOST:PORT`` (ScenarioError)."""
    import re

    if not isinstance(address, str) or not address:
        raise ScenarioError(f"--dask: expected an address or 'local', got {address!r}")
    if address == "local":
        return
    m = re.fullmatch(r"(?:(tcp|tls|ws|wss|ucx)://)?(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]{1,253})"
                     r":(\d{1,5})/?", address)
    if not m or not 0 < int(m.group(3)) < 65536:
        raise ScenarioError(f"--dask {address[:200]}: expected 'local' or a scheduler address "
                            f"such as tcp://127.0.0.1:8786 (a port from 1 to 65535)")


def _execute(executor: Any, todo: list[Job], stop: StopRequest | None,
             run_timeout: float = DEFAULT_RUN_TIMEOUT_S):
    """Rows of ``todo`` as they finish; a job whose worker process dies becomes a row too.

    A few jobs per worker are in flight at a time, so a sweep of a million runs holds a
    million small Job records in the parent, not a million queued tasks.  When a local
    worker dies, the pool fails every job in flight and cannot tell which one killed it;
    those jobs are then run again one at a time, so a death is pinned on its own job and
    the others finish normally.  A job whose worker died while it ran alone is run again,
    up to :data:`MAX_DEATHS` times in all (a worker killed from outside is not the job's
    fault), and only then is a ``failed`` row.  Dask retries a task whose worker died by
    itself, and reports ``KilledWorker`` once it gives up: a ``failed`` row.  Each job
    yields exactly one row.

    A run that takes longer than ``run_timeout`` seconds from its start is killed with its
    worker (:meth:`executor.kill <tspend.sweep.executors.LocalPool.kill>`) and is a
    ``timeout`` row, once; it is not run again.  The start is when a worker took it: a pool
    hands out jobs first in, first out, one at a time per worker, so the jobs running are
    the ``workers`` oldest in flight (stamped at the check after they became so, 0.25 s at
    most late).  The local pool cannot tell which worker runs which job, so the other jobs
    in flight lose their worker too and are run again from the start (not as deaths).
    """
    waiting = deque(todo)
    alone: deque[Job] = deque()           # to run by themselves after a worker died
    workers = max(1, int(getattr(executor, "workers", 1)))
    window = max(16, 4 * workers)
    pending: dict[Any, Job] = {}
    order: dict[Any, int] = {}            # future -> when it was submitted (a count)
    started: dict[Any, float] = {}        # future -> when a worker took it (monotonic s)
    deaths: dict[str, int] = {}
    solo: set[str] = set()                # keys of jobs submitted by themselves
    retries_itself = getattr(executor, "retries_itself", False)
    submitted = 0

    def submit(job: Job) -> None:
        nonlocal submitted
        future = executor.submit(run_job, job)
        pending[future] = job
        order[future] = submitted
        submitted += 1

    def forget(future: Any) -> Job:
        order.pop(future, None)
        started.pop(future, None)
        return pending.pop(future)

    def top_up() -> None:
        if alone:
            if not pending:
                job = alone.popleft()
                solo.add(job.key)
                submit(job)
            return
        while waiting and len(pending) < window:
            submit(waiting.popleft())

    def stamp_started() -> None:
        now = time.monotonic()
        for future in sorted(pending, key=order.__getitem__)[:workers]:
            started.setdefault(future, now)

    top_up()
    stamp_started()
    while pending:
        if stop is not None and stop.signal_name is not None:
            raise RunInterrupted(stop.signal_name, stop.exit_status)
        done = executor.wait(pending, timeout=0.25)
        lost: list[Job] = []
        broken = False
        for future in done:
            job = forget(future)
            try:
                yield executor.result(future)
            except WorkerDied as exc:
                broken = not retries_itself
                if retries_itself:
                    yield _died_row(job, str(exc))
                elif job.key in solo:
                    # it ran alone: the death is its own (or a kill from outside)
                    deaths[job.key] = deaths.get(job.key, 0) + 1
                    if deaths[job.key] >= MAX_DEATHS:
                        yield _died_row(job, str(exc))
                    else:
                        lost.append(job)
                else:
                    lost.append(job)
        if broken:
            # the local pool has failed every job in flight and refuses more: a fresh pool
            # runs them, one at a time
            alone.extend(lost + list(pending.values()))
            pending.clear()
            order.clear()
            started.clear()
            executor.restart()
        else:
            now = time.monotonic()
            late = [f for f, t0 in started.items() if now - t0 > run_timeout]
            if late:
                late_jobs = [(pending[f], now - started[f]) for f in late]
                others_lost = executor.kill(late)
                for future in late:
                    forget(future)
                for job, took in late_jobs:
                    yield _timeout_row(job, run_timeout, took)
                if others_lost:
                    # their worker was killed with it: run again, first, from the start
                    again = sorted(pending, key=order.__getitem__, reverse=True)
                    for future in again:
                        job = pending[future]
                        (alone if job.key in solo else waiting).appendleft(job)
                    pending.clear()
                    order.clear()
                    started.clear()
        top_up()
        stamp_started()


#: a job whose worker dies this many times while it runs alone is a ``failed`` row
MAX_DEATHS = 5


def _died_row(job: Job, why: str) -> dict[str, Any]:
    from tspend import __version__

    row: dict[str, Any] = {"scenario": job.label}
    row.update(job.grid)
    row.update(seed=job.seed, controller=job.controller, status="failed",
               message=f"the worker process died while running it ({why})".strip())
    row.update({k: None for k in METRIC_COLUMNS})
    row.update(version=__version__, scenario_hash=job.scenario_hash, recording=None,
               job_s=None, run_key=job.key)
    return row


def _timeout_row(job: Job, limit_s: float, took_s: float) -> dict[str, Any]:
    """The row of a run killed past the time limit: no metrics (its process is gone)."""
    row = _died_row(job, "")
    row.update(status=TIMEOUT,
               message=f"killed after {took_s:.1f} s of wall time: longer than the run "
                       f"time limit of {limit_s:g} s (--run-timeout)",
               job_s=took_s)
    return row


def _unused_recording_path(job: Job) -> Job:
    """The job, its recording path moved aside if a file is there (never overwritten)."""
    if job.record_path is None or not Path(job.record_path).exists():
        return job
    from dataclasses import replace

    base = Path(job.record_path)
    n = 2
    while (candidate := base.with_name(f"{base.stem}-{n}{base.suffix}")).exists():
        n += 1
    return replace(job, record_path=str(candidate))


def _check_compatible(existing, plan: list[Job], path: Path) -> None:
    """Refuse to mix rows of another grid or of an edited scenario into one table."""
    if not len(existing) or not plan:
        return
    fixed = set(LEADING_COLUMNS) | set(TRAILING_COLUMNS)
    ours = [k for k, _ in plan[0].grid]
    # the flattened machine metrics (joints.slider.max_abs, plant.M ...) are no grid keys
    theirs = [c for c in existing.columns
              if c not in fixed and (not is_machine_column(c) or c in ours)]
    if sorted(theirs) != sorted(ours):
        raise ScenarioError(f"--out {path}: the table holds a sweep over grid keys "
                            f"({', '.join(theirs) or 'none'}), this one is over "
                            f"({', '.join(ours) or 'none'}); choose another --out")
    hashes = dict(zip(existing["scenario"], existing["scenario_hash"]))
    for job in plan:
        old = hashes.get(job.label)
        if old is not None and old != job.scenario_hash:
            raise ScenarioError(f"--out {path}: its '{job.label}' rows were run from another "
                                f"version of that scenario (hash {old}, now "
                                f"{job.scenario_hash}); choose another --out")


class _CallableModule(types.ModuleType):
    """``tspend.sweep(...)`` calls :func:`sweep`, while ``tspend.sweep`` stays this module."""

    def __call__(self, *args: Any, **kwargs: Any):
        return sweep(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule

__all__ = ["sweep", "prepare_sweep", "PreparedSweep", "read_table", "make_executor",
           "make_plan", "Job"]
