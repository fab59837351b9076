"""The host's end of a rig link: :class:`RigLink`, the class a lab's own hardware interface
subclasses (``--rig path/to/file.py:MyRig``), and its two implementations over the wire
protocol (:mod:`tspend.rig.protocol`): UDP and a serial line.

A link says why it refuses, in one line (:class:`RigRefused`, exit 2), before any motion:
the rig unreachable or silent, the wrong machine in its hello, a period it does not accept
or that the serial line cannot carry at its baud rate.
"""

from __future__ import annotations

import socket
import time
import urllib.parse
from abc import ABC, abstractmethod

from tspend.runtime.errors import ScenarioError
from tspend.rig import protocol
from tspend.rig.protocol import Command, FrameError, Hello, Sensor

#: how long the host waits for the rig's hello (s)
ANSWER_TIMEOUT_S = 1.0
#: how long the host waits for the first sensor frames after START (s): a rig may set
#: itself up between START and sampling (a real-time class, locked memory, homing its
#: encoders), and a loaded host stretches that; nothing moves before those frames
FIRST_FRAME_TIMEOUT_S = 5.0
#: bits a serial line spends on one byte (start, 8 data, stop)
BITS_PER_BYTE = 10
BAUD_RANGE = (300, 12_000_000)


class RigRefused(ScenarioError):
    """The link or the rig cannot run this experiment (exit 2, before any motion)."""


class RigLink(ABC):
    """A rig as the real-time runner sees it.  Subclass it for a lab's own hardware
    (a DAQ card, a QUARC server, ros2_control): :meth:`hello` states the machine,
    :meth:`start` begins sampling at the period, :meth:`poll` returns the sensor frames
    that arrived since the last call without waiting, :meth:`send` applies a command,
    :meth:`stop` brings the motor to zero, :meth:`close` releases the hardware;
    :meth:`query`, optional, reads the sensors before :meth:`start` (the runner then
    checks the start it would run from before any motion).  The constructor takes no
    arguments and only stores; the runner calls the rest in order and calls :meth:`stop`
    on every exit path."""

    #: frames that failed their check (CRC, size, type) and were dropped
    rejected: int = 0

    @abstractmethod
    def hello(self) -> Hello: ...

    @abstractmethod
    def start(self, period_s: float) -> None: ...

    @abstractmethod
    def poll(self) -> list[Sensor]: ...

    @abstractmethod
    def send(self, command: Command) -> None: ...

    @abstractmethod
    def stop(self, reason: int) -> None: ...

    def close(self) -> None:
        pass

    def query(self) -> Sensor | None:
        """One sensor frame read before :meth:`start`, the motor off (its ``rig_time_us``
        on any clock of the rig's, the same for every query); None: this link reads no
        state before the start (the runner says so and checks its start at the first
        cycle instead)."""
        return None

    def shortest_period_s(self) -> float:
        """The shortest period the link itself can carry (0: no limit of its own)."""
        return 0.0

    def describe(self) -> str:
        return type(self).__name__


class _FramedLink(RigLink):
    """What the UDP and serial links share: the hello exchange and the frames' checks."""

    def __init__(self) -> None:
        self.rejected = 0
        self._seq = 0
        self._answers_query = False

    @abstractmethod
    def _write(self, frame: bytes) -> None: ...

    @abstractmethod
    def _frames(self) -> list[tuple[bytes, int, tuple]]:
        """Whole, checked frames that arrived (bad ones counted in ``rejected``)."""

    def _next_seq(self) -> int:
        self._seq += 1
        return self._seq

    def hello(self) -> Hello:
        tries = 3
        for _ in range(tries):
            self._write(protocol.hello_request(self._next_seq()))
            until = time.monotonic() + ANSWER_TIMEOUT_S / tries
            while time.monotonic() < until:
                for kind, _seq, fields in self._frames():
                    if kind == protocol.HELLO:
                        try:
                            hello = protocol.as_hello(fields)
                        except FrameError as exc:
                            raise RigRefused(f"{self.describe()}: a malformed hello ({exc})")
                        self._answers_query = hello.answers_query
                        return hello
                time.sleep(0.001)
        if getattr(self, "refused", False):
            raise RigRefused(f"{self.describe()}: unreachable (nothing listens on that port)")
        raise RigRefused(f"{self.describe()}: no hello within {ANSWER_TIMEOUT_S:g} s "
                         f"(is the rig running and listening there?)")

    def start(self, period_s: float) -> None:
        self._write(protocol.start(period_s, self._next_seq()))

    def query(self) -> Sensor | None:
        """The rig's answer to a QUERY (the sensor frame echoing its seq), where its hello
        says it answers one; RigRefused when it says so and stays silent."""
        if not self._answers_query:
            return None
        seq = self._next_seq()
        self._write(protocol.query(seq))
        until = time.monotonic() + ANSWER_TIMEOUT_S
        while time.monotonic() < until:
            for frame in self.poll():
                if frame.seq == seq and frame.command_seq == protocol.NO_COMMAND:
                    return frame
            time.sleep(0.0002)
        raise RigRefused(f"{self.describe()}: its hello says it answers a query before the "
                         f"start, and no answer came within {ANSWER_TIMEOUT_S:g} s")

    def poll(self) -> list[Sensor]:
        found = []
        for kind, seq, fields in self._frames():
            if kind == protocol.SENSOR:
                try:
                    found.append(protocol.as_sensor(seq, fields))
                except FrameError:
                    self.rejected += 1
            elif kind == protocol.STOP:
                raise RigRefused(f"{self.describe()}: the rig stopped the session "
                                 f"(reason {fields[0]})")
        return found

    def send(self, command: Command) -> None:
        self._write(protocol.command(command))

    def stop(self, reason: int) -> None:
        self._write(protocol.command(Command(self._next_seq(), 0.0, 0, 1)))
        self._write(protocol.stop(reason, self._next_seq()))


class UdpLink(_FramedLink):
    """``udp://HOST:PORT``: one frame per datagram."""

    def __init__(self, host: str, port: int) -> None:
        super().__init__()
        self.host, self.port = host, port
        self._sock: socket.socket | None = None
        #: an ICMP "port unreachable" came back for a datagram
        self.refused = False

    def describe(self) -> str:
        return f"udp://{self.host}:{self.port}"

    def _socket(self) -> socket.socket:
        if self._sock is None:
            try:
                self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                self._sock.connect((self.host, self.port))
            except OSError as exc:
                raise RigRefused(f"{self.describe()}: unreachable ({exc.strerror or exc})")
            self._sock.setblocking(False)
        return self._sock

    def _write(self, frame: bytes) -> None:
        try:
            self._socket().send(frame)
        except ConnectionRefusedError:
            # an ICMP answer to an earlier datagram (sent before the rig was up, or the
            # rig gone): the hello says so after its tries, the runner on silence
            self.refused = True
        except BlockingIOError:
            pass  # the socket's buffer is full: this frame is lost, as on a wire

    def _frames(self) -> list[tuple[bytes, int, tuple]]:
        sock, found = self._socket(), []
        while True:
            try:
                data = sock.recv(protocol.LONGEST + 1)
            except BlockingIOError:
                return found
            except ConnectionRefusedError:
                self.refused = True
                continue
            try:
                found.append(protocol.decode(data))
            except FrameError:
                self.rejected += 1

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


class SerialLink(_FramedLink):
    """``serial:///dev/ttyUSB0?baud=230400``: frames on a byte stream (pyserial)."""

    def __init__(self, port: str, baud: int) -> None:
        super().__init__()
        self.port, self.baud = port, baud
        self._serial = None
        self._parser = protocol.StreamParser()

    def describe(self) -> str:
        return f"serial://{self.port}?baud={self.baud}"

    def shortest_period_s(self) -> float:
        """A sensor frame one way and a command the other, back to back, in one period."""
        line_bytes = protocol.SIZES[protocol.SENSOR] + protocol.SIZES[protocol.COMMAND]
        return line_bytes * BITS_PER_BYTE / self.baud

    def _port(self):
        if self._serial is None:
            try:
                import serial  # pyserial, the [rig] extra
            except ImportError:
                raise RigRefused(f"{self.describe()}: needs pyserial (pip install "
                                 f"'tspend[rig]')") from None
            try:
                self._serial = serial.Serial(self.port, self.baud, timeout=0, write_timeout=0.1)
            except (OSError, ValueError, serial.SerialException) as exc:
                raise RigRefused(f"{self.describe()}: cannot open it ({exc})") from None
        return self._serial

    def _write(self, frame: bytes) -> None:
        self._port().write(frame)

    def _frames(self) -> list[tuple[bytes, int, tuple]]:
        port = self._port()
        waiting = port.in_waiting
        found = self._parser.feed(port.read(waiting)) if waiting else []
        self.rejected = self._parser.rejected
        return found

    def close(self) -> None:
        if self._serial is not None:
            self._serial.close()
            self._serial = None


def parse_rig(spec: str) -> RigLink:
    """The link ``--rig`` names: ``udp://HOST:PORT``, ``serial://DEVICE?baud=N`` or a
    plug-in class ``path/to/file.py:MyRig`` (loaded as controller plug-ins are)."""
    if spec.startswith("udp://"):
        parts = urllib.parse.urlsplit(spec)
        try:
            port = parts.port
        except ValueError:
            port = None
        if not parts.hostname or port is None or not 0 < port < 65536:
            raise RigRefused(f"--rig {spec}: expected udp://HOST:PORT with a port 1-65535")
        return UdpLink(parts.hostname, port)
    if spec.startswith("serial://"):
        parts = urllib.parse.urlsplit(spec)
        query = urllib.parse.parse_qs(parts.query)
        try:
            baud = int(query.get("baud", ["115200"])[0])
        except ValueError:
            baud = 0
        if not parts.path or not BAUD_RANGE[0] <= baud <= BAUD_RANGE[1]:
            raise RigRefused(f"--rig {spec}: expected serial:///dev/DEVICE?baud=N with N "
                             f"{BAUD_RANGE[0]}-{BAUD_RANGE[1]}")
        return SerialLink(parts.path, baud)
    from tspend.runtime.plugins import is_spec, load_object

    if not is_spec(spec):
        raise RigRefused(f"--rig {spec}: expected udp://HOST:PORT, serial:///dev/DEVICE?baud=N "
                         f"or path/to/file.py:Class")
    cls = load_object(spec, option="--rig")
    if not (isinstance(cls, type) and issubclass(cls, RigLink)):
        raise RigRefused(f"--rig {spec}: not a subclass of tspend.rig.links.RigLink")
    try:
        return cls()
    except Exception as exc:  # the lab's code: one line
        raise RigRefused(f"--rig {spec}: its constructor failed: {type(exc).__name__}: {exc}")
