"""The ``tspend`` command: run scenarios headless or live, list them, cross-check backends.

Exit status (the ``EXIT_*`` constants):

====  =====================================================================================
0     success
1     ``crosscheck``: the backends differ by more than ``--tol``, or the verdict is
      inconclusive (less than 0.5 s of open loop compared before a constraint acted)
2     bad input: command line, scenario, model file, output path, a size bound exceeded
3     the closed loop diverged (recording and metrics kept up to the divergence)
4     the task ended the run (``[task]``, tspend/task.py): ``fell`` (the pole passed
      ``fall_angle``), ``rail_end`` (a slide joint's range, or ``effects.rail``),
      ``joint_limit`` (another joint's range, or the rig's stop), ``state_bound``,
      ``not_reached`` (every bound held, but not the goal ``task.goal_angle`` from
      ``task.goal_by`` on); outputs kept up to the end
5     an output could not be completed (disk full, I/O error); the file it would have
      replaced is untouched and the metrics are printed to stdout as JSON as well
6     the controller failed (status ``controller_error``): it raised, returned something
      that is not one number, or called ``sys.exit``; outputs kept up to that sample
7     ``sweep``, ``compare``: runs did not complete (status ``controller_error``,
      ``timeout``, killed past ``--run-timeout``, or ``failed``); every other run's row is kept, and stderr says
      how many
70    internal error (a bug: please report it with the ``--debug`` traceback)
129   SIGHUP, 130 SIGINT (Ctrl-C), 143 SIGTERM: outputs completed up to the stop
====  =====================================================================================

Every error is one line on stderr, ``tspend: error: ...``, with control characters
escaped; ``--debug`` adds the traceback.

A command that writes files does its work in this order, so that a rejected command
writes nothing and a failed one replaces nothing: (1) check everything: arguments,
scenario, the plant and controller built, and the output paths against each other and
against every input; (2) claim the outputs (an exclusive partial file beside each, see
:mod:`tspend.runtime.outputs`); (3) print the banner; (4) run; (5) complete the outputs, each
renamed into place only when whole.  Signal handlers are installed before any of it,
before numpy, MuJoCo or Rerun are imported (:mod:`tspend.runtime.interrupts`).

Adding a subcommand: write ``tspend/cli/<name>.py`` with ``add_parser(subparsers)``
(adds its subparser) and ``cmd(args) -> int``, and add ``"<name>"`` to :data:`COMMANDS`.
Keep the module's top-level imports light (stdlib, ``tspend.cli``); import the heavy
parts inside ``cmd``.  The machinery below is for those modules:
:func:`add_scenario_options`, :func:`load_with_overrides`, :func:`plan`, :class:`Claimed`
(outputs), ``args.guard`` (the :class:`~tspend.runtime.interrupts.SignalGuard`), :func:`printable`,
:func:`print_metrics`, and the ``EXIT_*`` statuses.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import json
import math
import os
import re
import sys
import traceback
import warnings
from pathlib import Path
from contextlib import contextmanager
from typing import Any, Iterable, Iterator, Sequence

from tspend import __version__
from tspend.errors import OutputError, ScenarioError, TspendError
from tspend.runtime.interrupts import Interrupted, SignalGuard, StopRequest
from tspend.runtime.outputs import (Output, OutputRequest, PlannedOutput, claim, display,
    plan_outputs)

#: the subcommands, each the module ``tspend/cli/<name>.py``, in ``--help`` order
COMMANDS = ("run", "crosscheck", "list", "inspect", "sweep", "export", "compare", "tune",
            "figures", "excite", "identify", "plan")

DEFAULT_SCENARIO = "pendulum_mujoco"
EXIT_OK = 0
EXIT_TOLERANCE = 1
EXIT_BAD_INPUT = 2
EXIT_DIVERGED = 3
#: the task ended the run: fell, rail_end, joint_limit, state_bound (tspend.task.TERMINATIONS)
EXIT_TERMINATED = 4
EXIT_RAIL_END = EXIT_TERMINATED  # the name before [task]: a rail end is one termination
EXIT_WRITE_FAILED = 5
#: the controller failed: raised, returned no number, or called sys.exit (a plug-in's
#: error; the recording and metrics are kept up to the sample before)
EXIT_CONTROLLER_ERROR = 6
#: sweep, compare: some runs did not complete (controller_error, timeout, failed); their
#: rows are kept
EXIT_INCOMPLETE = 7
EXIT_INTERNAL = 70
#: the largest value accepted by options taking a count (--record-every)
MAX_COUNT = 10**9


class UsageError(ScenarioError):
    """A command-line problem argparse found (exit 2, one line)."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        # "tspend: error: run: ...": the program's name is said once, by say()
        command = self.prog.removeprefix("tspend").strip()
        raise UsageError(f"{command + ': ' if command else ''}{message} (see '{self.prog} --help')")


# -- deprecated spellings of options (one release; docs/reference/cli.md) ----------------
class _DeprecatedAlias(argparse.Action):
    """An old option's spelling: stores into the new option's ``dest`` and notes the
    deprecation, printed as one ``tspend: warning:`` line once the input is accepted."""

    def __init__(self, option_strings, dest, new: str = "", **kwargs) -> None:
        self.new = new
        super().__init__(option_strings, dest, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        setattr(namespace, self.dest, values)
        notes = namespace.__dict__.setdefault("deprecations", [])
        notes.append(f"{option_string} is deprecated and goes in the next release; use {self.new}")


def add_deprecated_alias(p: argparse.ArgumentParser, old: str, new: str, metavar: str) -> None:
    """``old`` as a hidden, deprecated spelling of the option ``new`` (same ``dest``)."""
    p.add_argument(old, dest=new.lstrip("-").replace("-", "_"), action=_DeprecatedAlias,
                   new=new, metavar=metavar, help=argparse.SUPPRESS)


def add_metrics_option(p: argparse.ArgumentParser, what: str = "the metrics",
                       old: str | None = None) -> None:
    """``--metrics PATH.json``: every command's figures as one JSON object (``old``: a
    deprecated spelling kept one release, e.g. ``--json``)."""
    p.add_argument("--metrics", metavar="PATH.json",
                   help=f"write {what} as one JSON object (replaced only by a complete one)")
    if old:
        add_deprecated_alias(p, old, "--metrics", "PATH.json")


def say_deprecations(args: argparse.Namespace) -> None:
    """One ``tspend: warning:`` line per deprecated spelling used (stderr)."""
    for note in args.__dict__.pop("deprecations", []):
        say(f"warning: {note}")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="tspend", description=__doc__.split("\n")[0])
    p.add_argument("--version", action="version", version=f"tspend {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        module = importlib.import_module(f"tspend.cli.{name}")
        known = set(sub.choices)
        module.add_parser(sub)
        for added in set(sub.choices) - known:  # whatever names the module registered
            sub.choices[added].set_defaults(handler=module.cmd)
    return p


# -- options and values shared by the commands -------------------------------------------
def finite(low: float = 0.0, high: float = math.inf, strict: bool = True):
    """An argparse type: a finite float in (low, high] (``strict``) or [low, high]."""
    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text[:40]!r}") from None
        ok = math.isfinite(v) and (v > low if strict else v >= low) and v <= high
        if not ok:
            span = f"{'>' if strict else '>='} {low:g}" + (f" and <= {high:g}" if high < math.inf
                                                          else "")
            raise argparse.ArgumentTypeError(f"must be a finite number {span}, got {text[:40]}")
        return v
    return parse


def bounded_int(low: int, high: int):
    """An argparse type: an integer in [low, high], read without converting huge digit strings."""
    def parse(text: str) -> int:
        t = text.strip()
        if not re.fullmatch(r"[+-]?\d{1,30}", t):
            shown = t if len(t) <= 40 else f"{t[:20]}... ({len(t)} characters)"
            raise argparse.ArgumentTypeError(f"must be an integer from {low} to {high}, got "
                                             f"{shown!r}")
        v = int(t)
        if not low <= v <= high:
            raise argparse.ArgumentTypeError(f"must be an integer from {low} to {high}, got {v}")
        return v
    return parse


def add_scenario_options(p: argparse.ArgumentParser, recording: bool = True) -> None:
    """The options of every command that runs a scenario: overrides and recording."""
    from tspend.runtime.bounds import MAX_SEED

    p.add_argument("--duration", type=finite(), metavar="S", help="override run.duration")
    p.add_argument("--seed", type=bounded_int(0, MAX_SEED), metavar="N",
                   help="override run.seed")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override any field, e.g. --set controller.eta=0.01 (repeatable)")
    if recording:
        out = p.add_mutually_exclusive_group()
        out.add_argument("--out", metavar="PATH.rrd",
                         help="recording file (default runs/<scenario>-<time>-s<seed>.rrd, a "
                              "new name for every run); an existing file is replaced only "
                              "by a complete recording")
        out.add_argument("--no-record", action="store_true", help="record nothing")
        p.add_argument("--record-every", type=bounded_int(1, MAX_COUNT), default=1, metavar="N",
                       help="record every Nth sample of the time series (default 1: every "
                            "one, exact); 10 makes long recordings ten times smaller")
        p.add_argument("--spawn", action="store_true", help="also stream to a live Rerun viewer")
        p.add_argument("--connect", metavar="URL",
                       help="also stream to a running Rerun viewer "
                            "(e.g. rerun+http://127.0.0.1:9876/proxy)")
    p.add_argument("--debug", action="store_true", help="show tracebacks")


def parse_set_value(item: str) -> tuple[str, Any]:
    """``KEY=VALUE`` of --set: the value in TOML (a bare word is a string), on one line
    (:func:`tspend.sweep.plan.parse_value`, the one reader of a value on the command line)."""
    from tspend.sweep.plan import parse_value

    key, sep, text = item.partition("=")
    if not sep or not key.strip():
        raise ScenarioError(f"--set {item[:80]}: expected KEY=VALUE, e.g. controller.eta=0.01")
    return key.strip(), parse_value(text.strip(), f"--set {key.strip()[:80]}")


def load_with_overrides(args: argparse.Namespace):
    """The scenario named by ``args.scenario`` with --duration, --seed and --set applied."""
    from tspend.scenario import load_scenario, override

    scn = load_scenario(args.scenario)
    changes: dict[str, Any] = {}
    if args.duration is not None:
        changes["run.duration"] = float(args.duration)
    if args.seed is not None:
        changes["run.seed"] = int(args.seed)
    for item in args.set:
        key, value = parse_set_value(item)
        changes[key] = value
    return override(scn, **changes) if changes else scn


def uses_mujoco(scn) -> bool:
    """Whether the scenario's plant is a MuJoCo model (its domain's backend steps an MJCF)."""
    from tspend.plants.registry import PLANT_KINDS

    return PLANT_KINDS[scn.plant.kind].mujoco


def scenario_inputs(scn) -> list[str]:
    """Every file a run reads: outputs must never be one of them."""
    from tspend.scenario import resolve_model_path

    inputs = [scn.path] if scn.path and scn.path != "<string>" else []
    if uses_mujoco(scn):
        inputs.append(str(resolve_model_path(scn)))
    return inputs


def check_model_size(scn, limit: int = 10_000_000, kind: str | None = None) -> None:
    """An MJCF larger than ``limit`` bytes is refused before MuJoCo reads it."""
    from tspend.plants.registry import PLANT_KINDS

    if not (uses_mujoco(scn) or (kind and PLANT_KINDS[kind].mujoco)):
        return
    from tspend.scenario import resolve_model_path

    path = resolve_model_path(scn)
    try:
        size = os.stat(path).st_size
    except (OSError, ValueError):
        return  # the plant reports a missing file with its own message
    if size > limit:
        raise ScenarioError(f"{path}: the model file is {size} bytes, more than {limit}")


def check_viewer_url(url: str | None) -> None:
    if url is None:
        return
    from tspend.recorder.stream import viewer_url_problem  # light: no Rerun call at import time

    problem = viewer_url_problem(url)
    if problem:
        raise ScenarioError(f"--connect {url[:200]}: {problem}")


# -- outputs -----------------------------------------------------------------------------
def recording_request(args: argparse.Namespace, stem: str) -> OutputRequest | None:
    """The recording of a command with the scenario options, or None (--no-record)."""
    if args.no_record:
        return None
    return OutputRequest("--out", "recording", ".rrd", args.out, default_stem=stem)


def plan(requests: Iterable[OutputRequest | None], inputs: Iterable[str] = ()) -> list[PlannedOutput]:
    """Check the outputs against each other and the inputs; writes nothing (exit 2 if bad)."""
    return plan_outputs([r for r in requests if r is not None], inputs)


class Claimed:
    """The outputs of one command, claimed together and completed or removed together.

    ``with Claimed(plans, seed) as outs:`` creates every partial file (or none);
    ``outs[option]`` is the :class:`~tspend.runtime.outputs.Output` of that option (or None);
    :meth:`complete` renames them into place; whatever is not completed when the block
    ends is removed.  Enter it inside ``args.guard.deferred()``.
    """

    def __init__(self, plans: Sequence[PlannedOutput], seed: int | None = None) -> None:
        self._plans, self._seed = plans, seed
        self.outputs: list[Output] = []

    def __enter__(self) -> "Claimed":
        self.outputs = claim(self._plans, self._seed)
        return self

    def __exit__(self, *exc: object) -> None:
        for out in self.outputs:
            if not out.committed:
                out.discard()

    def __getitem__(self, option: str) -> Output | None:
        return next((o for o in self.outputs if o.plan.request.option == option), None)

    def complete(self, output: Output | None, problem: str = "") -> str:
        """Rename ``output`` into place; returns "" or the one-line reason it failed.

        ``problem``: the writer already knows the file is incomplete; it is removed.
        """
        if output is None:
            return ""
        if problem:
            output.discard()
            return (f"{output.what} {display(output.target)}: could not be completed "
                    f"({problem}); nothing was replaced")
        try:
            output.commit()
        except OutputError as exc:
            return str(exc)
        return ""

    def write_json(self, output: Output | None, obj: dict) -> str:
        """Write ``obj`` as JSON to ``output`` and complete it; "" or why it failed."""
        if output is None:
            return ""
        try:
            output.write((json.dumps(obj, indent=2) + "\n").encode())
        except OutputError as exc:
            output.discard()
            return str(exc)
        return self.complete(output)


# -- printing ----------------------------------------------------------------------------
_CONTROL = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069]")
_LONG_TOKEN = re.compile(r"\S{161,}")


def printable(text: object, limit: int = 2000) -> str:
    """``text`` on one line, safe for a terminal: controls escaped, long runs elided."""
    s = " ".join(str(text).split("\n"))
    s = s.replace("\t", " ").replace("\r", " ")
    s = _CONTROL.sub(lambda m: repr(m.group())[1:-1], s)
    s = _LONG_TOKEN.sub(lambda m: f"{m.group()[:100]}...({len(m.group())} characters)", s)
    return s if len(s) <= limit else s[:limit] + "..."


def format_value(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    return "n/a" if v is None else str(v)


def print_metrics(metrics: dict, stream=None) -> None:
    stream = stream or sys.stdout
    keys = ("rmse", "rmse_ss", "max_abs_e", "max_abs_e_ss", "iae", "ise", "itae",
            "control_energy", "max_abs_u", "tv_u_per_s", "sim_s", "steps", "wall_s")
    width = max(len(k) for k in keys)
    for k in keys:
        if k in metrics:
            print(f"  {k:<{width}}  {format_value(metrics[k])}", file=stream)


def metrics_document(scn, end, controller=None, spec: str | None = None,
                     units: dict | None = None) -> dict:
    """The metrics JSON: the figures, how the run ended, and what produced it.

    ``controller``: the controller that ran; ``spec``: what ``--controller`` named (None:
    the scenario's own).  ``controller`` records its kind, the spec and its settings.
    """
    doc = dict(end.metrics, scenario=scn.name, status=end.status, message=end.message,
               version=__version__, scenario_path=scn.path,
               overrides={k: v for k, v in scn.overrides}, scenario_text=scn.text)
    if units:  # the unit of every figure: {"e": "rad", "u": "N", "joints": {"hinge": "rad"}}
        doc["units"] = units
    if controller is not None:
        from tspend.controllers import settings_of

        kind = getattr(controller, "kind", "") or type(controller).__name__
        paper = kind in ("second_type", "first_type") and spec is None
        doc["controller"] = {"kind": kind, "spec": spec or kind,
                             "settings": settings_of(scn, None if paper else kind)}
    return doc


def controller_help(args: argparse.Namespace) -> bool:
    """``--controller help``: print every kind, one line each (the command then exits 0)."""
    if getattr(args, "controller", None) != "help":
        return False
    from tspend.controllers import help_text

    sys.stdout.write(help_text())
    return True


@contextmanager
def stop_on_signals() -> Iterator[StopRequest]:
    """For a command called without the CLI's ``args.guard`` (from Python): signals only
    request a stop while the block runs; the previous handlers are put back after."""
    guard = SignalGuard().install()
    try:
        with guard.deferred() as stop:
            yield stop
    finally:
        guard.restore()


def check_writable(path: Path, what: str) -> None:
    """Check one JSON output before the work (a command with several outputs uses
    :func:`plan` and :class:`Claimed`)."""
    plan_outputs([OutputRequest(f"--{what}", what, ".json", str(path))])


def write_json(path: Path, obj: dict) -> None:
    """Write ``obj`` to ``path`` atomically: a partial file beside it, renamed when whole.

    Raises OutputError (exit 5) if it cannot be completed; ``path`` is then untouched.
    """
    plans = plan_outputs([OutputRequest("--json", "json", ".json", str(path))])
    with Claimed(plans) as outs:
        problem = outs.write_json(outs["--json"], obj)
    if problem:
        raise OutputError(problem)


def release_warnings(args: argparse.Namespace) -> None:
    """Print the warnings held so far, one ``tspend: warning:`` line each.

    Warnings are held while a command checks its input, so that bad input stays one line;
    a command calls this once the input is accepted (before its banner).
    """
    say_deprecations(args)  # after the input is accepted: bad input stays one line
    held = getattr(args, "warnings", None)
    if held:
        # a command that builds its plant more than once (the cross-check) warns once
        shown = args.__dict__.setdefault("warnings_shown", set())
        for message in dict.fromkeys(str(w.message) for w in held):
            if message not in shown:
                shown.add(message)
                say(f"warning: {message}")
        held.clear()


def say(message: str) -> None:
    """One line on stderr, ``tspend: ...``; a vanished terminal (SIGHUP) is not an error."""
    try:
        print(f"tspend: {printable(message)}", file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


class _ReaderGoneTolerant:
    """stdout that goes quiet once its reader has gone (``tspend list | head -1``, a
    closed terminal): the command carries on and its files are completed."""

    def __init__(self, stream) -> None:
        self._stream = stream
        self.reader_gone = False

    def _gone(self) -> None:
        self.reader_gone = True
        try:  # so the interpreter's final flush cannot fail either
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, self._stream.fileno())
            os.close(devnull)
        except (OSError, ValueError, AttributeError):
            pass

    def write(self, text: str) -> int:
        if not self.reader_gone:
            try:
                return self._stream.write(text)
            except OSError as exc:
                if exc.errno not in (errno.EPIPE, errno.EIO, errno.EINVAL):
                    raise
                self._gone()
        return len(text)

    def flush(self) -> None:
        if not self.reader_gone:
            try:
                self._stream.flush()
            except OSError as exc:
                if exc.errno not in (errno.EPIPE, errno.EIO, errno.EINVAL):
                    raise
                self._gone()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


#: commands that load MuJoCo models outside a run's own handling of MuJoCo's warnings
_MUJOCO_COMMANDS = ("plan", "excite", "identify", "tune", "figures", "compare")


def _native_logs(command: str):
    """For :data:`_MUJOCO_COMMANDS`: MuJoCo's warnings collected into the one-line error,
    never a ``MUJOCO_LOG.TXT`` in the working folder (other commands pay no MuJoCo import)."""
    from contextlib import nullcontext

    from tspend.runtime.native_logs import mujoco_warnings_in_errors

    return mujoco_warnings_in_errors(True) if command in _MUJOCO_COMMANDS else nullcontext()


# -- entry point -------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> int:
    guard = SignalGuard().install()  # first: a signal from here on has its exit status
    real_stdout = sys.stdout
    sys.stdout = _ReaderGoneTolerant(real_stdout)
    args: argparse.Namespace | None = None
    try:
        from tspend.runtime.native_logs import quiet_rerun

        quiet_rerun()
        args = build_parser().parse_args(argv)
        args.guard = guard
        from tspend.cli.extras import check_needed

        check_needed(args)  # a missing optional package: one line naming its extra, no work
        # warnings (numpy's overflow on the way to a bad value, say) would add lines to
        # the one-line error: kept, and printed after a command that succeeds
        with warnings.catch_warnings(record=True) as caught, _native_logs(args.command):
            args.warnings = caught
            status = args.handler(args)
        release_warnings(args)
        return status
    except Interrupted as exc:
        guard.hold()
        say(f"interrupted by {exc.signal_name} before any output was written")
        return exc.exit_status
    except TspendError as exc:
        guard.hold()
        if getattr(args, "debug", False):
            traceback.print_exc()
        say(f"error: {exc}")
        return exc.exit_status
    except KeyboardInterrupt:  # handlers not installed (not the main thread)
        guard.hold()
        say("interrupted")
        return 130
    except Exception as exc:  # a bug: still one line, the traceback on request
        guard.hold()
        if guard.stop.signal_name is not None:
            # the signal's exception, turned into another by the code it interrupted (an
            # extension module being imported reports "ImportError: initialization failed")
            say(f"interrupted by {guard.stop.signal_name} before any output was written")
            return guard.stop.exit_status
        if getattr(args, "debug", False):
            traceback.print_exc()
        say(f"internal error: {type(exc).__name__}: {exc} (--debug shows the traceback)")
        return EXIT_INTERNAL
    finally:
        guard.hold()  # from here a signal is only noted: the exit cannot be cut short
        try:
            sys.stdout.flush()
        except (OSError, ValueError):
            pass
        sys.stdout = real_stdout
        if argv is not None:  # called from Python (tests, notebooks): handlers back
            guard.restore()
        else:
            # the program itself: the interpreter's shutdown resets Python handlers to the
            # default action, so a late second signal would kill the process and lose the
            # exit status.  Its work is done: ignore them for the last milliseconds.
            guard.ignore_from_now_on()


if __name__ == "__main__":
    sys.exit(main())
