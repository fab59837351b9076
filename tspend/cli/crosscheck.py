"""``tspend crosscheck``: a scenario on its domain's MuJoCo and ODE backends, open and closed loop."""

from __future__ import annotations

import argparse

from tspend.cli.common import (DEFAULT_SCENARIO, EXIT_OK, EXIT_TOLERANCE, Claimed,
    add_metrics_option, add_scenario_options, check_model_size, check_viewer_url, finite, format_value,
    load_with_overrides, plan, printable, recording_request, release_warnings, say,
    scenario_inputs)
from tspend.cli.run import close_sinks, open_sinks
from tspend.runtime.errors import OutputError, ScenarioError
from tspend.runtime.outputs import OutputRequest, display, slug


def add_parser(subparsers) -> argparse.ArgumentParser:
    c = subparsers.add_parser("crosscheck", help="run a scenario on its MuJoCo and its ODE backend")
    c.add_argument("scenario", nargs="?", default=DEFAULT_SCENARIO,
                   help=f"a scenario name (tspend list) or a .toml file with a MuJoCo plant "
                        f"(default: {DEFAULT_SCENARIO})")
    # every sample of both backends: the recorded differences are drawn from them
    add_scenario_options(c, compact=False)
    add_metrics_option(c, "the cross-check figures", old="--json")
    c.add_argument("--tol", type=finite(), default=1e-8,
                   help="open-loop tolerance on the tracked state's max difference (default 1e-8)")
    c.add_argument("--open-loop-duration", type=finite(), default=10.0, metavar="S",
                   help="length of the open-loop comparison (default 10 s)")
    return c


def cmd(args: argparse.Namespace) -> int:
    from tspend.runtime.native_logs import mujoco_warnings_in_errors
    from tspend.runtime.bounds import MAX_STEPS

    scn = load_with_overrides(args)
    from tspend.studies.crosscheck import backends

    _, mj_kind, _ = backends(scn)
    if args.open_loop_duration < scn.run.dt or args.open_loop_duration / scn.run.dt > MAX_STEPS:
        raise ScenarioError(f"--open-loop-duration {args.open_loop_duration:g}: must be from "
                            f"dt ({scn.run.dt:g} s) to {MAX_STEPS:.0e} dt")
    check_viewer_url(args.connect)
    check_model_size(scn, kind=mj_kind)
    plans = plan([recording_request(args, f"{slug(scn.name)}-crosscheck"),
                  OutputRequest("--metrics", "cross-check report", ".json", args.metrics)
                  if args.metrics is not None else None],
                 scenario_inputs(scn) + _mujoco_model(scn))
    with mujoco_warnings_in_errors(True):
        from tspend.studies.crosscheck import crosscheck
        from tspend.loop.simulation import prepare

        prepare(scn, mj_kind)  # the model, checked now
        with args.guard.deferred() as stop, Claimed(plans, scn.run.seed) as outs:
            return _crosscheck(args, scn, stop, outs, crosscheck)


def _mujoco_model(scn) -> list[str]:
    from tspend.cli.common import uses_mujoco
    from tspend.scenario import resolve_model_path

    return [] if uses_mujoco(scn) else [str(resolve_model_path(scn))]


def _crosscheck(args, scn, stop, outs: Claimed, crosscheck) -> int:
    from tspend.loop.runner import RunInterrupted

    recording, json_out = outs["--out"], outs["--metrics"]
    rec, sinks = open_sinks(args, f"{scn.name}-crosscheck",
                            recording.partial if recording else None, prefixes=("mujoco/", "ode/"))
    release_warnings(args)
    from tspend.recorder.crosscheck import crosscheck_sinks, record_verdict

    sinks = crosscheck_sinks(sinks)
    try:
        report = crosscheck(scn, sinks=sinks, open_loop_duration=args.open_loop_duration,
                            stop=stop, tol=args.tol)
        # the verdict goes into the recording before it is closed
        record_verdict(sinks, report)
    except RunInterrupted as exc:
        report, interrupted = None, exc
    else:
        interrupted = None
    finally:
        problem = close_sinks(rec, recording.partial if recording else None)
    failures = [outs.complete(recording, problem)]
    if report is not None:
        for k, v in report.items():
            if not isinstance(v, dict):
                print(f"  {k:<34} {printable(format_value(v))}")
        failures.append(outs.write_json(json_out, report))
    failures = [f for f in failures if f]
    if recording is not None and recording.committed:
        print(f"recording: {printable(display(recording.target))}  "
              f"(open with: rerun {printable(display(recording.target))})")
    if failures:
        raise OutputError("; ".join(failures) + ("; the figures are on stdout" if report else ""))
    if interrupted is not None:
        say(f"cross-check interrupted by {interrupted.signal_name}")
        return interrupted.exit_status
    if stop.signal_name is not None:
        say(f"{stop.signal_name} after the cross-check completed; results kept")
        return stop.exit_status
    if report.get("inconclusive"):
        say(f"cross-check inconclusive: {report['verdict']}")
        return EXIT_TOLERANCE
    if not report["open_loop_ok"]:
        say(f"cross-check failed: {report['verdict']}")
        return EXIT_TOLERANCE
    say(f"cross-check: {report['verdict']}")
    return EXIT_OK
