"""Progress on a terminal: a bar for a long ``tspend run`` and for a sweep.

On a terminal (stderr is a TTY) a tqdm bar with its ETA; otherwise a sweep prints a
plain line every ``every`` seconds, and a single run prints nothing (its log would
only be noise in files and CI output).  A single run shows its bar only once it has
taken more than ``after`` seconds, so short runs print exactly what they printed before.
"""

from __future__ import annotations

import sys
import time
from typing import Any, TextIO

from tspend.loop.sinks import Block, InnerSnapshot, RunEnd, RunInfo


def _on_terminal(stream: TextIO) -> bool:
    isatty = getattr(stream, "isatty", None)
    return bool(isatty and isatty())


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class RunProgress:
    """A sink showing a run's simulated time against its duration, on a terminal only."""

    wants_inner = False

    def __init__(self, stream: TextIO | None = None, after: float = 3.0) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.after = after
        self.enabled = _on_terminal(self.stream)
        self._bar = None
        self._started = 0.0
        self._info: RunInfo | None = None
        self._done = 0

    def start(self, info: RunInfo) -> None:
        self._info = info
        self._started = time.monotonic()
        self._done = 0

    def block(self, block: Block) -> None:
        if not self.enabled or self._info is None:
            return
        steps = len(block.data["t"])
        self._done = block.start + steps
        if self._bar is None:
            if time.monotonic() - self._started < self.after:
                return
            from tqdm import tqdm

            self._bar = tqdm(total=self._info.steps, initial=block.start, file=self.stream,
                             unit="step", unit_scale=True, leave=False, dynamic_ncols=True,
                             desc=f"{self._info.scenario_name}",
                             bar_format="{desc}: {percentage:3.0f}%|{bar}| {postfix} "
                                        "[{elapsed}<{remaining}, {rate_fmt}]")
        self._bar.set_postfix_str(f"t = {self._done * self._info.dt:.1f} / "
                                  f"{self._info.duration:g} s", refresh=False)
        self._bar.update(self._done - self._bar.n)

    def inner(self, snap: InnerSnapshot) -> None:
        pass

    def finish(self, end: RunEnd) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


class SweepProgress:
    """Runs done out of the total, with the ETA and how many diverged or failed."""

    def __init__(self, total: int, skipped: int = 0, stream: TextIO | None = None,
                 every: float = 10.0, enabled: bool = True) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.total, self.skipped, self.every = total, skipped, every
        self.enabled = enabled
        self.counts = {"completed": 0, "diverged": 0, "failed": 0}
        self._done = 0
        self._started = time.monotonic()
        self._last_line = self._started
        self._bar = None

    def start(self, workers: int, where: str) -> None:
        """Say what is about to run, then show the bar (on a terminal) or plain lines."""
        if not self.enabled:
            return
        before = f", {self.skipped} already in the table" if self.skipped else ""
        print(f"sweep: {self.total} runs on {workers} {where} worker"
              f"{'s' if workers != 1 else ''}{before}", file=self.stream, flush=True)
        self._started = self._last_line = time.monotonic()
        if _on_terminal(self.stream):
            from tqdm import tqdm

            self._bar = tqdm(total=self.total, file=self.stream, unit="run", dynamic_ncols=True,
                             desc="sweep", smoothing=0.05)
            self._bar.set_postfix_str(self._postfix(), refresh=True)

    def _postfix(self) -> str:
        text = f"diverged {self.counts['diverged']}, failed {self.counts['failed']}"
        # a controller's error and a run killed past --run-timeout: shown once there is one
        for status in ("controller_error", "timeout"):
            if self.counts.get(status, 0):
                text += f", {status} {self.counts[status]}"
        return text

    def update(self, row: dict[str, Any]) -> None:
        status = row.get("status", "failed")
        self.counts[status] = self.counts.get(status, 0) + 1
        self._done += 1
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.set_postfix_str(self._postfix(), refresh=False)
            self._bar.update(1)
            return
        now = time.monotonic()
        if now - self._last_line >= self.every or self._done == self.total:
            self._last_line = now
            print(self.line(now), file=self.stream, flush=True)

    def line(self, now: float | None = None) -> str:
        elapsed = (now or time.monotonic()) - self._started
        rate = self._done / elapsed if elapsed > 0 else 0.0
        eta = (self.total - self._done) / rate if rate > 0 else float("nan")
        eta_text = _duration(eta) if eta == eta else "?"
        return (f"sweep: {self._done}/{self.total} runs ({self._postfix()}), "
                f"{_duration(elapsed)} elapsed, ETA {eta_text}")

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


class TuneProgress:
    """Trials done out of the budget, with the best score so far (``tspend tune``)."""

    def __init__(self, total: int, done: int = 0, label: str = "tune",
                 stream: TextIO | None = None, every: float = 10.0,
                 enabled: bool = True) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.total, self.done, self.label, self.every = total, done, label, every
        self.enabled = enabled
        self.best = float("nan")
        self._started = self._last_line = time.monotonic()
        self._bar = None
        if enabled and _on_terminal(self.stream):
            from tqdm import tqdm

            self._bar = tqdm(total=total, initial=done, file=self.stream, unit="trial",
                             dynamic_ncols=True, desc=label)

    def update(self, best: float) -> None:
        self.done += 1
        self.best = best
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.set_postfix_str(f"best {best:.4g}", refresh=False)
            self._bar.update(1)
            return
        now = time.monotonic()
        if now - self._last_line >= self.every or self.done == self.total:
            self._last_line = now
            print(f"{self.label}: {self.done}/{self.total} trials, best {best:.4g}, "
                  f"{_duration(now - self._started)} elapsed", file=self.stream, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


#: how every progress line of a slow step starts on stderr; such a line is never an error,
#: so a script (or a test) that reads stderr for the one error line of a failure skips it
PROGRESS_PREFIX = "tspend: progress: "


class SlowStep:
    """A step that can take long with nothing else to show (numba's first compile, a
    safety filter's design): once it has lasted ``after`` seconds, one line says what it
    is and about how long it takes (``estimate``, e.g. "about 25 s on 2 idle cores"); on
    a terminal that line then counts the seconds in place; when the step ends after such
    a notice, one more line says how long it took. A step that ends sooner prints nothing.

    Use as ``with SlowStep(...):`` or call :meth:`begin` and :meth:`end` (a sink ends it
    on the closed loop's first block)."""

    def __init__(self, what: str, estimate: str, stream: TextIO | None = None,
                 after: float = 2.0) -> None:
        self.what, self.estimate, self.after = what, estimate, after
        self.stream = stream if stream is not None else sys.stderr
        self.announced = False
        self._started = 0.0
        self._thread = None
        self._ended = None

    def begin(self) -> "SlowStep":
        import threading

        self._started = time.monotonic()
        self._ended = threading.Event()
        self._thread = threading.Thread(target=self._watch, daemon=True, name="slow-step")
        self._thread.start()
        return self

    def _say(self, text: str, end: str = "\n") -> None:
        try:
            print(text, file=self.stream, end=end, flush=True)
        except (OSError, ValueError):  # a vanished terminal is not the step's failure
            pass

    def _watch(self) -> None:
        if self._ended.wait(self.after):
            return
        self.announced = True
        head = f"{PROGRESS_PREFIX}{self.what} ({self.estimate})"
        if not _on_terminal(self.stream):
            self._say(head + "...")
            return
        while not self._ended.wait(1.0):  # the line counts the seconds in place
            self._say(f"\r{head}: {time.monotonic() - self._started:.0f} s", end="")

    def end(self, failed: bool = False) -> None:
        """The step is over: one line with its duration when it was announced (none when it
        ``failed``: the error says what happened)."""
        if self._ended is None or self._ended.is_set():
            return
        self._ended.set()
        self._thread.join()
        if self.announced and not failed:
            # on a terminal: over the counting line, erased to its end
            lead, tail = ("\r", "\033[K") if _on_terminal(self.stream) else ("", "")
            self._say(f"{lead}{PROGRESS_PREFIX}{self.what}: done in "
                      f"{time.monotonic() - self._started:.0f} s{tail}")

    def __enter__(self) -> "SlowStep":
        return self.begin()

    def __exit__(self, kind, value, traceback) -> None:
        self.end(failed=kind is not None)
