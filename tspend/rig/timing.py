"""Per-cycle stamps of a rig run and the metrics JSON's ``timing`` block."""

from __future__ import annotations

import numpy as np

#: the quantiles the timing block reports
QUANTILES = (("p50", 50.0), ("p99", 99.0), ("p99_9", 99.9))


class CycleLog:
    """Preallocated stamps, one row per cycle (``perf_counter_ns``), and the frames' counts.

    A cycle: its deadline, the wake-up, the sensor frame read (the state handed to the
    controller), the command ready, the command sent."""

    def __init__(self, cycles: int, joints: int) -> None:
        self.deadline = np.zeros(cycles, dtype=np.int64)
        self.wake = np.zeros(cycles, dtype=np.int64)
        self.read = np.zeros(cycles, dtype=np.int64)
        self.ready = np.zeros(cycles, dtype=np.int64)
        self.sent = np.zeros(cycles, dtype=np.int64)
        self.missed = np.zeros(cycles, dtype=bool)
        self.fresh = np.zeros(cycles, dtype=bool)
        self.sensor_seq = np.zeros(cycles, dtype=np.int64)
        self.rig_time_us = np.zeros(cycles, dtype=np.int64)
        self.counts = np.zeros((cycles, joints), dtype=np.int64)
        self.u_sent = np.full(cycles, np.nan)
        #: running totals at each cycle
        self.lost = np.zeros(cycles, dtype=np.int64)
        self.late = np.zeros(cycles, dtype=np.int64)
        self.rejected = np.zeros(cycles, dtype=np.int64)
        self.cycles = 0  # cycles whose command went out (or whose run ended there)

    def series(self, start: int, stop: int) -> dict[str, np.ndarray]:
        """The recorded panels of cycles [start, stop): microseconds and counts."""
        s = slice(start, stop)
        wake = self.wake[s]
        before = self.wake[start - 1] if start else wake[0]
        done = self.sent[s] > 0
        return {
            "lateness_us": (wake - self.deadline[s]) * 1e-3,
            "compute_us": np.where(done, (self.ready[s] - self.read[s]) * 1e-3, np.nan),
            "period_us": np.diff(wake, prepend=before) * 1e-3,
            "missed": self.missed[s].astype(float),
            "frames_lost": self.lost[s].astype(float),
            "frames_late": self.late[s].astype(float),
            "frames_rejected": self.rejected[s].astype(float),
            "fresh": self.fresh[s].astype(float),
            "u_sent": self.u_sent[s],
        }

    def block(self, period_s: float, policy: str) -> dict:
        """The metrics JSON's ``timing`` block over the cycles run."""
        n = self.cycles
        if n == 0:
            return {"cycles": 0, "period_s": period_s, "miss_policy": policy}
        lateness = (self.wake[:n] - self.deadline[:n]) * 1e-3
        done = self.sent[:n] > 0
        compute = (self.ready[:n][done] - self.read[:n][done]) * 1e-3
        misses = int(self.missed[:n].sum())
        return {
            "period_s": period_s, "cycles": n,
            "lateness_us": _stats(lateness), "compute_us": _stats(compute),
            "misses": misses, "miss_share": misses / n, "miss_policy": policy,
            "frames": {"lost": int(self.lost[n - 1]), "late": int(self.late[n - 1]),
                       "corrupt": int(self.rejected[n - 1]),
                       "stale_cycles": int(n - self.fresh[:n].sum())},
        }


def _stats(values_us: np.ndarray) -> dict:
    if values_us.size == 0:
        return {}
    out = {name: float(np.percentile(values_us, q)) for name, q in QUANTILES}
    out["max"] = float(values_us.max())
    return out
