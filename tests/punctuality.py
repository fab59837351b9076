"""The machine's punctuality while a ``realtime`` test runs: a witness apart from the code
under test (tests/conftest.py starts it beside each such test and reads it at the end).

It wakes every millisecond on an absolute schedule, by sleeping alone (nothing spun: it
takes about 1 % of a core), under SCHED_FIFO at a priority above the rig runner's (50)
and the C rig end's (40), so neither the suite's other work nor the processes under test
delay it: what delays it is the machine itself (a virtual machine's host taking its cores,
a kernel stall).  On SIGTERM it prints one JSON line: its wake-ups, the share of them
later than ``LATE_US`` in its worst second, and its largest lateness.

Run alone to see this machine's: ``python tests/punctuality.py 5`` (5 s)."""

from __future__ import annotations

import json
import os
import signal
import sys
import time
from array import array

PERIOD_NS = 1_000_000
#: a wake-up this late would have made a 2 ms rig cycle's frame or command miss its cycle
LATE_US = 300
#: above the rig runner's SCHED_FIFO priority (tspend.rig.realtime.FIFO_PRIORITY, 50)
PRIORITY = 60


def watch(stop_after_s: float | None = None) -> dict:
    """Wake every PERIOD_NS until SIGTERM (or ``stop_after_s``); the summary."""
    fifo = _fifo()
    stopped = []
    signal.signal(signal.SIGTERM, lambda *_: stopped.append(True))
    lateness_ns, at_ns = array("q"), array("q")
    clock = time.perf_counter_ns
    t0 = clock()
    k = 0
    while not stopped and (stop_after_s is None or clock() - t0 < stop_after_s * 1e9):
        k += 1
        deadline = t0 + k * PERIOD_NS
        ahead = deadline - clock()
        if ahead > 0:
            time.sleep(ahead * 1e-9)
        now = clock()
        lateness_ns.append(now - deadline)
        at_ns.append(now - t0)
        k = max(k, (now - t0) // PERIOD_NS)  # a stall counts once, not as a burst after it
    return summary(lateness_ns, at_ns, fifo)


def summary(lateness_ns, at_ns, fifo: bool) -> dict:
    late_by_second: dict[int, list[int]] = {}
    for lateness, at in zip(lateness_ns, at_ns):
        counts = late_by_second.setdefault(at // 1_000_000_000, [0, 0])
        counts[0] += 1
        counts[1] += lateness > LATE_US * 1000
    worst = max((late / n for n, late in late_by_second.values()), default=0.0)
    return {"wakes": len(lateness_ns), "fifo": fifo, "late_us": LATE_US,
            "worst_second_late_share": worst,
            "max_lateness_ms": max(lateness_ns, default=0) * 1e-6}


def _fifo() -> bool:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(PRIORITY))
        return True
    except (AttributeError, OSError):  # not Linux, or not allowed: it says so
        return False


if __name__ == "__main__":
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else None
    print(json.dumps(watch(seconds)), flush=True)
