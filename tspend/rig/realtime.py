"""Real time on a general-purpose OS: an absolute schedule, sleep then spin, garbage
collection paused, ``SCHED_FIFO`` and locked memory where the OS allows it.

Measured on the project's 2-core machine (docs/rig.md, benchmarks/rig_timing.py): the
scheduling class matters more than the sleep; plain ``time.sleep`` wakes milliseconds late
under load, a FIFO thread microseconds late.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import os
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterator

#: the loop sleeps to this long before a deadline, then spins on the clock (ns)
SPIN_NS = 200_000
#: the FIFO priority of the loop thread (1-99; the kernel's own threads sit at 50)
FIFO_PRIORITY = 50
_MCL_CURRENT, _MCL_FUTURE, _MCL_ONFAULT = 1, 2, 4


def wait_until(deadline_ns: int, spin_ns: int = SPIN_NS) -> int:
    """Sleep to ``spin_ns`` before ``deadline_ns`` (``perf_counter_ns``), spin to it, and
    return the wake-up time (ns)."""
    clock = time.perf_counter_ns
    ahead = deadline_ns - clock() - spin_ns
    if ahead > 0:
        time.sleep(ahead * 1e-9)
    now = clock()
    while now < deadline_ns:
        now = clock()
    return now


@dataclass
class RealTimeState:
    """What the process was granted: the lines say what was not, and why."""

    sched_fifo: bool = False
    memory_locked: bool = False
    gc_paused: bool = False
    notes: tuple[str, ...] = ()

    def as_dict(self) -> dict:
        return {"sched_fifo": self.sched_fifo, "memory_locked": self.memory_locked,
                "gc_paused": self.gc_paused, "notes": list(self.notes)}


def _lock_memory() -> str:
    """mlockall (pages locked as they are touched, so nothing is read in at once); "" or
    why not."""
    name = ctypes.util.find_library("c")
    if name is None:
        return "locked memory: no C library found"
    libc = ctypes.CDLL(name, use_errno=True)
    if libc.mlockall(_MCL_CURRENT | _MCL_FUTURE | _MCL_ONFAULT) != 0:
        return f"locked memory: not allowed ({os.strerror(ctypes.get_errno())})"
    return ""


def _unlock_memory() -> None:
    name = ctypes.util.find_library("c")
    if name is not None:
        ctypes.CDLL(name).munlockall()


@contextmanager
def real_time(fifo: bool = True, lock: bool = True) -> Iterator[RealTimeState]:
    """The calling thread under ``SCHED_FIFO``, memory locked, garbage collection paused
    (the objects alive so far frozen out of it), all undone on exit."""
    state, notes = RealTimeState(), []
    previous_policy = os.sched_getscheduler(0) if hasattr(os, "sched_getscheduler") else None
    if fifo and previous_policy is not None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(FIFO_PRIORITY))
            state.sched_fifo = True
        except OSError as exc:
            notes.append(f"SCHED_FIFO: not allowed ({exc.strerror}); the loop runs at normal "
                         f"priority and wakes later under load")
    elif fifo:
        notes.append("SCHED_FIFO: this OS has no sched_setscheduler")
    if lock:
        why = _lock_memory()
        state.memory_locked = not why
        if why:
            notes.append(why)
    gc.collect()
    gc.freeze()
    gc.disable()
    state.gc_paused = True
    state.notes = tuple(notes)
    try:
        yield state
    finally:
        gc.enable()
        gc.unfreeze()
        if state.memory_locked:
            _unlock_memory()
        if state.sched_fifo:
            os.sched_setscheduler(0, previous_policy, os.sched_param(0))
