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


#: the span of one window of the clock offset's minimum (s): long enough to hold arrivals
#: without queueing delay (50 frames at 2 ms), short enough that a crystal's drift (50
#: ppm) moves the offset by 5 us within it
CLOCK_WINDOW_S = 0.1
#: the fewest cycles a window holds
CLOCK_WINDOW_CYCLES = 20
#: a rig clock gaining or losing more than this on the host's (us per s, i.e. ppm) is said
#: in one line: twice a common crystal's tolerance
CLOCK_WARN_US_PER_S = 100.0
#: a re-alignment moves the schedule by at most this many bounds: a crystal's drift (up to
#: 1000 ppm) moves the offset less in two windows, a spell of queued frames more
REALIGN_STEP_BOUNDS = 2
#: the most windows the drift's fit takes (evenly spread over the run)
DRIFT_FIT_WINDOWS = 400


class ClockTracker:
    """The offset between the host's clock and the rig's timestamps over a run.

    Each sensor frame's arrival (host ns, stamped as it is read) minus its rig timestamp is
    a lag: the clocks' offset plus the frame's transit and queueing.  Its minimum over a
    window of :data:`CLOCK_WINDOW_S` drops the queueing, so the minima follow the offset
    alone; their slope against the host's time (a Theil-Sen fit) is the drift.  When a window's minimum has
    moved from the schedule's reference by more than ``bound_ns``, the schedule moves with
    it (:meth:`end_of_cycle` returns the shift): the deadlines stay on the rig's clock.

    A spell of queued frames two windows long looks like the offset moving: a shift is at
    most :data:`REALIGN_STEP_BOUNDS` bounds, so such a spell moves the schedule that much at
    most, and the windows after it move it back.  A frame already waiting when the host
    woke to listen is stamped at the wake: its lag follows the schedule, not the link, so a
    window whose every frame was waiting is kept out of the drift's fit (a schedule late
    by a spell would tilt it)."""

    def __init__(self, reference_ns: int, period_ns: int, bound_ns: int) -> None:
        self.reference_ns, self.bound_ns = reference_ns, bound_ns
        self.window_cycles = max(CLOCK_WINDOW_CYCLES, round(CLOCK_WINDOW_S * 1e9 / period_ns))
        self.windows: list[tuple[int, int]] = []  # (host ns at the window's end, min lag ns)
        self.realigned = 0
        self.shift_ns = 0
        self._min: int | None = None
        self._heard = 0  # frames of this window that arrived while the host listened
        self._calibrated = False
        self._pending = 0  # the previous window's excess past the bound (0: none)

    def arrived(self, host_ns: int, rig_time_us: int, waiting: bool = False) -> None:
        """A frame read at ``host_ns``; ``waiting``: it was there when the host woke."""
        lag = host_ns - rig_time_us * 1000
        self._heard += not waiting
        if self._min is None or lag < self._min:
            self._min = lag

    def end_of_cycle(self, cycle: int, host_ns: int) -> int:
        """The shift (ns) to add to the schedule after ``cycle``: 0 but at the end of the
        second window in a row whose minimum left the reference by more than the bound on
        the same side (one window's outlier on a jittery link moves nothing); then the
        smaller of the two excesses.  The first window's minimum is the reference (the
        start's few frames would set it higher than a window of them)."""
        if (cycle + 1) % self.window_cycles or self._min is None:
            return 0
        if self._heard:
            self.windows.append((host_ns, self._min))
        excess, self._min, self._heard = self._min - self.reference_ns, None, 0
        if not self._calibrated:
            self._calibrated, self.reference_ns = True, self.reference_ns + excess
            return 0
        if abs(excess) <= self.bound_ns:
            self._pending = 0
            return 0
        previous, self._pending = self._pending, excess
        if previous == 0 or (previous > 0) != (excess > 0):
            return 0
        most = REALIGN_STEP_BOUNDS * self.bound_ns
        shift = max(-most, min(most, min(previous, excess, key=abs)))
        self._pending = 0
        self.reference_ns += shift
        self.realigned += 1
        self.shift_ns += shift
        return shift

    def gain_us_per_s(self) -> float | None:
        """How fast the rig's clock gains on the host's (us per s; negative: it loses); None
        before two windows."""
        if len(self.windows) < 2:
            return None
        from scipy.stats import theilslopes

        # Theil-Sen (the median of the pairwise slopes): a window whose every frame
        # queued (a load spike) does not tilt it; its cost is quadratic, so a long run's
        # windows are thinned to an even subset
        picked = np.unique(np.linspace(0, len(self.windows) - 1, DRIFT_FIT_WINDOWS).astype(int))
        host_s = np.array([self.windows[i][0] for i in picked], dtype=float) * 1e-9
        lag_us = np.array([self.windows[i][1] for i in picked], dtype=float) * 1e-3
        return float(-theilslopes(lag_us - lag_us[0], host_s - host_s[0])[0])

    def block(self) -> dict:
        """The timing block's ``clock`` entry."""
        return {"rig_gain_us_per_s": self.gain_us_per_s(), "windows": len(self.windows),
                "window_cycles": self.window_cycles, "realigned": self.realigned,
                "realign_bound_us": self.bound_ns * 1e-3, "schedule_shift_us": self.shift_ns * 1e-3}

    def warning(self) -> str:
        """One line when the drift is past :data:`CLOCK_WARN_US_PER_S`; "" otherwise."""
        gain = self.gain_us_per_s()
        if gain is None or abs(gain) <= CLOCK_WARN_US_PER_S:
            return ""
        return (f"the rig's clock {'gains' if gain > 0 else 'loses'} {abs(gain):.0f} us per s "
                f"on the host's (more than {CLOCK_WARN_US_PER_S:g}): the schedule followed it "
                f"({self.realigned} re-alignments, {self.shift_ns * 1e-3:.0f} us in all); "
                f"check the rig's oscillator")
