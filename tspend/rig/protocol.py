"""The rig wire protocol, version 1 (docs/rig.md is its specification; this is its code).

Every frame is ``magic (2) | version (1) | type (1) | seq (4) | payload | CRC-32 (4)``, all
little-endian; the CRC is IEEE 802.3's (``zlib.crc32``) over every byte before it.  Each
type has one fixed payload size, so a byte stream (a serial line) is cut into frames by
the header alone and re-synchronised after a corrupt byte by sliding one byte on.

Positions travel as signed 32-bit counts; the hello states each joint's counts per unit
(per metre, per radian), so a rig with an encoder sends its counts as they are and a rig
that measures in SI units sends micro-units (1e6 counts per unit).
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

VERSION = 1
MAGIC = b"TS"
#: the most joints a sensor frame carries (a triple pendulum on a cart has four)
MAX_JOINTS = 4

HELLO_REQUEST, HELLO, START, SENSOR, COMMAND, STOP = b"H", b"h", b"G", b"S", b"C", b"X"
#: the host's request, before START, for one sensor frame (the rig's state, its motor off)
QUERY = b"Q"

_HEADER = struct.Struct("<2sBcI")          # magic, version, type, seq
_CRC = struct.Struct("<I")
#: payload layouts, one per type (docs/rig.md, "Frames")
_PAYLOADS = {
    HELLO_REQUEST: struct.Struct("<I"),                        # host's protocol version
    HELLO: struct.Struct("<32sBBHIIId4d"),                     # machine, n, flags, pad, min/max period us, watchdog us, u limit, counts per unit
    START: struct.Struct("<II"),                               # period us, reserved
    SENSOR: struct.Struct("<QIHBB4i"),                         # rig time us, command seq applied, flags, n, pad, counts
    COMMAND: struct.Struct("<dII"),                            # u, sensor seq answered, flags
    STOP: struct.Struct("<I"),                                 # reason
    QUERY: struct.Struct("<I"),                                # reserved
}
SIZES = {kind: _HEADER.size + p.size + _CRC.size for kind, p in _PAYLOADS.items()}
LONGEST = max(SIZES.values())

#: HELLO flags: the rig answers a QUERY before START with one sensor frame (the host
#: checks the start it would run from before any motion: a safety filter's admission)
ANSWERS_QUERY = 1
#: the command seq a sensor frame states when no command was applied (an answer to QUERY)
NO_COMMAND = 0xFFFFFFFF
#: SENSOR flags
WATCHDOG_TRIPPED, AMPLIFIER_CLIPPED = 1, 2
#: STOP reasons
STOP_DONE, STOP_TASK, STOP_SIGNAL, STOP_ERROR = 0, 1, 2, 3
#: STOP from the rig: it refused the period START asked for
STOP_REFUSED_PERIOD = 4
#: what each STOP reason says
STOP_NAMES = {STOP_DONE: "done", STOP_TASK: "task", STOP_SIGNAL: "signal",
              STOP_ERROR: "error", STOP_REFUSED_PERIOD: "period refused"}


@dataclass(frozen=True)
class Hello:
    """What a rig states about itself before any motion."""

    machine: str                     # "<domain>:<joint>,<joint>": e.g. "cartpole:slider,hinge"
    counts_per_unit: tuple[float, ...]  # one per joint, in the machine's joint order
    min_period_s: float
    max_period_s: float
    watchdog_s: float
    u_limit: float                   # the amplifier's limit on |u| (inf: none stated)
    flags: int = 0                   # ANSWERS_QUERY: it reads its state before START

    @property
    def answers_query(self) -> bool:
        return bool(self.flags & ANSWERS_QUERY)


@dataclass(frozen=True)
class Sensor:
    seq: int
    rig_time_us: int
    command_seq: int                 # the last command the rig applied
    flags: int
    counts: tuple[int, ...]


@dataclass(frozen=True)
class Command:
    seq: int
    u: float
    sensor_seq: int
    flags: int = 0


class FrameError(ValueError):
    """A frame that is not one: wrong magic, version, type, size or CRC."""


def _frame(kind: bytes, seq: int, *fields) -> bytes:
    body = _HEADER.pack(MAGIC, VERSION, kind, seq & 0xFFFFFFFF) + _PAYLOADS[kind].pack(*fields)
    return body + _CRC.pack(zlib.crc32(body))


def hello_request(seq: int = 0) -> bytes:
    return _frame(HELLO_REQUEST, seq, VERSION)


def hello(h: Hello, seq: int = 0) -> bytes:
    counts = tuple(h.counts_per_unit) + (0.0,) * (MAX_JOINTS - len(h.counts_per_unit))
    return _frame(HELLO, seq, h.machine.encode("ascii")[:32], len(h.counts_per_unit), h.flags, 0,
                  round(h.min_period_s * 1e6), round(h.max_period_s * 1e6),
                  round(h.watchdog_s * 1e6), h.u_limit, *counts)


def query(seq: int = 0) -> bytes:
    return _frame(QUERY, seq, 0)


def start(period_s: float, seq: int = 0) -> bytes:
    return _frame(START, seq, round(period_s * 1e6), 0)


def sensor(s: Sensor) -> bytes:
    counts = tuple(s.counts) + (0,) * (MAX_JOINTS - len(s.counts))
    return _frame(SENSOR, s.seq, s.rig_time_us, s.command_seq & 0xFFFFFFFF, s.flags,
                  len(s.counts), 0, *counts)


def command(c: Command) -> bytes:
    return _frame(COMMAND, c.seq, c.u, c.sensor_seq & 0xFFFFFFFF, c.flags)


def stop(reason: int, seq: int = 0) -> bytes:
    return _frame(STOP, seq, reason)


def decode(frame: bytes) -> tuple[bytes, int, tuple]:
    """``(type, seq, payload fields)`` of one whole frame; FrameError when it is not one."""
    if len(frame) < _HEADER.size + _CRC.size:
        raise FrameError(f"{len(frame)} bytes: shorter than any frame")
    magic, version, kind, seq = _HEADER.unpack_from(frame)
    if magic != MAGIC:
        raise FrameError("wrong magic")
    if version != VERSION:
        raise FrameError(f"protocol version {version}, this host speaks {VERSION}")
    if kind not in _PAYLOADS:
        raise FrameError(f"unknown frame type {kind!r}")
    if len(frame) != SIZES[kind]:
        raise FrameError(f"a {kind.decode()} frame of {len(frame)} bytes, not {SIZES[kind]}")
    (crc,) = _CRC.unpack_from(frame, len(frame) - _CRC.size)
    if zlib.crc32(frame[:-_CRC.size]) != crc:
        raise FrameError("CRC mismatch")
    return kind, seq, _PAYLOADS[kind].unpack_from(frame, _HEADER.size)


def as_hello(fields: tuple) -> Hello:
    machine, n, flags, _pad, lo_us, hi_us, dog_us, u_limit, *counts = fields
    if not 0 < n <= MAX_JOINTS:
        raise FrameError(f"a hello stating {n} joints (1 to {MAX_JOINTS})")
    return Hello(machine.rstrip(b"\0").decode("ascii", "replace"), tuple(counts[:n]),
                 lo_us / 1e6, hi_us / 1e6, dog_us / 1e6, u_limit,  # / 1e6: 100000 us is 0.1 s
                 flags)


def as_sensor(seq: int, fields: tuple) -> Sensor:
    rig_time_us, command_seq, flags, n, _pad, *counts = fields
    if not 0 < n <= MAX_JOINTS:
        raise FrameError(f"a sensor frame with {n} joints")
    return Sensor(seq, rig_time_us, command_seq, flags, tuple(counts[:n]))


def as_command(seq: int, fields: tuple) -> Command:
    u, sensor_seq, flags = fields
    return Command(seq, u, sensor_seq, flags)


class StreamParser:
    """Frames out of a byte stream: ``feed(bytes)`` returns the whole frames found
    (``(type, seq, fields)``) and counts the bytes skipped to re-synchronise and the
    frames rejected (a good header whose CRC fails).  Its buffer is bounded."""

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.rejected = 0
        self.skipped_bytes = 0

    def feed(self, data: bytes) -> list[tuple[bytes, int, tuple]]:
        self._buffer += data
        found = []
        buf = self._buffer
        while len(buf) >= _HEADER.size:
            at = buf.find(MAGIC)
            if at < 0:
                self.skipped_bytes += len(buf) - 1
                del buf[:-1]  # the last byte may be the magic's first
                break
            if at:
                self.skipped_bytes += at
                del buf[:at]
                continue
            kind = bytes(buf[3:4])
            if buf[2] != VERSION or kind not in SIZES:
                self.skipped_bytes += 1
                del buf[:1]
                continue
            size = SIZES[kind]
            if len(buf) < size:
                break
            try:
                found.append(decode(bytes(buf[:size])))
            except FrameError:
                self.rejected += 1
                self.skipped_bytes += 1
                del buf[:1]  # slide on: the frame may have started inside this one
                continue
            del buf[:size]
        return found
