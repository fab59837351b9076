"""The ``tspend`` command: run scenarios headless or live, list them, cross-check backends.

Exit status: 0 success; 1 cross-check out of tolerance or an internal error; 2 bad
input (scenario, model, command line, output path); 3 the closed loop diverged; 130
interrupted by Ctrl-C (SIGINT); 143 terminated (SIGTERM).  Errors print one line;
``--debug`` shows the traceback.  A run that stops early still writes its recording
and its metrics up to that point.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import signal
import sys
import time
import traceback
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

from . import __version__, cli_inspect
from . import cli_export, cli_sweep
from . import cli_compare, cli_figures
from .errors import ScenarioError, TspendError
from .plants.mjcf_warning import print_as_one_line
from .progress import RunProgress
from .runner import RunInterrupted, StopRequest

DEFAULT_SCENARIO = "pendulum_mujoco"
EXIT_DIVERGED = 3


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="tspend", description=__doc__.split("\n")[0])
    p.add_argument("--version", action="version", version=f"tspend {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("run", help="run a scenario (default: the MuJoCo pendulum) headless")
    r.add_argument("scenario", nargs="?", default=DEFAULT_SCENARIO,
                   help="scenario name (see 'tspend list') or path to a .toml file")
    _common(r)
    r.add_argument("--controller", metavar="KIND",
                   help="run another controller kind on the scenario (default: the scenario's "
                        "own; 'tspend run --controller help' lists the kinds)")
    r.add_argument("--metrics", metavar="PATH", help="write the metrics as one JSON object")

    c = sub.add_parser("crosscheck", help="run a cart-pole scenario on MuJoCo and on the ODE")
    c.add_argument("scenario", nargs="?", default=DEFAULT_SCENARIO)
    _common(c)
    c.add_argument("--json", metavar="PATH", help="write the cross-check figures as JSON")
    c.add_argument("--tol", type=float, default=1e-8,
                   help="open-loop tolerance on max |dtheta| in rad (default 1e-8)")
    c.add_argument("--open-loop-duration", type=float, default=10.0, metavar="S",
                   help="length of the open-loop comparison (default 10 s)")

    sub.add_parser("list", help="list the scenarios with their descriptions")
    cli_inspect.add_parser(sub)
    cli_sweep.add_parser(sub)
    cli_export.add_parser(sub)
    cli_compare.add_parser(sub)
    cli_figures.add_parser(sub)
    return p


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--duration", type=float, metavar="S", help="override run.duration")
    p.add_argument("--seed", type=int, metavar="N", help="override run.seed")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override any field, e.g. --set controller.eta=0.01 (repeatable)")
    out = p.add_mutually_exclusive_group()
    out.add_argument("--out", metavar="PATH.rrd",
                     help="recording file (default runs/<scenario>-<timestamp>.rrd)")
    out.add_argument("--no-record", action="store_true", help="record nothing")
    p.add_argument("--record-every", type=int, default=1, metavar="N",
                   help="record every Nth sample of the time series (default 1: every one, "
                        "exact); 10 makes long recordings ten times smaller")
    p.add_argument("--spawn", action="store_true", help="also stream to a live Rerun viewer")
    p.add_argument("--connect", metavar="URL", help="also stream to a running Rerun viewer")
    p.add_argument("--debug", action="store_true", help="show tracebacks")


# -- helpers -----------------------------------------------------------------------------
def _parse_value(text: str) -> Any:
    """A --set value: TOML-ish scalars and lists (numbers, true/false, strings)."""
    import tomllib

    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def load_with_overrides(args: argparse.Namespace):
    from .scenario import load_scenario, override

    scn = load_scenario(args.scenario)
    changes: dict[str, Any] = {}
    if args.duration is not None:
        if not (args.duration > 0 and math.isfinite(args.duration)):
            raise ScenarioError(f"--duration: must be a positive number of seconds, got "
                                f"{args.duration}")
        changes["run.duration"] = float(args.duration)
    if args.seed is not None:
        if args.seed < 0:
            raise ScenarioError(f"--seed: must be >= 0, got {args.seed}")
        changes["run.seed"] = int(args.seed)
    for item in args.set:
        key, sep, value = item.partition("=")
        if not sep:
            raise ScenarioError(f"--set {item}: expected KEY=VALUE, e.g. controller.eta=0.01")
        changes[key.strip()] = _parse_value(value.strip())
    return override(scn, **changes) if changes else scn


def check_writable(path: Path, what: str) -> None:
    """Fail before the run if ``path`` cannot be written (directory created if needed)."""
    parent = path.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ScenarioError(f"{what} {path}: cannot create directory {parent}: "
                            f"{exc.strerror or exc}") from None
    if path.is_dir():
        raise ScenarioError(f"{what} {path}: is a directory")
    if not os.access(parent, os.W_OK):
        raise ScenarioError(f"{what} {path}: directory {parent} is not writable")


def default_recording_path(name: str) -> Path:
    return Path("runs") / f"{name}-{time.strftime('%Y%m%d-%H%M%S')}.rrd"


@contextmanager
def stop_on_signals() -> Iterator[StopRequest]:
    """SIGINT and SIGTERM ask the run to stop at the next sample (it then flushes).

    A second Ctrl-C interrupts at once, for a run stuck outside the loop.
    """
    stop = StopRequest()

    def on_signal(signum, frame):
        if signum == signal.SIGINT and stop.signal_name == "SIGINT":
            raise KeyboardInterrupt
        stop.request(*{signal.SIGINT: ("SIGINT", 130), signal.SIGTERM: ("SIGTERM", 143)}[signum])

    try:
        previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    except ValueError:  # not the main thread: signals stay as they are
        yield stop
        return
    try:
        yield stop
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _fmt(v: Any) -> str:
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
            print(f"  {k:<{width}}  {_fmt(metrics[k])}", file=stream)


def metrics_document(scn, end) -> dict:
    """The metrics JSON: the figures, how the run ended, and what produced it."""
    return dict(end.metrics, scenario=scn.name, status=end.status, message=end.message,
                version=__version__, scenario_path=scn.path,
                overrides={k: v for k, v in scn.overrides}, scenario_text=scn.text)


def write_json(path: Path, obj: dict) -> None:
    path.write_text(json.dumps(obj, indent=2, sort_keys=False) + "\n")


# -- recording ---------------------------------------------------------------------------
def open_sinks(args: argparse.Namespace, name: str, prefixes: tuple[str, ...] = ("",)):
    """The recording stream and one Rerun sink per prefix (none with --no-record)."""
    if args.record_every < 1:
        raise ScenarioError(f"--record-every: must be >= 1, got {args.record_every}")
    if args.no_record and not (args.spawn or args.connect):
        return None, None, []
    from .recorder import RerunSink, open_recording

    path = None if args.no_record else Path(args.out or default_recording_path(name))
    if path is not None:
        check_writable(path, "recording")
    app_id = "tspend_" + re.sub(r"[^A-Za-z0-9_-]", "_", name)  # Rerun entry-name rules
    rec = open_recording(app_id, path=path, spawn=args.spawn, connect=args.connect)
    if rec is None:  # no viewer reachable and nothing to save: the run goes on headless
        return None, None, []
    sinks = [RerunSink(rec, prefix=p, blueprint_prefixes=prefixes if i == 0 else None,
                       curves_every=args.record_every)
             for i, p in enumerate(prefixes)]
    return rec, path, sinks


# -- commands ----------------------------------------------------------------------------
def cmd_list(args: argparse.Namespace) -> int:
    from .scenario import available_scenarios, load_scenario

    for path in available_scenarios():
        try:
            desc = load_scenario(path).description
        except TspendError as exc:
            desc = f"(invalid: {exc})"
        mark = " (default)" if path.stem == DEFAULT_SCENARIO else ""
        print(f"{path.stem}{mark}\n    {desc}")
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    from .simulation import run

    from .controllers import KINDS

    scn = load_with_overrides(args)
    if args.controller is not None and args.controller not in KINDS:
        raise ScenarioError(f"--controller {args.controller}: unknown kind; allowed: "
                            f"{', '.join(KINDS)}")
    metrics_path = Path(args.metrics) if args.metrics else None
    if metrics_path is not None:
        check_writable(metrics_path, "metrics")
    rec, rrd, sinks = open_sinks(args, scn.name)
    sinks = [*sinks, RunProgress()]  # a bar on a terminal once the run takes a few seconds
    print(f"tspend {__version__}: {scn.name} ({scn.plant.kind}), {scn.run.duration:g} s at "
          f"dt = {scn.run.dt:g} s, seed {scn.run.seed}"
          + (f", recording to {rrd}" if rrd else ""), flush=True)
    # signals only set a flag from here on, so closing the recording cannot be cut short
    with stop_on_signals() as stop:
        try:
            result = run(scn, sinks=sinks, keep_history=False, stop=stop,
                         controller=args.controller)
        except RunInterrupted as exc:
            if metrics_path is not None and exc.end is not None:
                write_json(metrics_path, metrics_document(scn, exc.end))
            print(f"tspend: interrupted by {exc.signal_name}; recording"
                  f"{' ' + str(rrd) if rrd else ''} and metrics kept up to the stop",
                  file=sys.stderr)
            return exc.exit_status
        finally:
            if rec is not None:
                _close(rec)
    end = result.end
    if metrics_path is not None:
        write_json(metrics_path, metrics_document(scn, end))
    if stop.signal_name is not None:  # arrived after the last sample: the run is whole
        print(f"tspend: {stop.signal_name} after the run completed; results kept",
              file=sys.stderr)
        return stop.exit_status
    print(f"{end.status}: {end.steps_done} steps" + (f" ({end.message})" if end.message else ""))
    print_metrics(end.metrics)
    if rrd:
        print(f"recording: {rrd}  (open with: rerun {rrd})")
    if end.status == "diverged":
        print(f"tspend: {end.message}", file=sys.stderr)
        return EXIT_DIVERGED
    if end.status == "rail_end":  # tspend.effects.RailEnd
        print(f"tspend: {end.message}", file=sys.stderr)
        return 4
    return 0


def _close(rec) -> None:
    from .recorder import close_recording

    try:
        close_recording(rec)
    except Exception as exc:  # the run's result stands; say what happened to the file
        print(f"tspend: warning: closing the recording failed: {exc}", file=sys.stderr)


def cmd_crosscheck(args: argparse.Namespace) -> int:
    from .crosscheck import crosscheck

    scn = load_with_overrides(args)
    json_path = Path(args.json) if args.json else None
    if json_path is not None:
        check_writable(json_path, "json")
    if not (args.tol > 0 and math.isfinite(args.tol)):
        raise ScenarioError(f"--tol: must be a positive number, got {args.tol}")
    rec, rrd, sinks = open_sinks(args, f"{scn.name}-crosscheck", prefixes=("mujoco/", "ode/"))
    from .recorder.crosscheck import crosscheck_sinks, record_verdict
    sinks = crosscheck_sinks(sinks)
    with stop_on_signals() as stop:
        try:
            report = crosscheck(scn, sinks=sinks, open_loop_duration=args.open_loop_duration,
                                stop=stop)
            report["tolerance"] = args.tol
            report["open_loop_ok"] = report["open_loop_max_dtheta"] <= args.tol
            record_verdict(sinks, report)
        except RunInterrupted as exc:
            print(f"tspend: cross-check interrupted by {exc.signal_name}", file=sys.stderr)
            return exc.exit_status
        finally:
            if rec is not None:
                _close(rec)
    for k, v in report.items():
        if not isinstance(v, dict):
            print(f"  {k:<34} {_fmt(v)}")
    if json_path is not None:
        write_json(json_path, report)
    if rrd:
        print(f"recording: {rrd}  (open with: rerun {rrd})")
    if not report["open_loop_ok"]:
        from .crosscheck import failure_reason

        print(f"tspend: cross-check failed: max |dtheta| = {report['open_loop_max_dtheta']:.3g} "
              f"rad > {args.tol:g}; {failure_reason(report)}", file=sys.stderr)
    return 0 if report["open_loop_ok"] else 1


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    commands = {"run": cmd_run, "list": cmd_list, "crosscheck": cmd_crosscheck,
                "inspect": cli_inspect.cmd}
    commands["sweep"] = cli_sweep.cmd
    commands["export"] = cli_export.cmd
    commands["compare"] = cli_compare.cmd
    commands["figures"] = cli_figures.cmd
    print_as_one_line()
    try:
        return commands[args.command](args)
    except TspendError as exc:
        if getattr(args, "debug", False):
            traceback.print_exc()
        print(f"tspend: error: {exc}", file=sys.stderr)
        return exc.exit_status
    except KeyboardInterrupt:
        print("tspend: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # a bug: still one line, the traceback on request
        if getattr(args, "debug", False):
            traceback.print_exc()
        print(f"tspend: internal error: {type(exc).__name__}: {exc} (--debug shows the "
              f"traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
