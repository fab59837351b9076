"""``tspend rig serve``: the simulated rig; and the ``--rig`` options of ``tspend run``.

docs/rig.md describes the protocol, the double and the runner.
"""

from __future__ import annotations

import argparse
import sys
from contextlib import contextmanager
from pathlib import Path

from tspend.cli.common import (EXIT_OK, add_scenario_options, bounded_int, doc, finite,
                               load_with_overrides, printable, say)



def add_parser(subparsers) -> argparse.ArgumentParser:
    from tspend.cli.common import PlainRawDescriptionFormatter

    r = subparsers.add_parser("rig", help="serve a simulated rig (the test double of a real one)")
    sub = r.add_subparsers(dest="rig_command", required=True, metavar="ACTION",
                           help="serve: a simulated rig ('tspend rig serve --help')")
    s = sub.add_parser("serve", help="the scenario's machine as a rig on a UDP port or serial line",
                       description="The scenario's MuJoCo machine, paced to the wall clock, "
                                   f"speaking tspend's rig protocol (see {doc('docs/rig.md')}) with an "
                                   "encoder, latency, jitter, lost and corrupt frames, an "
                                   "amplifier limit and a watchdog.",
                       formatter_class=PlainRawDescriptionFormatter)
    s.add_argument("scenario", help="scenario name (see 'tspend list') or path to a .toml file")
    add_scenario_options(s, recording=False)
    s.add_argument("--listen", required=True, metavar="URL",
                   help="udp://HOST:PORT (e.g. udp://127.0.0.1:9500) or "
                        "serial:///dev/DEVICE?baud=N")
    s.add_argument("--counts-per-unit", type=finite(), nargs="+", metavar="N",
                   help="the encoders' counts per metre (slide) or per radian (hinge), one per "
                        "joint in the model's order (default: 100000 per metre, 20000 per "
                        "revolution)")
    s.add_argument("--min-period-ms", type=finite(0.1, 1000.0), default=2.0, metavar="MS",
                   help="the shortest control period the rig accepts (default 2: 500 Hz); "
                        "a whole multiple of the scenario's dt")
    s.add_argument("--max-period-ms", type=finite(0.1, 1000.0), default=20.0, metavar="MS",
                   help="the longest control period the rig accepts (default 20; the host "
                        "needs the watchdog to outlast two periods)")
    s.add_argument("--watchdog-ms", type=finite(0.1, 10_000.0), default=50.0, metavar="MS",
                   help="the motor command goes to zero when no valid command came for this "
                        "long (default 50)")
    s.add_argument("--amp-limit", type=finite(), metavar="U",
                   help="the amplifier's limit on |u| (default: the machine's input range)")
    s.add_argument("--no-query", action="store_true",
                   help="answer no query before the start, as a rig whose firmware reads its "
                        "sensors only once started (the host then checks its start at the "
                        "first cycle; e.g. --no-query)")
    _add_fault_options(s)
    s.add_argument("--log", metavar="PATH.npz",
                   help="write the double's true state, commands, frames and events (one file "
                        "per session: PATH.npz, then PATH-2.npz ...); never replaces a file")
    s.add_argument("--sessions", type=bounded_int(1, 1000), default=1, metavar="N",
                   help="serve this many runs, then exit (default 1)")
    s.add_argument("--wait-s", type=finite(0.1, 86_400.0), default=600.0, metavar="S",
                   help="how long to wait for a host's start (default 600: a first run "
                        "compiles its controller between the hello and the start)")
    s.add_argument("--max-session-s", type=finite(0.1, 86_400.0), default=600.0, metavar="S",
                   help="the longest session (default 600)")
    s.set_defaults(handler=cmd)
    return r


def _add_fault_options(s: argparse.ArgumentParser) -> None:
    """``rig serve``'s faults: what the double does to the frames and its clock."""
    for name, what in (("drop", "share of sensor frames dropped"),
                       ("corrupt", "share of frames with one bit flipped (sensor frames sent, "
                                   "commands received)")):
        s.add_argument(f"--{name}", type=finite(0.0, 0.5, strict=False), default=0.0,
                       metavar="P", help=f"{what}, 0 to 0.5 (default 0)")
    for name, what in (("sensor-latency-ms", "added to every sensor frame"),
                       ("command-latency-ms", "before a received command acts"),
                       ("jitter-ms", "uniform extra latency, 0 to this, on each frame")):
        s.add_argument(f"--{name}", type=finite(0.0, 1000.0, strict=False), default=0.0,
                       metavar="MS", help=f"latency {what} (ms, default 0)")
    s.add_argument("--clock-ppm", type=finite(-2000.0, 2000.0, strict=False), default=0.0,
                   metavar="PPM",
                   help="the rig's clock error against the host's, parts per million, "
                        "-2000 to 2000 (positive: it runs fast; default 0); a crystal is "
                        "typically within 50 (e.g. --clock-ppm 300: 0.3 ms gained per second)")
    s.add_argument("--fault-seed", type=bounded_int(0, 2**32 - 1), default=0, metavar="N",
                   help="seed of the drawn faults (default 0)")


def add_rig_options(p: argparse.ArgumentParser) -> None:
    """``tspend run``'s options for a rig."""
    p.add_argument("--rig", metavar="URL",
                   help="close the loop on a rig instead of a simulation: udp://HOST:PORT, "
                        "serial:///dev/ttyUSB0?baud=230400, or your own interface "
                        "path/to/file.py:MyRig (a tspend.rig.links.RigLink); the period is the "
                        "scenario's control period (run.control_period, else run.dt), raised "
                        f"to the shortest the rig accepts (see {doc('docs/rig.md')})")
    p.add_argument("--miss-policy", choices=("hold", "zero", "stop"), default="hold",
                   help="with --rig, a command ready after its period ended: 'hold' sends the "
                        "previous command, 'zero' sends 0, 'stop' ends the run (default hold)")
    p.add_argument("--velocity-tau-ms", type=finite(0.0, 1000.0, strict=False), default=5.0,
                   metavar="MS",
                   help="with --rig or --estimator, the low-pass time constant of the velocity "
                        "estimate from the positions (default 5; 0: the bare backward "
                        "difference)")
    p.add_argument("--twin", action="store_true",
                   help="with --rig, after the run: simulate its twin (the same scenario and "
                        "controller on the model machine, from the rig's first measured "
                        "state, through the same encoders and velocity estimator), draw it "
                        "over the rig's trajectories in the same recording (under twin/) and "
                        "put the gap, twin - rig per state and for u, into the metrics "
                        "(twin_gap)")
    p.add_argument("--estimator", choices=("lowpass",),
                   help="without --rig: feed the simulated controller what a rig's sensors "
                        "give, so a simulation and a rig run compare on equal terms: the "
                        "loop samples at the control period, positions are rounded to whole "
                        "encoder counts (--counts-per-unit) and velocities come from the rig "
                        "runner's estimator, 'lowpass' (the backward difference through a "
                        "first-order low-pass, --velocity-tau-ms); the recorded state is the "
                        "sensed one, as on a rig (e.g. --estimator lowpass)")
    p.add_argument("--counts-per-unit", type=finite(), nargs="+", metavar="N",
                   help="with --estimator, the encoders' counts per metre (slide) or per "
                        "radian (hinge), one per joint in the model's order (default: the "
                        "simulated rig's, 100000 per metre, 20000 per revolution)")


class RigRun:
    """An open rig session for ``tspend run``: the scenario at the rig's period and the
    ``run`` callable the command hands its sinks to."""

    def __init__(self, args, session, scenario) -> None:
        self.args, self.session, self.scenario = args, session, scenario

    def run(self, scn, sinks=(), keep_history=False, stop=None, controller=None, prepared=None):
        from tspend.rig import protocol
        from tspend.rig.closed_loop import run_on_rig
        from tspend.rig.estimator import VelocityEstimator
        from tspend.rig.runner import RigPlant, session_settings
        from tspend.scenario.writer import dump_toml, resolved_document

        estimator = VelocityEstimator(self.args.velocity_tau_ms * 1e-3)
        settings = session_settings(self.session, scn.run.duration, self.args.miss_policy,
                                    estimator)
        plant = RigPlant(prepared.plant, self.session.link, self.session.hello, settings)
        rec = next((s.rec for s in sinks if getattr(s, "rec", None) is not None), None)
        hello = self.session.hello
        notes = {"scenario_toml": dump_toml(resolved_document(prepared.scenario)),
                 "controller": controller, "rig": self.args.rig,
                 "counts_per_unit": list(hello.counts_per_unit),
                 "timing_notes": {"link": self.args.rig, "machine": hello.machine,
                                  "velocity_estimator": estimator.describe(),
                                  "velocity_tau_s": estimator.tau_s}}
        from tspend.rig.twin import TWIN_PREFIX

        twin_sinks = [s for s in sinks if getattr(s, "prefix", "") == TWIN_PREFIX.strip("/")]
        rig_sinks = [s for s in sinks if s not in twin_sinks]
        try:
            result = run_on_rig(prepared, self.session, plant, rig_sinks, stop, rec, notes)
        except BaseException as exc:
            # before or after the loop (its own end sets the reason): a signal, else an error
            signalled = isinstance(exc, KeyboardInterrupt) or getattr(stop, "signal_name", None)
            self.session.stop_reason = protocol.STOP_SIGNAL if signalled else protocol.STOP_ERROR
            raise
        finally:
            self.session.close()  # the stop frame at once, before the outputs are completed
        drift = plant.clock.warning() if plant.clock is not None else ""
        if drift:
            print(f"rig: {drift}", flush=True)
        if self.args.twin:
            from tspend.rig.twin import twin_of_run

            print("twin: simulating the run's twin (the model machine, the same sensors)",
                  flush=True)
            result.end.metrics["twin_gap"] = twin_of_run(
                prepared, result.history, hello.counts_per_unit, estimator.tau_s, controller,
                twin_sinks)[0]
        return result


def twin_prefixes(args) -> tuple[str, ...]:
    """The recording's run prefixes: the rig run's own, and with ``--twin`` its twin's."""
    if not getattr(args, "twin", False):
        return ("",)
    from tspend.rig.twin import TWIN_PREFIX

    return ("", TWIN_PREFIX)


def sensed_scenario(args, scn):
    """With ``--estimator``: the scenario sampled at its control period, as a rig run
    samples it; else unchanged.  Called only without ``--rig``."""
    from tspend.runtime.errors import ScenarioError

    if getattr(args, "twin", False):
        raise ScenarioError("--twin: only with --rig (the twin of a rig run)")
    if getattr(args, "estimator", None) is None:
        if getattr(args, "counts_per_unit", None) is not None:
            raise ScenarioError("--counts-per-unit: only with --estimator (a rig states its "
                                "encoders in its hello)")
        return scn
    from tspend.rig.runner import rig_scenario

    return rig_scenario(scn, scn.run.control_period or scn.run.dt)


def encoder_counts(args, joints) -> tuple[float, ...]:
    """``--counts-per-unit``, one per joint, or the simulated rig's default encoders."""
    from tspend.runtime.errors import ScenarioError
    from tspend.rig.estimator import default_counts_per_unit

    counts = args.counts_per_unit or default_counts_per_unit(joints)
    if len(counts) != len(joints):
        raise ScenarioError(f"--counts-per-unit: {len(counts)} given, the machine has "
                            f"{len(joints)} joints ({', '.join(j.name for j in joints)})")
    return tuple(counts)


def sensed_plant(args, prepared):
    """With ``--estimator`` (no ``--rig``): ``prepared`` with its plant seen through a rig's
    encoders and velocity estimator (:class:`tspend.rig.estimator.SensedPlant`)."""
    if getattr(args, "estimator", None) is None or args.rig is not None:
        return prepared
    from dataclasses import replace

    from tspend.runtime.errors import ScenarioError
    from tspend.rig.estimator import SensedPlant, VelocityEstimator

    joints = prepared.plant.joints
    if not joints:
        raise ScenarioError(f"--estimator: the plant ({prepared.scenario.plant.kind}) has no "
                            f"joints to read encoders from")
    counts = encoder_counts(args, joints)
    estimator = VelocityEstimator(args.velocity_tau_ms * 1e-3)
    print(f"sensors: encoders of {', '.join(f'{c:g}' for c in counts)} counts per unit; "
          f"velocities: {estimator.describe()}", flush=True)
    return replace(prepared, plant=SensedPlant(prepared.plant, tuple(counts), estimator))


@contextmanager
def rig_for_run(args, scn):
    """With ``--rig``: the link opened and checked (one line and exit 2 when refused, before
    any motion), a :class:`RigRun`; the stop frame on every way out.  None without."""
    if getattr(args, "rig", None) is None:
        yield None
        return
    from tspend.loop.simulation import build_plant
    from tspend.rig.links import parse_rig
    from tspend.rig.runner import model_not_stepped, open_session, rig_scenario

    link = parse_rig(args.rig)
    requested = scn.run.control_period or scn.run.dt
    session = open_session(link, build_plant(scn), requested)
    try:
        if session.period_s != requested:
            print(f"rig: it accepts periods from {session.hello.min_period_s * 1e3:g} ms; "
                  f"running at {session.period_s * 1e3:g} ms ({1 / session.period_s:g} Hz)",
                  flush=True)
        with model_not_stepped():
            yield RigRun(args, session, rig_scenario(scn, session.period_s))
    finally:
        session.close()


def _log_path(base: str | None, session: int) -> Path | None:
    if base is None:
        return None
    path = Path(base)
    return path if session == 1 else path.with_name(f"{path.stem}-{session}{path.suffix}")


def _listen(url: str):
    """The double's transport for ``--listen``."""
    import urllib.parse

    from tspend.runtime.errors import ScenarioError
    from tspend.rig.double import SerialServer, UdpServer
    from tspend.rig.links import BAUD_RANGE

    parts = urllib.parse.urlsplit(url)
    try:
        if parts.scheme == "udp" and parts.hostname and parts.port:
            return UdpServer(parts.hostname, parts.port)
        if parts.scheme == "serial" and parts.path:
            baud = int(urllib.parse.parse_qs(parts.query).get("baud", ["115200"])[0])
            if not BAUD_RANGE[0] <= baud <= BAUD_RANGE[1]:
                raise ValueError(f"baud {baud} outside {BAUD_RANGE[0]}-{BAUD_RANGE[1]}")
            return SerialServer(parts.path, baud)
    except (OSError, ValueError, ImportError) as exc:
        raise ScenarioError(f"--listen {url}: {exc}") from None
    raise ScenarioError(f"--listen {url}: expected udp://HOST:PORT or serial:///dev/DEVICE?baud=N")


def build_double(args: argparse.Namespace, scn):
    """The simulated rig the options describe (checked before it listens)."""
    import numpy as np

    from tspend.runtime.errors import ScenarioError
    from tspend.loop.simulation import build_plant
    from tspend.rig.double import Faults, SimulatedRig, u_limit_of
    from tspend.rig.protocol import ANSWERS_QUERY, MAX_JOINTS, Hello
    from tspend.rig.runner import machine_id

    plant = build_plant(scn)
    # one step now, so nothing is compiled or first touched between a host's START and
    # the first sensor frame (the host waits a bounded time for it)
    plant.reset(np.asarray(scn.plant.x0, dtype=float))
    plant.full_state()
    plant.step(0.0, 0.0, scn.run.dt)
    joints = plant.joints
    if not 0 < len(joints) <= MAX_JOINTS:
        raise ScenarioError(f"{scn.name}: a rig carries 1 to {MAX_JOINTS} joints; this machine "
                            f"has {len(joints)}")
    counts = encoder_counts(args, joints)
    dt = scn.run.dt
    for option in ("min_period_ms", "max_period_ms"):
        period = getattr(args, option) * 1e-3
        if abs(round(period / dt) * dt - period) > 1e-9 or period < dt:
            raise ScenarioError(f"--{option.replace('_', '-')} {period * 1e3:g}: not a whole "
                                f"multiple of the scenario's dt {dt * 1e3:g} ms")
    if args.max_period_ms < args.min_period_ms:
        raise ScenarioError("--max-period-ms is shorter than --min-period-ms")
    if args.log and not args.log.endswith(".npz"):
        raise ScenarioError(f"--log {printable(args.log)}: expected a .npz path")
    hello = Hello(machine_id(plant), tuple(float(c) for c in counts), args.min_period_ms * 1e-3,
                  args.max_period_ms * 1e-3, args.watchdog_ms * 1e-3,
                  args.amp_limit if args.amp_limit is not None else u_limit_of(plant, scn),
                  0 if args.no_query else ANSWERS_QUERY)
    faults = Faults(args.drop, args.corrupt, args.sensor_latency_ms * 1e-3,
                    args.command_latency_ms * 1e-3, args.jitter_ms * 1e-3, args.clock_ppm)
    joint_index = np.array([plant.state_names.index(j.name) for j in joints])
    return SimulatedRig(plant, scn, hello, faults, _listen(args.listen),
                        np.random.default_rng(args.fault_seed), joint_index)


def cmd(args: argparse.Namespace) -> int:
    import numpy as np

    scn = load_with_overrides(args)
    logs = [_log_path(args.log, i + 1) for i in range(args.sessions)] if args.log else []
    for path in logs:
        if path.exists():
            from tspend.runtime.errors import OutputError

            raise OutputError(f"--log {printable(path)}: exists; the double never replaces a file")
    double = build_double(args, scn)
    from tspend.rig.double import TruthLog
    from tspend.rig.realtime import real_time

    hello = double.hello
    print(f"rig serve: {printable(scn.name)} as '{hello.machine}' on {printable(args.listen)}, "
          f"periods {hello.min_period_s * 1e3:g}-{hello.max_period_s * 1e3:g} ms, watchdog "
          f"{hello.watchdog_s * 1e3:g} ms, |u| <= {hello.u_limit:g}", flush=True)
    import time

    try:
        for number in range(1, args.sessions + 1):
            log = TruthLog(double.plant.state_names)
            period = double.wait_for_start(time.monotonic() + args.wait_s, log)
            if period is None:
                say(f"rig serve: no host started a session within {args.wait_s:g} s")
                return 2
            if isinstance(period, str):
                print(f"session {number}: {period}; nothing moved", flush=True)
                continue
            print(f"session {number}: period {period * 1e3:g} ms", flush=True)
            with real_time() as granted:
                reason = double.session(period, args.max_session_s, log)
            for line in granted.notes:
                print(f"real time: {line}", flush=True)
            arrays = log.arrays()
            trips = int(np.sum(arrays["event"] == "watchdog"))
            print(f"session {number}: ended ({reason}) after {len(arrays['t'])} steps; "
                  f"watchdog trips {trips}", flush=True)
            if logs:
                log.save(logs[number - 1])
                print(f"log: {printable(logs[number - 1])}", flush=True)
            sys.stdout.flush()
    finally:
        double.transport.close()
    return EXIT_OK
