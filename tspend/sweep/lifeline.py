"""Processes of a sweep that end when their parent ends, however it ends (SIGKILL too).

A local sweep runs a fork server (``multiprocessing``'s forkserver start method) that
forks the worker processes.  When the sweep is killed outright, nothing in it can stop
them, and a worker busy in compiled code (numba, MuJoCo) holds the GIL, so a watchdog
thread alone may not run for minutes.  So, on Linux, each of them asks the kernel for a
parent-death signal (``prctl(PR_SET_PDEATHSIG, SIGKILL)``): the sweep's death kills the
fork server, whose death kills the workers, at once.  A watchdog thread on the sweep's pid
covers the systems without ``prctl``.

Importing :mod:`tspend.sweep.forkserver_lifeline` in the fork server (as its preload) is
what arms the fork server; :func:`init_worker <tspend.sweep.worker.init_worker>` arms a
worker.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time

__all__ = ["die_with_parent", "watch_parent"]

#: linux/prctl.h
PR_SET_PDEATHSIG = 1


def die_with_parent(expected_parent: int | None = None, sig: int = signal.SIGKILL) -> bool:
    """Have the kernel send ``sig`` to this process when its parent ends (Linux only).

    ``expected_parent``: if the parent is already another process (the real one died
    before the call), exit now.  Returns whether the kernel took the request.
    """
    armed = False
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            armed = libc.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
        except (OSError, AttributeError):
            armed = False
    if expected_parent is not None and os.getppid() != expected_parent:
        os._exit(1)  # orphaned before the request took effect
    return armed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def watch_parent(pids: tuple[int, ...], interval_s: float = 0.5) -> threading.Thread:
    """A daemon thread that ends this process once any of ``pids`` is gone, or this
    process's parent changes (it was orphaned)."""
    parent = os.getppid()

    def watch() -> None:
        while True:
            time.sleep(interval_s)
            if os.getppid() != parent or not all(_alive(p) for p in pids):
                os._exit(1)

    thread = threading.Thread(target=watch, name="tspend-lifeline", daemon=True)
    thread.start()
    return thread
