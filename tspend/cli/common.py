"""What the tspend subcommands share: exit statuses, option types, the scenario options,
outputs claimed and completed together, printing and the metrics document.

Every subcommand module (tspend/cli/<name>.py) imports from here, and so does
tspend/cli/main.py, which builds the parser and runs a command: no command imports main.
"""

from __future__ import annotations

import argparse
import errno
import json
import math
import os
import re
import sys
import textwrap
import traceback
import warnings
from pathlib import Path
from contextlib import contextmanager
from typing import Any, Iterable, Iterator, Sequence

from tspend import __version__
from tspend.runtime.errors import OutputError, ScenarioError, TspendError
from tspend.runtime.interrupts import Interrupted, SignalGuard, StopRequest
from tspend.runtime.outputs import (Output, OutputRequest, PlannedOutput, claim, display,
    plan_outputs)

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


_RST_ROLE = re.compile(r":[a-z]+:`~?([^`]+)`")
_RST_LITERAL = re.compile(r"``([^`]+)``")
#: a literal with a possessive (``[controllers.tvlqr]``'s): double quotes, so the help does
#: not read '[controllers.tvlqr]''s
_RST_POSSESSIVE = re.compile(r"``([^`]+)``'s\b")


def plain_text(text: str) -> str:
    """Help text as a terminal shows it: reStructuredText roles and literals (from a
    docstring) become plain words and quotes."""
    text = _RST_POSSESSIVE.sub("\"\\1\"'s", _RST_ROLE.sub(r"\1", text))
    return _RST_LITERAL.sub(r"'\1'", text)


def doc(name: str) -> str:
    """Where a user reads the document ``name`` (``docs/safety.md``): the copy shipped with
    tspend, beside a checkout's package or inside an installed wheel, so help text points
    at a file that is there (``tspend list --files`` lists the folder)."""
    from tspend.shipped import data_root

    return str(data_root() / name)


#: how the examples that end every command's help start (:data:`EXAMPLES`)
EXAMPLES_HEAD = "examples:"
#: the one or two commands a user needs first, by parser (``tspend figures paper``): the end
#: of each command's ``--help`` (tests/test_cli_plain.py parses every one)
EXAMPLES = {
    "tspend run": ("tspend run                          # the default scenario, headless",
                   "tspend run ex2_duffing --controller lqr --seed 3 --metrics m.json "
                   "--out duffing.rrd"),
    "tspend show": ("tspend show pendulum_mujoco > mine.toml   # then: tspend run mine.toml",),
    "tspend crosscheck": ("tspend crosscheck acrobot_mujoco --metrics cc.json",),
    "tspend list": ("tspend list --long", "tspend list --files   # where the examples and "
                                          "documents are"),
    "tspend inspect": ("tspend inspect models/double_cartpole.xml",),
    "tspend sweep": ("tspend sweep ex2_duffing --seeds 0:20 --grid controller.gamma=0.1,0.3 "
                     "--out gamma.parquet",),
    "tspend export": ("tspend export duffing.rrd --out duffing.csv",),
    "tspend compare": ("tspend compare ex2_duffing --controller second_type,first_type "
                       "--seeds 0:20",),
    "tspend tune": ("tspend tune ex3_pendulum_ode --controller pd --trials 8 --seeds 0:3 "
                    "--out tuned.toml",),
    "tspend figures": ("tspend figures paper --out figures",
                       "tspend figures box gamma.parquet --metric rmse_ss"),
    "tspend figures paper": ("tspend figures paper --out figures --duration 5",),
    "tspend figures box": ("tspend figures box gamma.parquet --metric rmse_ss,control_energy",),
    "tspend figures heatmap": ("tspend figures heatmap grid.parquet --x controller.gamma "
                               "--y controller.eta",),
    "tspend excite": ("tspend excite pendulum_mujoco_randomized --out exp.toml --duration 16",),
    "tspend identify": ("tspend identify e3.csv --model models/cartpole.xml --params m,l,M "
                        "--out fitted.xml",),
    "tspend plan": ("tspend plan double_cartpole_swingup --nominal --out p.parquet",),
    "tspend rig": ("tspend rig serve pendulum_mujoco --listen udp://127.0.0.1:9500",),
    "tspend rig serve": ("tspend rig serve pendulum_mujoco --listen udp://127.0.0.1:9500   "
                         "# then, in another shell: tspend run pendulum_mujoco --controller "
                         "lqr --rig udp://127.0.0.1:9500 --duration 20",),
    "tspend replay": ("tspend replay rig.rrd   # a rig run's commands, recomputed offline",),
}


class PlainHelpFormatter(argparse.HelpFormatter):
    """Help as plain text: no reStructuredText markup, and lines broken only between words
    (a long name such as pendulum_damping is never split across two lines)."""

    def _split_lines(self, text: str, width: int) -> list[str]:
        text = " ".join(plain_text(text).split())
        return textwrap.wrap(text, width, break_long_words=False, break_on_hyphens=False)

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if text.startswith(EXAMPLES_HEAD):  # commands: one a line, as typed
            return "".join(indent + line for line in text.splitlines(keepends=True))
        text = " ".join(plain_text(text).split())
        return textwrap.fill(text, width, initial_indent=indent, subsequent_indent=indent,
                             break_long_words=False, break_on_hyphens=False)


class PlainRawDescriptionFormatter(PlainHelpFormatter):
    """:class:`PlainHelpFormatter` that keeps the description's and epilog's own lines."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return "".join(indent + line for line in plain_text(text).splitlines(keepends=True))


class Parser(argparse.ArgumentParser):
    """argparse's parser, whose errors are one line (UsageError, exit 2) and whose help is
    plain text (:class:`PlainHelpFormatter`), for the command and every subcommand."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("formatter_class", PlainHelpFormatter)
        examples = EXAMPLES.get(kwargs.get("prog", ""))
        if examples and not kwargs.get("epilog"):  # a subcommand's help ends with them
            kwargs["epilog"] = "\n".join([EXAMPLES_HEAD, *("  " + e for e in examples)])
        super().__init__(*args, **kwargs)

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


class DeprecatedFlag(argparse.Action):
    """A flag that no longer does anything (``figures --pdf``: PDF is always written): kept
    one release so old scripts run, and said so in one ``tspend: warning:`` line."""

    def __init__(self, option_strings, dest, why: str = "", **kwargs) -> None:
        self.why = why
        super().__init__(option_strings, dest, nargs=0, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        notes = namespace.__dict__.setdefault("deprecations", [])
        notes.append(f"{option_string} does nothing ({self.why}) and goes in the next release")


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


def add_scenario_options(p: argparse.ArgumentParser, recording: bool = True,
                         compact: bool = True) -> None:
    """The options of every command that runs a scenario: overrides and recording
    (``compact``: --diagnostics-hz, the rate of a compact recording's views)."""
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
        if compact:
            p.add_argument("--diagnostics-hz", type=finite(0.0, 1e9, strict=False), default=50.0,
                           metavar="HZ",
                           help="rate of simulated time at which the plots and the controller's "
                                "diagnostics are recorded (default 50; its membership functions at "
                                "2 Hz); the state, the reference, the applied input and the "
                                "disturbance keep every sample whatever this is; 0 records every series and snapshot as it "
                                "comes (about three times larger)")
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


def reads_mjcf(scn) -> bool:
    """Whether a run reads an MJCF through MuJoCo: a MuJoCo plant, or an ODE whose machine
    is read and whose equations are derived from its MJCF (``double_cartpole_ode``: its
    MuJoCo warnings and errors, too, belong in the one line, never in MUJOCO_LOG.TXT)."""
    from tspend.plants.registry import domain_of

    return uses_mujoco(scn) or bool(domain_of(scn.plant.kind).model_file(scn.plant))


def scenario_inputs(scn) -> list[str]:
    """Every file a run reads: outputs must never be one of them."""
    from tspend.scenario import resolve_model_path

    inputs = [scn.path] if scn.path and scn.path != "<string>" else []
    if reads_mjcf(scn):
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


class ReaderGoneTolerant:
    """stdout that goes quiet once its reader has gone (``tspend list | head -1``, a
    closed terminal): the command carries on and its files are completed.  stdout that
    cannot be written (``> /dev/full``, a full disk) goes quiet the same way, and the
    failure is kept in :attr:`write_error`: the command's output was not completed
    (:meth:`failure`, exit 5)."""

    def __init__(self, stream) -> None:
        self._stream = stream
        self.reader_gone = False
        self.write_error: OSError | None = None

    def _gone(self, exc: OSError) -> None:
        if exc.errno not in (errno.EPIPE, errno.EIO, errno.EINVAL):
            self.write_error = exc  # not a reader that left: output lost, said at the end
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
                self._gone(exc)
        return len(text)

    def flush(self) -> None:
        if not self.reader_gone:
            try:
                self._stream.flush()
            except OSError as exc:
                self._gone(exc)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)

    def failure(self) -> OutputError | None:
        """After the command: stdout flushed, and the error of a write that failed (not a
        reader that left), or None."""
        self.flush()
        if self.write_error is None:
            return None
        reason = self.write_error.strerror or type(self.write_error).__name__
        return OutputError(f"stdout could not be written ({reason}): what the command "
                           f"printed there is incomplete")


