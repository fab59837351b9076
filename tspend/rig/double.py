"""The simulated rig (``tspend rig serve``): the scenario's machine paced to the wall clock,
speaking the wire protocol, with what a real rig has: encoder quantisation, sensor and
command latency with jitter, dropped and corrupted frames, an amplifier limit and a
watchdog that brings the motor command to zero when no valid command came within its
time.  It logs its own true state (:class:`TruthLog`), so a test compares what the
controller believed with what happened.
"""

from __future__ import annotations

import math
import socket
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from tspend.rig import protocol
from tspend.rig.protocol import FrameError, Hello, Sensor
from tspend.rig.realtime import wait_until

#: a session ends when the watchdog has tripped and nothing came from the host this long (s)
HOST_LOST_S = 1.0
_LOG_CHUNK = 10_000
#: a tick's physics step starts this long before the next tick (ns): time for the step
STEP_MARGIN_NS = 150_000


@dataclass
class _Tick:
    """A session's running state."""

    t0: int
    every: int
    last_valid: int = 0
    last_heard: int = 0
    u: float = 0.0
    command_seq: int = -1
    seq: int = 0
    tripped: bool = False
    state: np.ndarray | None = None
    commands: deque = field(default_factory=deque)   # (apply at ns, seq, u, flags)
    outgoing: deque = field(default_factory=deque)   # (send at ns, frame)


@dataclass(frozen=True)
class Faults:
    """What the double does to the frames: shares of sensor frames dropped and of frames
    corrupted (one bit flipped; sensor frames sent and commands received), latencies (s)
    and a uniform jitter added to each; and its clock's error against the host's, in parts
    per million (positive: the rig's clock runs fast, so its ticks come sooner and its
    timestamps gain on the host's clock, as a crystal off its nominal frequency does)."""

    drop: float = 0.0
    corrupt: float = 0.0
    sensor_latency_s: float = 0.0
    command_latency_s: float = 0.0
    jitter_s: float = 0.0
    clock_ppm: float = 0.0


class TruthLog:
    """The double's rows, one per physics step, in chunks (memory grows with the session
    only), and its events (watchdog trips, commands rejected, frames corrupted)."""

    COLUMNS = ("wall_s", "t", "u_command", "u_applied", "watchdog", "command_seq")

    def __init__(self, state_names: tuple[str, ...]) -> None:
        self.state_names = state_names
        self._width = len(self.COLUMNS) + len(state_names)
        self._chunks: list[np.ndarray] = []
        self._rows = 0
        self.events: list[tuple[float, str]] = []
        self.sensors: list[tuple[int, int, tuple[int, ...], bool, bool]] = []  # seq, rig us, counts, dropped, corrupted
        self.commands: list[tuple[int, float, bool]] = []  # seq, u, applied

    def row(self, values: tuple, state: np.ndarray) -> None:
        at = self._rows % _LOG_CHUNK
        if at == 0:
            self._chunks.append(np.zeros((_LOG_CHUNK, self._width)))
        chunk = self._chunks[-1]
        chunk[at, :len(values)] = values
        chunk[at, len(values):] = state
        self._rows += 1

    def arrays(self) -> dict[str, np.ndarray]:
        rows = np.concatenate(self._chunks)[:self._rows] if self._chunks else \
            np.zeros((0, self._width))
        out = {name: rows[:, i] for i, name in enumerate(self.COLUMNS)}
        out["state"] = rows[:, len(self.COLUMNS):]
        out["state_names"] = np.array(self.state_names)
        out["event_wall_s"] = np.array([e[0] for e in self.events])
        out["event"] = np.array([e[1] for e in self.events], dtype=str)
        out["sensor_seq"] = np.array([s[0] for s in self.sensors], dtype=np.int64)
        out["sensor_rig_time_us"] = np.array([s[1] for s in self.sensors], dtype=np.int64)
        width = len(self.sensors[0][2]) if self.sensors else 0
        out["sensor_counts"] = np.array([s[2] for s in self.sensors], dtype=np.int64).reshape(-1, width)
        out["sensor_dropped"] = np.array([s[3] for s in self.sensors], dtype=bool)
        out["sensor_corrupted"] = np.array([s[4] for s in self.sensors], dtype=bool)
        out["command_seq_received"] = np.array([c[0] for c in self.commands], dtype=np.int64)
        out["command_u_received"] = np.array([c[1] for c in self.commands])
        out["command_applied"] = np.array([c[2] for c in self.commands], dtype=bool)
        return out

    def save(self, path) -> None:
        np.savez(path, **self.arrays())


class UdpServer:
    """The double's end of ``udp://HOST:PORT``: answers the last host that wrote."""

    def __init__(self, host: str, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, port))
        self.sock.setblocking(False)
        self.peer = None

    def receive(self) -> list[bytes]:
        found = []
        while True:
            try:
                data, self.peer = self.sock.recvfrom(protocol.LONGEST + 1)
            except (BlockingIOError, ConnectionRefusedError):
                return found
            found.append(data)

    def send(self, frame: bytes) -> None:
        if self.peer is not None:
            try:
                self.sock.sendto(frame, self.peer)
            except OSError:
                pass  # the host went away: the watchdog handles it

    def close(self) -> None:
        self.sock.close()


class SerialServer:
    """The double's end of a serial line (pyserial): bytes, cut into frames by the reader."""

    def __init__(self, port: str, baud: int) -> None:
        import serial

        self.port = serial.Serial(port, baud, timeout=0)

    def receive(self) -> list[bytes]:
        waiting = self.port.in_waiting
        return [self.port.read(waiting)] if waiting else []

    def send(self, frame: bytes) -> None:
        self.port.write(frame)

    def close(self) -> None:
        self.port.close()


class SimulatedRig:
    """One machine (a built plant, reset to the scenario's x0 at each session) behind a
    transport; :meth:`serve` runs sessions until told how many."""

    def __init__(self, plant, scenario, hello: Hello, faults: Faults, transport,
                 rng: np.random.Generator, joint_index: np.ndarray) -> None:
        self.plant, self.scenario, self.hello, self.faults = plant, scenario, hello, faults
        self.transport, self.rng, self.joint_index = transport, rng, joint_index
        self.dt = scenario.run.dt
        self.stream = isinstance(transport, SerialServer)
        self.parser = protocol.StreamParser()

    def _frames(self, now_ns: int, log: TruthLog) -> list[tuple[bytes, int, tuple]]:
        """Checked frames that arrived; a frame the faults corrupt is rejected here."""
        found = []
        for raw in self.transport.receive():
            if self.faults.corrupt and self.rng.random() < self.faults.corrupt:
                raw = _flip_bit(raw, self.rng)
            if self.stream:
                before = self.parser.rejected
                found += self.parser.feed(raw)
                if self.parser.rejected > before:
                    log.events.append((now_ns * 1e-9, "rejected_command"))
                continue
            try:
                found.append(protocol.decode(raw))
            except FrameError:
                log.events.append((now_ns * 1e-9, "rejected_command"))
        return found

    def wait_for_start(self, until: float, log: TruthLog) -> float | str | None:
        """Answer hellos and queries (the machine at rest where the session will start)
        until a START with an accepted period: its period; a STOP before it (the host
        refused its start): why; None: timed out."""
        self.plant.reset(np.asarray(self.scenario.plant.x0, dtype=float))
        while time.monotonic() < until:
            for kind, seq, fields in self._frames(time.perf_counter_ns(), log):
                if kind == protocol.HELLO_REQUEST:
                    self.transport.send(protocol.hello(self.hello))
                elif kind == protocol.QUERY and self.hello.answers_query:
                    self.transport.send(protocol.sensor(Sensor(
                        seq, time.perf_counter_ns() // 1000, protocol.NO_COMMAND, 0,
                        self.counts(self.plant.full_state()))))
                elif kind == protocol.STOP:
                    why = protocol.STOP_NAMES.get(fields[0], "unknown")
                    return f"the host stopped before START (reason {fields[0]}: {why})"
                elif kind == protocol.START:
                    period = fields[0] * 1e-6
                    steps = round(period / self.dt)
                    if (self.hello.min_period_s - 1e-9 <= period <= self.hello.max_period_s + 1e-9
                            and steps >= 1 and abs(steps * self.dt - period) < 1e-7):
                        return period
                    self.transport.send(protocol.stop(protocol.STOP_REFUSED_PERIOD))
            time.sleep(0.0005)
        return None

    def session(self, period_s: float, max_s: float, log: TruthLog) -> str:
        """Run until the host's STOP, the host lost (the watchdog tripped and silence), or
        ``max_s``; the reason.

        Each physics step of ``dt`` is a tick: at its start the sensors are sampled (the
        state at that time, sent as a frame every period); just before its end the
        commands that arrived are applied and the step [t, t + dt) is integrated with
        the command in force.  So a command that reaches the rig within the tick it was
        sampled in acts from that sample on: the zero-order hold the controller's model
        and ``tspend identify`` assume, plus the latencies the faults add."""
        plant, dt = self.plant, self.dt
        plant.reset(np.asarray(self.scenario.plant.x0, dtype=float))
        s = _Tick(t0=time.perf_counter_ns(), every=round(period_s / dt))
        s.last_valid = s.last_heard = s.t0
        rate = 1.0 + self.faults.clock_ppm * 1e-6  # rig seconds per host second
        tick_ns = dt * 1e9 / rate
        for i in range(int(max_s / dt)):
            self._sample(i, wait_until(s.t0 + round(i * tick_ns)), s, log)
            now = wait_until(s.t0 + round((i + 1) * tick_ns) - STEP_MARGIN_NS)
            ended = self._receive(now, s, log)
            if ended:
                return ended
            applied = 0.0 if s.tripped else min(max(s.u, -self.hello.u_limit), self.hello.u_limit)
            d = float(self.scenario.disturbance(np.array([i * dt]))[0])
            log.row(((now - s.t0) * 1e-9, i * dt, s.u, applied, float(s.tripped), s.command_seq),
                    s.state)
            if s.command_seq >= 0:
                # the machine rests at x0 until the controller's first command (a pole held
                # by hand or on its stop): the run starts where the scenario says
                plant.step(applied, d, dt)
        return "session time limit"

    def counts(self, state: np.ndarray) -> tuple[int, ...]:
        """The encoders' counts of the full ``state``."""
        return tuple(int(round(v)) for v in state[self.joint_index] * self.hello.counts_per_unit)

    def _sample(self, i: int, now: int, s: "_Tick", log: TruthLog) -> None:
        """The tick's start: the state read, a sensor frame every period (faults drawn)."""
        f = self.faults
        s.state = self.plant.full_state()
        if i % s.every == 0:
            counts = self.counts(s.state)
            flags = protocol.WATCHDOG_TRIPPED if s.tripped else 0
            # the sampling instant on the rig's own clock, as a rig's timer stamps it: the
            # tick's time (a fast or slow clock shows in when the ticks come on the host's)
            rig_us = round(i * self.dt * 1e6)
            frame = protocol.sensor(Sensor(s.seq, rig_us, s.command_seq, flags, counts))
            dropped = f.drop > 0 and self.rng.random() < f.drop
            corrupted = f.corrupt > 0 and self.rng.random() < f.corrupt
            log.sensors.append((s.seq, rig_us, counts, dropped, corrupted))
            if not dropped:
                s.outgoing.append((now + self._latency(f.sensor_latency_s),
                                   _flip_bit(frame, self.rng) if corrupted else frame))
            s.seq += 1
        self._send_due(now, s)

    def _send_due(self, now: int, s: "_Tick") -> None:
        while s.outgoing and s.outgoing[0][0] <= now:
            self.transport.send(s.outgoing.popleft()[1])

    def _receive(self, now: int, s: "_Tick", log: TruthLog) -> str:
        """The tick's end: frames in, commands due applied, the watchdog; "" or why the
        session ends."""
        self._send_due(now, s)
        for kind, fseq, fields in self._frames(now, log):
            s.last_heard = now
            if kind == protocol.STOP:
                log.events.append((now * 1e-9, "stop_frame"))
                return "stop frame"
            if kind == protocol.COMMAND:
                s.commands.append((now + self._latency(self.faults.command_latency_s), fseq,
                                   fields[0], fields[2]))
                s.last_valid = now
        while s.commands and s.commands[0][0] <= now:
            _, cseq, u, flags = s.commands.popleft()
            fresh = (cseq > s.command_seq or flags & 1) and math.isfinite(u)
            log.commands.append((cseq, u, bool(fresh)))
            if fresh:
                s.u, s.command_seq = u, cseq
        armed = s.command_seq >= 0  # the watchdog arms on the first command
        if armed and now - s.last_valid > round(self.hello.watchdog_s * 1e9):
            if not s.tripped:
                log.events.append((now * 1e-9, "watchdog"))
            s.tripped = True
        if (s.tripped or not armed) and now - s.last_heard > HOST_LOST_S * 1e9:
            return "host lost"
        if s.tripped and now - s.last_valid <= round(self.hello.watchdog_s * 1e9):
            s.tripped = False
            log.events.append((now * 1e-9, "watchdog_cleared"))
        return ""

    def _latency(self, base_s: float) -> int:
        jitter = self.faults.jitter_s * self.rng.random() if self.faults.jitter_s else 0.0
        return round((base_s + jitter) * 1e9)


def _flip_bit(frame: bytes, rng: np.random.Generator) -> bytes:
    """One bit flipped, anywhere in the frame (a CRC-32 detects every such error)."""
    data = bytearray(frame)
    bit = int(rng.integers(len(data) * 8))
    data[bit // 8] ^= 1 << (bit % 8)
    return bytes(data)


def u_limit_of(plant, scenario) -> float:
    """The amplifier's limit: the machine's input range (the narrower side)."""
    from tspend.loop.simulation import input_range

    lo, hi = input_range(plant, scenario)
    limit = min(-lo, hi)
    return limit if math.isfinite(limit) else 1e300
