"""``tspend run``: one scenario's closed loop, recorded to ``.rrd``, metrics printed."""

from __future__ import annotations

import argparse
import json
import re

from tspend import __version__
from tspend.cli.main import (DEFAULT_SCENARIO, EXIT_CONTROLLER_ERROR, EXIT_DIVERGED, EXIT_OK,
    EXIT_TERMINATED, Claimed,
    add_scenario_options, check_model_size, check_viewer_url, controller_help, load_with_overrides,
    metrics_document, plan, print_metrics, printable, recording_request, release_warnings, say,
    scenario_inputs, uses_mujoco)
from tspend.errors import OutputError, ScenarioError
from tspend.runtime.outputs import OutputRequest, display, slug


def add_parser(subparsers) -> argparse.ArgumentParser:
    r = subparsers.add_parser("run", help="run a scenario (default: the MuJoCo pendulum) headless")
    r.add_argument("scenario", nargs="?", default=DEFAULT_SCENARIO,
                   help="scenario name (see 'tspend list') or path to a .toml file")
    add_scenario_options(r)
    r.add_argument("--controller", metavar="KIND",
                   help="run another controller kind on the scenario (default: the scenario's "
                        "own), or your own: path/to/file.py:Class or package.module:Class; "
                        "'tspend run --controller help' lists the kinds")
    r.add_argument("--metrics", metavar="PATH.json",
                   help="write the metrics as one JSON object (replaced only by a complete one)")
    return r


def open_sinks(args: argparse.Namespace, app_name: str, path, prefixes: tuple[str, ...] = ("",)):
    """The recording stream (saving to ``path``, the partial file) and one sink per prefix."""
    if path is None and not (args.spawn or args.connect):
        return None, []
    from tspend.recorder import RerunSink, open_recording

    app_id = "tspend_" + re.sub(r"[^A-Za-z0-9_-]", "_", app_name)  # Rerun entry-name rules
    rec = open_recording(app_id, path=path, spawn=args.spawn, connect=args.connect)
    if rec is None:  # no viewer reachable and nothing to save: the run goes on headless
        return None, []
    sinks = [RerunSink(rec, prefix=p, blueprint_prefixes=prefixes if i == 0 else None,
                       curves_every=args.record_every)
             for i, p in enumerate(prefixes)]
    return rec, sinks


def close_sinks(rec, path) -> str:
    """Close the recording; "" or why the file at ``path`` is not complete."""
    if rec is None:
        return ""
    from tspend.recorder.stream import close_recording

    try:
        return close_recording(rec, path)
    except Exception as exc:  # noqa: BLE001 - whatever it was, the file is not trustworthy
        return f"{type(exc).__name__}: {exc}"


def cmd(args: argparse.Namespace) -> int:
    from tspend.runtime.native_logs import mujoco_warnings_in_errors

    if controller_help(args):
        return EXIT_OK
    if args.controller is not None:
        from tspend.controllers import load

        load(args.controller)  # before the scenario: it may carry the plug-in's table
    scn = load_with_overrides(args)
    check_viewer_url(args.connect)
    check_model_size(scn)
    stem = f"{slug(scn.name)}"
    plans = plan([recording_request(args, stem),
                  OutputRequest("--metrics", "metrics", ".json", args.metrics)
                  if args.metrics is not None else None],
                 scenario_inputs(scn))
    with mujoco_warnings_in_errors(uses_mujoco(scn)):
        from tspend.loop.simulation import prepare, run

        prepared = prepare(scn, controller=args.controller)
        with args.guard.deferred() as stop, Claimed(plans, scn.run.seed) as outs:
            return _run(args, scn, prepared, stop, outs, run)


def _run(args, scn, prepared, stop, outs: Claimed, run) -> int:
    from tspend.runtime.progress import RunProgress  # a bar on a terminal once the run takes a few seconds
    from tspend.loop.runner import CONTROLLER_ERROR, RunInterrupted
    from tspend.task import TERMINATIONS

    recording, metrics_out = outs["--out"], outs["--metrics"]
    rec, sinks = open_sinks(args, scn.name, recording.partial if recording else None)
    release_warnings(args)
    print(f"tspend {__version__}: {printable(scn.name)} ({scn.plant.kind}), "
          f"{scn.run.duration:g} s at dt = {scn.run.dt:g} s, seed {scn.run.seed}"
          + (f", recording to {printable(display(recording.target))}" if recording else ""),
          flush=True)
    interrupted = None
    try:
        end = run(scn, sinks=[*sinks, RunProgress()], keep_history=False, stop=stop,
                  controller=args.controller, prepared=prepared).end
    except RunInterrupted as exc:
        interrupted, end = exc, exc.end
    finally:
        problem = close_sinks(rec, recording.partial if recording else None)
    failures = [outs.complete(recording, problem)]
    if end is not None:
        failures.append(outs.write_json(metrics_out, metrics_document(
            prepared.scenario, end, prepared.controller, args.controller)))
    failures = [f for f in failures if f]

    if end is not None:
        print(f"{end.status}: {end.steps_done} steps" + (f" ({printable(end.message)})"
                                                          if end.message else ""))
        print_metrics(end.metrics)
    if recording is not None and recording.committed:
        print(f"recording: {printable(display(recording.target))}  "
              f"(open with: rerun {printable(display(recording.target))})")
    if failures:
        if end is not None:  # the figures of a finished run are never lost
            print(json.dumps(metrics_document(prepared.scenario, end, prepared.controller,
                                              args.controller), indent=2))
        raise OutputError("; ".join(failures) + "; the metrics are on stdout")
    if interrupted is not None:
        kept = [display(o.target) for o in (recording, metrics_out) if o is not None]
        say(f"interrupted by {interrupted.signal_name}"
            + (f"; {' and '.join(kept)} kept up to the stop" if kept else ""))
        return interrupted.exit_status
    if stop.signal_name is not None:  # arrived after the last sample: the run is whole
        say(f"{stop.signal_name} after the run completed; results kept")
        return stop.exit_status
    if end.status == "diverged":
        say(end.message)
        return EXIT_DIVERGED
    if end.status in TERMINATIONS:  # fell, rail_end, joint_limit, state_bound
        say(end.message)
        return EXIT_TERMINATED
    if end.status == CONTROLLER_ERROR:  # the controller's code failed, not tspend's
        say(end.message)
        return EXIT_CONTROLLER_ERROR
    return EXIT_OK
