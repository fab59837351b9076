"""Where a sweep's runs execute: a local pool of worker processes, or a Dask cluster.

Both take jobs one at a time (:meth:`submit`) and hand back finished futures as they
complete (:meth:`wait`), so rows are written as runs finish.  Worker processes are kept
for the whole sweep (and across sweeps when the executor is passed in), so each loads
the controller kernel once.  Either way a row depends only on its job, never on which
worker ran it or when: the same sweep gives the same rows on any executor.
"""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor
from concurrent.futures import wait as wait_futures
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Callable, Iterable

from tspend.runtime.errors import ScenarioError, TspendError
from tspend.sweep.worker import init_worker, warm

DASK_EXTRA = "pip install 'tspend[dask]'"


class WorkerDied(Exception):
    """The process running a job died (killed, out of memory, a crash in native code)."""


def default_jobs() -> int:
    """The number of cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


class LocalPool:
    """``jobs`` worker processes on this machine (forkserver: no inherited threads)."""

    name = "local"
    retries_itself = False

    def __init__(self, jobs: int | None = None) -> None:
        self.jobs = jobs or default_jobs()
        if self.jobs < 1:
            raise ScenarioError(f"--jobs: must be >= 1, got {self.jobs}")
        self._pool: ProcessPoolExecutor | None = None
        self._start()
        self.warm()

    def _start(self) -> None:
        method = "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() \
            else "spawn"
        context = multiprocessing.get_context(method)
        if method == "forkserver":
            # the fork server arms its parent-death signal as it starts (tspend.sweep.lifeline)
            context.set_forkserver_preload(["__main__", "tspend.sweep.forkserver_lifeline"])
        self._pool = ProcessPoolExecutor(self.jobs, mp_context=context, initializer=init_worker,
                                         initargs=(os.getpid(),))

    @property
    def workers(self) -> int:
        return self.jobs

    def warm(self) -> None:
        """Start the workers and load the kernel in them, or say why they cannot start."""
        try:
            list(self._pool.map(warm, range(self.jobs)))
        except BrokenProcessPool:
            raise TspendError("the sweep's worker processes could not start; from a script, "
                              "call sweep() under `if __name__ == \"__main__\":` (Python's "
                              "rule for process pools)") from None

    def submit(self, fn: Callable, job: Any) -> Future:
        try:
            return self._pool.submit(fn, job)
        except BrokenProcessPool as exc:
            # a worker died since the last wait: the job comes back as lost, and is rerun
            future: Future = Future()
            future.set_exception(exc)
            return future

    def wait(self, futures: Iterable[Future], timeout: float) -> set[Future]:
        done, _ = wait_futures(list(futures), timeout=timeout, return_when=FIRST_COMPLETED)
        return done

    def result(self, future: Future) -> Any:
        try:
            return future.result()
        except BrokenProcessPool as exc:
            raise WorkerDied(str(exc)) from None

    def restart(self) -> None:
        """A new pool after a worker died (the old one refuses further work)."""
        self.close(cancel=True)
        self._start()

    def kill(self, futures: Iterable[Future]) -> bool:
        """End the runs of ``futures`` (past their time limit) now: which worker runs which
        job is the pool's secret, so every worker is killed (SIGKILL: a run stuck in
        compiled code or ignoring SIGTERM ends too) and a fresh pool started.  Returns True:
        the other jobs in flight are lost and must be submitted again."""
        pool = self._pool
        if pool is not None:
            for process in list(getattr(pool, "_processes", {}).values()):
                try:
                    process.kill()
                except (OSError, ValueError):  # already gone
                    pass
        self.restart()
        return True

    def close(self, cancel: bool = False) -> None:
        pool, self._pool = self._pool, None
        if pool is None:
            return
        if cancel:
            # runs in progress are abandoned (they are rerun next time): stop them now
            for process in list(getattr(pool, "_processes", {}).values()):
                process.terminate()
        pool.shutdown(wait=True, cancel_futures=cancel)

    def __enter__(self) -> "LocalPool":
        return self

    def __exit__(self, *exc) -> None:
        self.close(cancel=exc[0] is not None)


class DaskExecutor:
    """Runs on a Dask distributed cluster at ``address``; ``"local"`` starts a
    ``LocalCluster`` of ``jobs`` single-threaded worker processes on this machine."""

    name = "dask"
    #: the scheduler reruns a task whose worker died, and reports KilledWorker when it gives up
    retries_itself = True

    def __init__(self, address: str, jobs: int | None = None) -> None:
        try:
            from dask.distributed import Client, LocalCluster
        except ImportError:
            raise ScenarioError(f"--dask needs dask.distributed, an optional extra: "
                              f"{DASK_EXTRA}") from None
        self._cluster = None
        if address == "local":
            self._cluster = LocalCluster(n_workers=jobs or default_jobs(), threads_per_worker=1,
                                         processes=True, dashboard_address=None)
            self.client = Client(self._cluster)
        else:
            try:
                self.client = Client(address, timeout="10s")
            except Exception as exc:  # noqa: BLE001 - unreachable, refused, not a scheduler
                raise ScenarioError(f"--dask {address[:200]}: cannot reach the scheduler "
                                    f"({type(exc).__name__}: "
                                    f"{' '.join(str(exc).split())[:200]})") from None

    @property
    def workers(self) -> int:
        return max(1, sum(self.client.nthreads().values()))

    def warm(self) -> None:
        self.client.run(warm)

    def submit(self, fn: Callable, job: Any):
        return self.client.submit(fn, job, pure=False)

    def wait(self, futures: Iterable[Any], timeout: float) -> set[Any]:
        from dask.distributed import wait as dask_wait

        try:
            done, _ = dask_wait(list(futures), timeout=timeout, return_when="FIRST_COMPLETED")
        except TimeoutError:
            return set()
        return set(done)

    def result(self, future: Any) -> Any:
        from distributed.scheduler import KilledWorker

        try:
            return future.result()
        except KilledWorker as exc:
            raise WorkerDied(str(exc)) from None

    def restart(self) -> None:
        pass

    def kill(self, futures: Iterable[Any]) -> bool:
        """End the runs of ``futures`` (past their time limit): each is cancelled, and the
        worker processes running them are restarted by their nannies (a thread cannot be
        stopped).  Returns False: the scheduler reruns any other task those workers held."""
        futures = list(futures)
        keys = {f.key for f in futures}
        try:
            holders = [w for w, held in self.client.processing().items()
                       if keys.intersection(held)]
        except Exception:  # noqa: BLE001 - the scheduler is gone: nothing more to stop
            holders = []
        self.client.cancel(futures, force=True)
        if holders:
            try:
                self.client.restart_workers(holders, raise_for_error=False)
            except Exception:  # noqa: BLE001 - a worker without a nanny: it shuts down
                pass
        return False

    def close(self, cancel: bool = False) -> None:
        self.client.close()
        if self._cluster is not None:
            self._cluster.close()

    def __enter__(self) -> "DaskExecutor":
        return self

    def __exit__(self, *exc) -> None:
        self.close(cancel=exc[0] is not None)


def make_executor(jobs: int | None = None, dask: str | None = None):
    """A :class:`DaskExecutor` for ``dask`` (an address or ``"local"``), else a
    :class:`LocalPool` of ``jobs`` workers."""
    if jobs is not None and jobs < 1:
        raise ScenarioError(f"--jobs: must be >= 1, got {jobs}")
    return DaskExecutor(dask, jobs) if dask else LocalPool(jobs)
