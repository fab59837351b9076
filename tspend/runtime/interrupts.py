"""Signals from the first instant: SIGINT, SIGTERM and SIGHUP, each with its exit status.

Before a run starts nothing has been written, so the first signal ends the command at
once: the handler raises :class:`Interrupted`, which unwinds through the cleanup code.
Once outputs exist (:meth:`SignalGuard.deferred`), a signal only sets the
:class:`StopRequest` that the closed loop honours between two samples, so the recording
and the metrics are completed up to the stop.  After the first signal, further ones are
ignored: the cleanup they would interrupt is what keeps the user's files whole.

Only the standard library is imported here, so the CLI installs the handlers before
numpy, MuJoCo, numba or Rerun are loaded.
"""

from __future__ import annotations

import signal
import sys
from contextlib import contextmanager
from typing import Iterator

#: signal -> (name, exit status); 128 + the signal number, as shells report it
HANDLED: dict[int, tuple[str, int]] = {
    signal.SIGINT: ("SIGINT", 130),
    signal.SIGTERM: ("SIGTERM", 143),
}
if hasattr(signal, "SIGHUP"):  # not on Windows
    HANDLED[signal.SIGHUP] = ("SIGHUP", 129)


class StopRequest:
    """A request to stop, set by a signal handler and honoured between two samples.

    Raising from the handler itself could land in the middle of handing a block to the
    sinks (some would have it, some not); the loop checks this flag before each sample
    instead, where everything before is complete.
    """

    def __init__(self) -> None:
        self.signal_name: str | None = None
        self.exit_status = 0
        #: set by the loop while the controller's own code runs: a signal then raises
        #: :class:`Interrupted` into it, since a plug-in that sleeps or loops would never
        #: reach the check between two samples (the loop turns it into its stop)
        self.in_controller = False

    def request(self, signal_name: str, exit_status: int) -> None:
        self.signal_name, self.exit_status = signal_name, exit_status


class Interrupted(BaseException):
    """A signal arrived before any output was opened: the command ends at once.

    A ``BaseException``, like ``KeyboardInterrupt``, so that ``except Exception`` in
    library code on the way cannot swallow it.
    """

    def __init__(self, signal_name: str, exit_status: int) -> None:
        super().__init__(f"interrupted by {signal_name}")
        self.signal_name, self.exit_status = signal_name, exit_status


class SignalGuard:
    """Handlers for :data:`HANDLED`, installed by :meth:`install` and put back by :meth:`restore`."""

    def __init__(self) -> None:
        self.stop = StopRequest()
        self._immediate = True
        self._previous: dict[int, object] = {}

    def install(self, held: bool = False) -> "SignalGuard":
        """Install the handlers; ``held``: recording only from the first handler on (as
        :meth:`hold`), so a signal that lands while the rest are installed does not raise
        there, outside any code that could turn it into an exit status."""
        if held:
            self._immediate = False
        try:
            for signum in HANDLED:
                self._previous[signum] = signal.signal(signum, self._on_signal)
        except ValueError:  # not the main thread (an embedding app): signals stay theirs
            self.restore()
            return self
        self._previous_hook = sys.unraisablehook
        sys.unraisablehook = self._unraisable
        return self

    def restore(self) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()
        if getattr(self, "_previous_hook", None) is not None:
            sys.unraisablehook = self._previous_hook
            self._previous_hook = None

    def _unraisable(self, unraisable) -> None:
        """A signal that lands inside a callback Python cannot raise from (an import
        lock's weakref callback, a finaliser) would print "Exception ignored" and a
        traceback.  The stop is already recorded, and :meth:`raise_if_stopped` ends the
        command at the next check, so that one exception is dropped quietly."""
        if isinstance(unraisable.exc_value, Interrupted):
            return
        (self._previous_hook or sys.__unraisablehook__)(unraisable)

    def ignore_from_now_on(self) -> None:
        """Ignore these signals until the process exits (for the program's last moments)."""
        if self.installed:
            for signum in HANDLED:
                signal.signal(signum, signal.SIG_IGN)

    @property
    def installed(self) -> bool:
        return bool(self._previous)

    def _on_signal(self, signum: int, frame: object) -> None:
        if self.stop.signal_name is not None:
            return  # already stopping: let the cleanup finish
        name, status = HANDLED[signum]
        self.stop.request(name, status)
        if self._immediate:
            self._immediate = False
            raise Interrupted(name, status)
        if self.stop.in_controller:
            raise Interrupted(name, status)

    def hold(self) -> None:
        """Signals stop raising (they are still recorded): for error handling and cleanup."""
        self._immediate = False

    def arm(self) -> None:
        """Signals raise again, and one already recorded raises now: for a guard installed
        held (the program's, while its modules load) once the command can unwind."""
        self._immediate = True
        self.raise_if_stopped()

    @contextmanager
    def deferred(self) -> Iterator[StopRequest]:
        """From here on a signal only requests a stop; it never raises again.

        Enter it just before the first output is created: from then on an exception
        raised by a signal could cut short the code that completes or removes files.
        """
        self.hold()
        self.raise_if_stopped()
        yield self.stop

    def raise_if_stopped(self) -> None:
        """Raise :class:`Interrupted` if a signal has already been received."""
        if self.stop.signal_name is not None:
            raise Interrupted(self.stop.signal_name, self.stop.exit_status)
