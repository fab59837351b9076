"""``tspend replay RUN.rrd``: a rig run's recorded sensor stream through the same controller,
offline; every recorded command reproduced exactly, or the first that differs named."""

from __future__ import annotations

import argparse

from tspend.cli.common import EXIT_OK, printable


def add_parser(subparsers) -> argparse.ArgumentParser:
    from tspend.cli.common import PlainRawDescriptionFormatter

    r = subparsers.add_parser(
        "replay", help="replay a rig run's sensor stream through its controller, offline",
        description="Feeds the sensor frames a rig run recorded (tspend run --rig ... --out "
                    "RUN.rrd) through the velocity estimator and the same controller, built "
                    "from the scenario the recording holds, and compares every command with "
                    "the recorded one, bit for bit. Exit 0: all equal; 1: one differs.",
        formatter_class=PlainRawDescriptionFormatter)
    r.add_argument("recording", metavar="RUN.rrd", help="a recording of tspend run --rig")
    r.add_argument("--twin", metavar="OUT.rrd",
                   help="also simulate the run's twin (same scenario, controller, encoders "
                        "and velocity estimator on the model machine, from x0 where the rig's "
                        "first frame reads as x0, else from that frame), write both "
                        "trajectories to OUT.rrd and print the gap, twin - rig per state and "
                        "for u (never replaces a file; tspend run --rig URL --twin puts the "
                        "twin into the run's own recording instead)")
    r.add_argument("--debug", action="store_true", help="show tracebacks")
    return r


def cmd(args: argparse.Namespace) -> int:
    from tspend.rig.replay import replay

    if args.twin is not None:
        from pathlib import Path

        from tspend.runtime.errors import OutputError

        if Path(args.twin).exists():
            raise OutputError(f"--twin {printable(args.twin)}: exists; nothing is overwritten")
    result = replay(args.recording)
    print(f"replay: {result.cycles} cycles of {printable(args.recording)}: "
          f"{result.equal} commands equal bit for bit, {result.cycles - result.equal} differ"
          + (f" (first at cycle {result.first_difference}: recorded {result.recorded!r}, "
             f"replayed {result.replayed!r})" if result.first_difference is not None else ""))
    if args.twin is not None:
        import json

        from tspend.rig.replay import twin

        gap = twin(args.recording, args.twin)
        print(f"twin: {printable(args.twin)} (sim_vs_rig/...); gap, twin - rig:")
        print(json.dumps(gap, indent=2))
    return EXIT_OK if result.equal == result.cycles else 1
