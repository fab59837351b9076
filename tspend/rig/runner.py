"""The real-time runner: the scenario's controller closing the loop on a rig.

The rig is a :class:`~tspend.plants.base.Plant` to the closed loop (:class:`RigPlant`):
reading its full state waits for the cycle's deadline on an absolute schedule (sleep, then
spin) and takes the newest sensor frame; stepping it sends the command.  So the loop, its
task checks, recordings and metrics are those of a simulated run; what a rig adds (the
stamps of every cycle, the frames' counts, the miss policy) lives here.

Every exit sends a zero command and a stop frame (:meth:`RigSession.close`), whatever
ended the run: completed, the task (rail, fall angle), a signal, an error.
"""

from __future__ import annotations

import time
import warnings
from contextlib import contextmanager
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tspend.runtime.errors import DivergenceError
from tspend.plants.base import Plant
from tspend.rig import protocol
from tspend.rig.estimator import ModelFacade, VelocityEstimator, sensor_state
from tspend.rig.links import FIRST_FRAME_TIMEOUT_S, RigLink, RigRefused
from tspend.rig.protocol import Command, Hello
from tspend.rig.realtime import SPIN_NS, wait_until
from tspend.rig.timing import ClockTracker, CycleLog

MISS_POLICIES = ("hold", "zero", "stop")
#: the first deadline comes this share of a period after the first sensor frame arrived:
#: a frame's arrival jitter up to it still lands before its deadline, and the command
#: still reaches a rig that integrates each step at its end (the double) within the
#: sample it answers
ALIGN_SHARE = 0.1
#: frames whose arrival aligns the schedule on the rig's clock
ALIGN_FRAMES = 5
#: the host polls for frames from this share of a period before each deadline on, stamping
#: each arrival (the clock's drift is measured on them): twice the expected arrival's lead
LISTEN_SHARE = 2 * ALIGN_SHARE
#: the schedule re-aligns on the rig's clock when the offset moved by this share of a
#: period: arrivals then stay inside the listening window and before their deadline
REALIGN_SHARE = ALIGN_SHARE / 2
#: the rig's watchdog must outlast this many periods (a command a period late is not a
#: lost host)
WATCHDOG_PERIODS = 2
#: sensor frames queried before START, a period apart, for the state the start is checked
#: from (the velocity estimator's filter settles over them: 20 ms at 2 ms against its 5 ms)
PRE_START_FRAMES = 10


class DeadlineMissed(DivergenceError):
    """Miss policy ``stop``: a command was ready after its period had ended."""


class RigSilent(DivergenceError):
    """No sensor frame for longer than the rig's watchdog: the rig is gone or stopped."""


def machine_id(plant: Plant) -> str:
    """What a rig's hello must state: ``<domain>:<joint>,<joint>`` in the model's order."""
    return f"{plant.domain}:{','.join(j.name for j in plant.joints)}"


def check_hello(hello: Hello, plant: Plant, where: str) -> None:
    """Refuse (one line) a rig that is not this scenario's machine."""
    expected = machine_id(plant)
    if hello.machine != expected:
        raise RigRefused(f"{where}: the rig is '{hello.machine}', the scenario's machine is "
                         f"'{expected}'")
    if len(hello.counts_per_unit) != len(plant.joints) or \
            not all(np.isfinite(c) and c > 0 for c in hello.counts_per_unit):
        raise RigRefused(f"{where}: the hello states counts per unit {hello.counts_per_unit}, "
                         f"not one positive number per joint ({len(plant.joints)})")


def choose_period(requested_s: float, hello: Hello, where: str) -> float:
    """The scenario's period, raised to the shortest the rig accepts (the caller says so)."""
    period = max(requested_s, hello.min_period_s)
    if period > hello.max_period_s:
        raise RigRefused(f"{where}: the rig accepts periods of {hello.min_period_s * 1e3:g} to "
                         f"{hello.max_period_s * 1e3:g} ms, not {requested_s * 1e3:g} ms")
    if WATCHDOG_PERIODS * period > hello.watchdog_s:
        raise RigRefused(f"{where}: the rig's watchdog ({hello.watchdog_s * 1e3:g} ms) is shorter "
                         f"than {WATCHDOG_PERIODS} periods of {period * 1e3:g} ms: one late "
                         f"command would stop the motor")
    return period


def check_line(link: RigLink, period_s: float) -> None:
    """Refuse a period the link cannot carry, before any frame is sent."""
    shortest = link.shortest_period_s()
    if shortest > period_s:
        raise RigRefused(f"{link.describe()}: one cycle's frames take {shortest * 1e3:.3g} ms "
                         f"of line time, longer than the period {period_s * 1e3:g} ms: raise "
                         f"the baud rate or the period (run.control_period)")


@dataclass(frozen=True)
class RigSettings:
    period_s: float
    cycles: int
    miss_policy: str = "hold"
    estimator: VelocityEstimator = VelocityEstimator()


class RigPlant(ModelFacade):
    """The rig as the closed loop's plant; the model plant answers what the rig does not
    (names, units, joints, inputs, the task's defaults)."""

    def __init__(self, machine: Plant, link: RigLink, hello: Hello, settings: RigSettings) -> None:
        self.machine, self.link, self.hello, self.settings = machine, link, hello, settings
        self.order, self.domain, self.name = machine.order, machine.domain, f"rig:{machine.name}"
        self.log = CycleLog(settings.cycles, len(machine.joints))
        self.sensors = sensor_state(machine, hello.counts_per_unit, settings.estimator)
        self._period_ns = round(settings.period_s * 1e9)
        self._t0_ns = 0
        self._cycle = 0
        self._read_cycle = -1
        self._highest_seq = -1
        self._first_seq = 0
        self._used_seq = -1
        self._lost = self._late = 0
        self._last_sent = 0.0
        self._silent = ""  # why the rig counts as gone ("" while it is not)
        self.clock: ClockTracker | None = None  # from the first frames on (begin)
        #: the state read before START for its check (:meth:`check_start`; None: none)
        self.start_state: np.ndarray | None = None
        self._held_back = False  # the check refused the start: START is never sent

    def reset(self, x0: np.ndarray) -> None:
        """The rig is where it is: its first frame, not x0, is the initial state."""

    # before the start
    def state_before_start(self) -> np.ndarray | None:
        """The full state from :data:`PRE_START_FRAMES` queried frames a period apart
        (the motor off; velocities from the run's own estimator); None where the link
        reads no state before START."""
        sensors = sensor_state(self.machine, self.hello.counts_per_unit, self.settings.estimator)
        for i in range(PRE_START_FRAMES):
            if i:
                wait_until(time.perf_counter_ns() + self._period_ns)
            frame = self.link.query()
            if frame is None:
                return None
            sensors.fresh(np.asarray(frame.counts, dtype=np.int64), frame.rig_time_us)
        return sensors.state.copy()

    def check_start(self, check: Callable[[np.ndarray | None], bool]) -> None:
        """Before START: ``check`` given the state read then (None where the link reads
        none) says whether to start; refused, START is never sent and the loop's first
        read is that state."""
        self.start_state = self.state_before_start()
        if not check(self.start_state):
            self._held_back = True
            self.sensors.state[:] = self.start_state

    # the cycle
    def begin(self) -> bool:
        """Start sampling and align the schedule on the rig's clock: the offset between
        the host's clock and the rig's timestamps is the smallest seen over the first
        :data:`ALIGN_FRAMES` frames (polled without sleeping, so each arrival is stamped
        when it lands); cycle 0 is the frame after them.  False, nothing started, when the
        check before the start refused it (:meth:`check_start`)."""
        if self._held_back:
            return False
        self.link.start(self.settings.period_s)
        until = time.monotonic() + FIRST_FRAME_TIMEOUT_S
        seen, offset = [], None
        clock = time.perf_counter_ns
        while len(seen) < ALIGN_FRAMES and time.monotonic() < until:
            for frame in self.link.poll():
                arrived = clock()
                seen.append(frame)
                lag = arrived - frame.rig_time_us * 1000
                offset = lag if offset is None else min(offset, lag)
        if not seen:
            raise RigRefused(f"{self.link.describe()}: no sensor frame within "
                             f"{FIRST_FRAME_TIMEOUT_S:g} s of the start")
        last = seen[-1]
        self._first_seq, self._highest_seq = last.seq + 1, last.seq
        self._t0_ns = (offset + last.rig_time_us * 1000 + self._period_ns
                       + round(ALIGN_SHARE * self._period_ns))
        self._last_fresh_ns = self._t0_ns
        self.clock = ClockTracker(offset, self._period_ns,
                                  round(REALIGN_SHARE * self._period_ns))
        return True

    def full_state(self) -> np.ndarray:
        k = self._cycle
        if self._read_cycle == k:
            return self.sensors.state.copy()
        if self._held_back or (not self._t0_ns and not self.begin()):
            # the first read starts the rig (here, so nothing before it delays cycle 0),
            # unless the check refused its start: the state it refused, nothing sampled
            return self.sensors.state.copy()
        log = self.log
        log.deadline[k] = deadline = self._t0_ns + k * self._period_ns
        frames, log.wake[k] = self._listen(deadline)
        newest = self._take_frames(k, frames)
        fresh_frame = newest is not None and newest.seq > self._used_seq
        if fresh_frame:
            self._last_fresh_ns = log.wake[k]
        elif log.wake[k] - self._last_fresh_ns > self.hello.watchdog_s * 1e9:
            # raised by step(), before anything is sent: the loop then ends the run as a
            # plant failure, with what was recorded kept
            self._silent = (f"no sensor frame from {self.link.describe()} for "
                            f"{(log.wake[k] - self._last_fresh_ns) * 1e-6:.0f} ms, longer than "
                            f"its watchdog ({self.hello.watchdog_s * 1e3:g} ms): the rig is gone")
        if fresh_frame:
            self._used_seq = newest.seq
            counts = np.asarray(newest.counts, dtype=np.int64)
            self.sensors.fresh(counts, newest.rig_time_us)
            log.fresh[k] = True
            log.sensor_seq[k], log.rig_time_us[k] = newest.seq, newest.rig_time_us
            log.counts[k] = counts
        elif k:
            log.sensor_seq[k], log.rig_time_us[k] = log.sensor_seq[k - 1], log.rig_time_us[k - 1]
            log.counts[k] = log.counts[k - 1]
        # a rejected frame left a gap too: lost counts the frames that never came at all
        log.lost[k] = max(self._lost - self.link.rejected, 0)
        log.late[k], log.rejected[k] = self._late, self.link.rejected
        log.read[k] = time.perf_counter_ns()
        self._t0_ns += self.clock.end_of_cycle(k, log.read[k])
        self._read_cycle = k
        log.cycles = k + 1
        return self.sensors.state.copy()

    def _listen(self, deadline: int) -> tuple[list, int]:
        """Sleep to the listening window before ``deadline``, then poll until it (and once
        at it), each frame's arrival stamped for the clock tracker; the frames and the
        wake-up time."""
        clock, link, frames = time.perf_counter_ns, self.link, []
        wait_until(deadline - max(SPIN_NS, round(LISTEN_SHARE * self._period_ns)))
        waiting = True  # the first poll reads what came while the host slept
        while True:
            now = clock()
            got = link.poll()
            if got:
                arrived = clock()
                for frame in got:
                    self.clock.arrived(arrived, frame.rig_time_us, waiting)
                frames += got
            waiting = False
            if now >= deadline:
                return frames, now

    def _take_frames(self, k: int, frames: list):
        """The newest of ``frames``, counting lost (gaps in the sequence) and late ones
        (arrived after their own cycle's deadline)."""
        newest = None
        for frame in frames:
            if frame.seq > self._highest_seq:
                self._lost += frame.seq - self._highest_seq - 1
                self._highest_seq = frame.seq
            elif frame.seq < self._highest_seq:
                self._lost -= 1  # counted lost, came after all
            if frame.seq < self._first_seq + k:
                self._late += 1
            if newest is None or frame.seq > newest.seq:
                newest = frame
        return newest

    def step(self, u: float, d: float, dt: float) -> None:
        k, log = self._cycle, self.log
        log.ready[k] = ready = time.perf_counter_ns()
        if self._silent:
            raise RigSilent(self._silent)
        if self._held_back:  # the loop ends a refused start before any input: a guard
            raise RigRefused(f"{self.link.describe()}: its start was refused before START")
        # before the first sensor frame the state is no measurement: the command stays 0
        sent = u if self._used_seq >= 0 else 0.0
        if ready > log.deadline[k] + self._period_ns:
            log.missed[k] = True
            policy = self.settings.miss_policy
            if policy == "stop":
                raise DeadlineMissed(f"deadline missed at cycle {k}: the command was ready "
                                     f"{(ready - log.deadline[k]) * 1e-6:.3g} ms after its "
                                     f"deadline (miss policy stop)")
            sent = self._last_sent if policy == "hold" else 0.0
        self.link.send(Command(k, sent, int(log.sensor_seq[k])))
        log.sent[k] = time.perf_counter_ns()
        log.u_sent[k] = self._last_sent = sent
        self._cycle = k + 1


class RigSession:
    """An open link: hello checked, period chosen; :meth:`close` sends the zero command
    and the stop frame, once, and releases the link."""

    def __init__(self, link: RigLink, hello: Hello, period_s: float) -> None:
        self.link, self.hello, self.period_s = link, hello, period_s
        self.plant: RigPlant | None = None
        self.stop_reason = protocol.STOP_DONE
        self.closed = False

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self.link.stop(self.stop_reason)
        finally:
            self.link.close()


def open_session(link: RigLink, machine: Plant, requested_period_s: float) -> RigSession:
    """The link checked before any motion: the line's capacity (before any frame), the
    hello's machine, the period the rig accepts."""
    where = link.describe()
    check_line(link, requested_period_s)
    try:
        hello = link.hello()
        check_hello(hello, machine, where)
        period = choose_period(requested_period_s, hello, where)
    except BaseException:
        link.close()
        raise
    return RigSession(link, hello, period)


@contextmanager
def model_not_stepped():
    """Quiet the model's warning on how its timestep splits a control sample: on a rig (and
    in its replay) nothing steps the model, so it would be about a run that does not happen."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*physics steps per control sample")
        yield


def rig_scenario(scenario, period_s: float):
    """The scenario at the rig's period: the loop's sample time and the control period."""
    from tspend.scenario import override

    return override(scenario, **{"run.dt": period_s, "run.control_period": period_s})


def session_settings(session: RigSession, duration_s: float, policy: str,
                     estimator: VelocityEstimator) -> RigSettings:
    return RigSettings(session.period_s, int(round(duration_s / session.period_s)), policy,
                       estimator)


__all__ = ["MISS_POLICIES", "RigPlant", "RigSession", "RigSettings", "open_session",
           "rig_scenario", "machine_id"]
