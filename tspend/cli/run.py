"""``tspend run``: one scenario's closed loop, recorded to ``.rrd``, metrics printed."""

from __future__ import annotations

import argparse
import json
import re

from tspend import __version__
from tspend.cli.common import (DEFAULT_SCENARIO, EXIT_CONTROLLER_ERROR, EXIT_DIVERGED, EXIT_OK,
    EXIT_TERMINATED, Claimed,
    add_scenario_options, check_model_size, check_viewer_url, controller_help, doc, load_with_overrides,
    metrics_document, plan, printable, recording_request, release_warnings, say,
    reads_mjcf, scenario_inputs)
from tspend.runtime.errors import OutputError, ScenarioError
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
    r.add_argument("--safety", metavar="FILTER",
                   help="run the controller behind a safety filter: 'cbf', a control barrier "
                        "function QP keeping the task's constraints; 'mpsc', predictive "
                        "safety certification: the input passes only when a backup plan "
                        "keeps every constraint and the fall angle and ends in the "
                        "balancing LQR's safe set; 'off' (the default) none (same as "
                        f"--set safety.filter=FILTER; {doc('docs/safety.md')}; e.g. --safety cbf)")
    from tspend.cli.rig import add_rig_options

    add_rig_options(r)
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
                       curves_every=args.record_every,
                       diagnostics_hz=getattr(args, "diagnostics_hz", 0.0))
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
    if args.safety is not None:
        args.set = [*args.set, f"safety.filter={args.safety}"]
    scn = load_with_overrides(args)
    check_viewer_url(args.connect)
    check_model_size(scn)
    stem = f"{slug(scn.name)}"
    plans = plan([recording_request(args, stem),
                  OutputRequest("--metrics", "metrics", ".json", args.metrics)
                  if args.metrics is not None else None],
                 scenario_inputs(scn))
    from tspend.cli.rig import rig_for_run, sensed_plant, sensed_scenario

    # --rig: the link checked (refused in one line) before anything is written or moves
    with mujoco_warnings_in_errors(reads_mjcf(scn)), rig_for_run(args, scn) as rig:
        from tspend.loop.simulation import prepare, run
        from tspend.runtime.progress import SlowStep

        scn = rig.scenario if rig is not None else sensed_scenario(args, scn)
        with SlowStep(PREPARE_STEP, PREPARE_ESTIMATE, after=PREPARE_NOTICE_S):
            prepared = sensed_plant(args, prepare(scn, controller=args.controller))
        with args.guard.deferred() as stop, Claimed(plans, scn.run.seed) as outs:
            return _run(args, scn, prepared, stop, outs, rig.run if rig is not None else run)


def _run(args, scn, prepared, stop, outs: Claimed, run) -> int:
    from tspend.runtime.progress import RunProgress  # a bar on a terminal once the run takes a few seconds
    from tspend.loop.runner import CONTROLLER_ERROR, NOT_REACHED, REFUSED, RunInterrupted
    from tspend.task import TERMINATIONS

    from tspend.cli.rig import twin_prefixes

    recording, metrics_out = outs["--out"], outs["--metrics"]
    rec, sinks = open_sinks(args, scn.name, recording.partial if recording else None,
                            twin_prefixes(args))
    release_warnings(args)
    print(f"tspend {__version__}: {printable(scn.name)} ({scn.plant.kind}), "
          f"{scn.run.duration:g} s at dt = {scn.run.dt:g} s, seed {scn.run.seed}"
          + (f", recording to {printable(display(recording.target))}" if recording else ""),
          flush=True)
    interrupted = None
    notice = CompileNotice()
    try:
        end = run(scn, sinks=[notice, *sinks, RunProgress()], keep_history=False, stop=stop,
                  controller=args.controller, prepared=prepared).end
    except RunInterrupted as exc:
        interrupted, end = exc, exc.end
    finally:
        notice.cancel()
        problem = close_sinks(rec, recording.partial if recording else None)
    failures = [outs.complete(recording, problem)]
    if end is not None:
        failures.append(outs.write_json(metrics_out, metrics_document(
            prepared.scenario, end, prepared.controller, args.controller, json_units(prepared))))
    failures = [f for f in failures if f]

    if end is not None:
        print(f"{end.status}: {end.steps_done} steps" + (f" ({printable(end.message)})"
                                                          if end.message else ""))
        print_summary(end.metrics, summary_units(prepared), notes=unregulated_note(prepared))
    if recording is not None and recording.committed:
        print(f"recording: {printable(display(recording.target))}  "
              f"(open with: rerun {printable(display(recording.target))})")
    if failures:
        if end is not None:  # the figures of a finished run are never lost
            print(json.dumps(metrics_document(prepared.scenario, end, prepared.controller,
                                              args.controller, json_units(prepared)), indent=2))
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
    # the task's goal (task.goal_angle by task.goal_by) missed, or a safety filter refused
    # to start (safety.refuse_unadmitted): ended by the task's rules, as a termination is
    if end.status in (NOT_REACHED, REFUSED):
        say(end.message)
        return EXIT_TERMINATED
    if end.status == CONTROLLER_ERROR:  # the controller's code failed, not tspend's
        say(end.message)
        return EXIT_CONTROLLER_ERROR
    return EXIT_OK


# -- the printed summary -----------------------------------------------------------------
#: a saturation line is printed when the actuator clipped more than this share of samples
SATURATION_SHARE = 0.01
#: the design before a run (a derivation, a safety filter's plans compiled to C): said
#: once it has taken this long, with what it is and about how long it takes
PREPARE_NOTICE_S = 5.0
PREPARE_STEP = "preparing the plant and the controller"
#: a cold cache's --safety mpsc design: 12 s of CPU measured (TSPEND_CACHE_DIR empty)
PREPARE_ESTIMATE = ("the first time only, then cached; about 15 s for --safety mpsc, whose "
                    "plans compile to C")
#: seconds without a first block before the compile notice
COMPILE_NOTICE_S = 2.0
#: the first run's compile, as benchmarks/install_footprint.py measures it (README.md)
COMPILE_ESTIMATE = "the first run only, then cached; about 25 s on 2 idle cores, longer on a busy machine"


class CompileNotice:
    """A sink that says that the closed loop is being compiled when the first block has not
    come within :data:`COMPILE_NOTICE_S` (numba's first compile; later runs load it from
    the cache), with an estimate, and how long it took, so the first run is not silent."""

    def __init__(self) -> None:
        from tspend.runtime.progress import SlowStep

        self._step = SlowStep("compiling the controller and the closed loop with numba",
                              COMPILE_ESTIMATE, after=COMPILE_NOTICE_S).begin()

    def cancel(self) -> None:
        self._step.end()

    def start(self, info) -> None:
        pass

    def block(self, block) -> None:
        self._step.end()

    def inner(self, snap) -> None:
        pass

    def finish(self, end) -> None:
        self._step.end()


def summary_units(prepared) -> dict[str, str]:
    """Units of the printed figures: ``e`` (the tracked output), ``u`` and each state."""
    from tspend.plants import registry

    plant, scn = prepared.plant, prepared.scenario
    units = dict(zip(plant.state_names, plant.state_units))
    view = prepared.task.view if prepared.task is not None else plant.state_names
    control = ((plant.inputs[0].unit if plant.inputs else "")
               or registry.domain_of(scn.plant.kind).labels.control.unit)
    return {"e": units.get(view[0], "") if view else "", "u": control, "states": units}


def json_units(prepared) -> dict:
    """The metrics JSON's ``units``: the tracked output's (``e``: rmse, max_abs_e ...), the
    input's (``u``) and each joint's, by the model's joint names."""
    units = summary_units(prepared)
    states = units.pop("states")
    joints = {j.name: states.get(j.name, "") for j in getattr(prepared.plant, "joints", ())}
    return {**units, "joints": joints} if joints else units


def _with(value, unit: str) -> str:
    from tspend.cli.common import format_value

    text = format_value(value)
    return f"{text} {unit}" if unit and isinstance(value, (int, float)) else text



#: the kinds that control the task's view only (the paper's): a joint outside it is free
VIEW_ONLY_KINDS = ("second_type", "first_type")


def unregulated_note(prepared) -> str:
    """For the paper's controllers: which joints they leave free and how to keep them, said
    under "largest |joint|" (the default run's cart travels tens of metres; issue 51)."""
    kind = getattr(prepared.controller, "kind", "")
    view = tuple(prepared.task.view) if prepared.task is not None else ()
    joints = [j for j in getattr(prepared.plant, "joints", ()) if j.name not in view]
    if kind not in VIEW_ONLY_KINDS or not view or not joints:
        return ""
    free = ", ".join(j.name for j in joints)
    rail = (", --set effects.rail=2 ends the run at a rail of +/-2 m"
            if any(j.kind == "slide" for j in joints) else "")
    return (f"{free} not regulated: {kind}, the paper's controller, regulates {view[0]} "
            f"only; --controller lqr regulates the whole state{rail}")


def print_summary(metrics: dict, units: dict[str, str], stream=None, notes: str = "") -> None:
    """The metrics a person reads: every figure with its unit, each joint's largest
    excursion (with ``notes``: what the controller leaves free), the actuator's saturation
    when it clipped more than :data:`SATURATION_SHARE` of the samples, and the task's
    events (goal, catch)."""
    import sys

    stream = stream or sys.stdout
    e, u = units.get("e", ""), units.get("u", "")
    e2 = f"{e}^2" if e else ""
    rows = [
        ("rmse", e, ""), ("rmse_ss", e, "steady state"), ("max_abs_e", e, ""),
        ("max_abs_e_ss", e, "steady state"), ("iae", f"{e} s".strip(), ""),
        ("ise", f"{e2} s".strip(), ""), ("itae", f"{e} s^2".strip(), ""),
        ("control_energy", f"{u}^2 s" if u else "s", "integral of the applied u^2"),
        ("control_energy_command", f"{u}^2 s" if u else "s", "integral of the commanded u^2"),
        ("max_abs_u", u, "applied, after the actuator's clip"
         if "max_abs_u_command" in metrics else ""),
        ("max_abs_u_command", u, "what the controller asked"),
        ("tv_u_per_s", f"{u}/s" if u else "1/s", "total variation of the command per second"),
        ("caught_at_s", "s", "the swing-up caught the pole"),
        ("sim_s", "s", ""), ("steps", "", ""), ("wall_s", "s", "")]
    shown = [(k, unit, note) for k, unit, note in rows if k in metrics]
    width = max([len(k) for k, _, _ in shown] + [len("joint excursions")])
    for key, unit, note in shown:
        print(f"  {key:<{width}}  {_with(metrics[key], unit)}" + (f"  ({note})" if note else ""),
              file=stream)
    act = metrics.get("actuator") or {}
    if act.get("force_unit") and act.get("max_abs_force") is not None:
        # u is the actuator's control (a geared motor's, a voltage): the force it applied
        force = act["force_unit"]
        print(f"  {'actuator force':<{width}}  up to {_with(act['max_abs_force'], force)} applied "
              f"({_with(act['force_per_u'], force)} per {u or 'unit'} of u at rest)", file=stream)
    joints = metrics.get("joints") or {}
    states = units.get("states", {})
    if joints:
        parts = [f"{name} {_with(j.get('max_abs'), states.get(name, ''))}"
                 for name, j in joints.items() if isinstance(j, dict)]
        print(f"  {'largest |joint|':<{width}}  {', '.join(parts)}", file=stream)
        if notes:
            print(f"  {'':<{width}}  ({notes})", file=stream)
    goal = metrics.get("goal")
    if isinstance(goal, dict):
        reached = goal.get("reached_at_s")
        angle, by = goal.get("angle_rad"), goal.get("by_s")
        target = (f"within {_with(angle, 'rad')}" if angle is not None else "the goal") + \
            (f" by {_with(by, 's')}" if by is not None else "")
        if goal.get("met") is None and "met" in goal:
            text = f"not judged: the run ended before {_with(by, 's')} ({target})"
        elif reached is not None:
            text = f"reached {target} at {_with(reached, 's')}" + (
                "" if goal.get("met", True) else " (too late)")
        else:
            text = f"not reached ({target})"
        print(f"  {'goal':<{width}}  {text}", file=stream)
    constraints = metrics.get("constraints") or {}
    if constraints:
        parts = [f"{name} {c['samples_outside']} (deepest {_with(c['max_depth'], c['unit'])})"
                 if c.get("samples_outside") else f"{name} 0"
                 for name, c in constraints.items() if isinstance(c, dict)]
        print(f"  {'violations':<{width}}  samples outside: {', '.join(parts)}", file=stream)
    safety = metrics.get("safety_filter")
    if isinstance(safety, dict) and safety.get("samples"):
        print(f"  {'safety filter':<{width}}  {safety['filter']} ({safety['solver']}): changed u "
              f"in {100 * safety['intervention_share']:.1f} % of {safety['samples']} samples, "
              f"mean |du| {_with(safety['mean_abs_du'], u)}, QP "
              f"{_with((safety.get('qp_ms') or {}).get('median'), 'ms')} median"
              + (f"; {safety['fallbacks']} samples on the last certified plan (no new plan "
                 f"passed), {safety['no_plan']} on an uncertified recovery plan, "
                 f"{safety['infeasible_samples']} plan QPs that failed (docs/safety.md)"
                 if "fallbacks" in safety else ""), file=stream)
    share = metrics.get("saturated_fraction")
    if isinstance(share, (int, float)) and share > SATURATION_SHARE:
        limit = metrics.get("u_limit") or (metrics.get("plant") or {}).get("ctrl_max")
        print(f"  saturation: the actuator clipped u in {100 * share:.1f} % of the samples "
              f"(more than {100 * SATURATION_SHARE:g} %)"
              + (f"; its limit is +/-{_with(limit, u)}" if isinstance(limit, (int, float)) else "")
              + (f"; the controller asked up to {_with(metrics['max_abs_u_command'], u)}"
                 if "max_abs_u_command" in metrics else ""), file=stream)
