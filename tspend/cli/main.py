"""The ``tspend`` command: the parser of every subcommand, and the one entry point that runs
a command and turns every outcome into its exit status (:data:`EXIT_STATUSES`).

A command that writes files does its work in this order, so that a rejected command
writes nothing and a failed one replaces nothing: (1) check everything: arguments,
scenario, the plant and controller built, and the output paths against each other and
against every input; (2) claim the outputs (an exclusive partial file beside each, see
:mod:`tspend.runtime.outputs`); (3) print the banner; (4) run; (5) complete the outputs, each
renamed into place only when whole.  Signal handlers are installed before any of it,
before numpy, MuJoCo or Rerun are imported (:mod:`tspend.runtime.interrupts`).

Adding a subcommand: write ``tspend/cli/<name>.py`` with ``add_parser(subparsers)`` (adds
its subparser) and ``cmd(args) -> int``, and add it to :func:`command_modules` (imported
there, after the guard). Keep the module's top-level imports light (stdlib,
``tspend.cli.common``); import the heavy parts inside ``cmd``. What the commands share is in :mod:`tspend.cli.common`.
"""

from __future__ import annotations

import argparse
import os
import sys
import textwrap
import traceback
import warnings

from tspend.runtime.interrupts import Interrupted, SignalGuard


def _run_as_the_program() -> bool:
    """Whether this module is being imported by the ``tspend`` program itself (its console
    script, or ``python -m tspend.cli``), not by tests or a notebook."""
    program = sys.modules.get("__main__")
    spec = getattr(program, "__spec__", None)
    return (getattr(spec, "name", "") == "tspend.cli.__main__"
            or os.path.basename(getattr(program, "__file__", "") or "") == "tspend")


#: the program's guard, installed as soon as the interrupts module is loaded (before the
#: rest of this module's imports: a signal in the first half second of a loaded machine
#: has its status too) and held, recording a signal until :func:`main` takes it over
_EARLY_GUARD = SignalGuard().install(held=True) if _run_as_the_program() else None

from tspend import __version__  # noqa: E402 - after the guard, on purpose
from tspend.cli.common import (EXIT_INTERNAL, Parser, PlainRawDescriptionFormatter,  # noqa: E402
                               ReaderGoneTolerant, release_warnings, say)
from tspend.runtime.errors import TspendError  # noqa: E402
from tspend.shipped import SCENARIO_PATH_VARIABLE  # noqa: E402


def command_modules() -> tuple:
    """The subcommands' modules, in --help order.  Imported here, when the parser is built,
    not with this module: a command module may pull in the runner, the controllers or
    numba, and this module is imported before :func:`main` installs the signal guard,
    which must come first."""
    from tspend.cli import (compare, crosscheck, excite, export, figures, identify, inspect,
                            plan, replay, rig, run, show, sweep, tune)
    from tspend.cli import list as list_command

    return (run, show, crosscheck, list_command, inspect, sweep, export, compare, tune,
            figures, excite, identify, plan, rig, replay)


DESCRIPTION = ("Control experiments on pendulums: run a scenario headless or live, show and "
               "list scenarios, cross-check MuJoCo against the derived equations, compare, "
               "tune and sweep controllers, identify a rig, plan swing-ups. 'tspend COMMAND "
               "--help' explains each command; every option: {cli_md}")

#: the exit statuses, as --help prints them
EXIT_STATUSES = """exit status:
  0    success
  1    crosscheck: the backends differ by more than --tol, or the verdict is inconclusive
  2    bad input (command line, scenario, model file, output path, a size bound); nothing
       is written
  3    the closed loop diverged (recording and metrics kept up to the divergence)
  4    the task ended the run: fell, rail_end, joint_limit, state_bound or not_reached
       (outputs kept up to the end); or refused: the safety filter could not certify
       the start (safety.refuse_unadmitted), nothing applied
  5    an output could not be completed (disk full, I/O error); the file it would have
       replaced is untouched
  6    the controller failed (controller_error); outputs kept up to that sample
  7    sweep, compare: some runs did not complete (controller_error, timeout, failed)
  70   internal error (a bug: please report it with the --debug traceback)
  129, 130, 143: stopped by SIGHUP, SIGINT (Ctrl-C), SIGTERM; outputs completed up to the stop
Every error is one line on stderr, "tspend: error: ...".
"""


def build_parser() -> argparse.ArgumentParser:
    from tspend.cli.common import doc  # where docs/reference/cli.md is, checkout or wheel

    p = Parser(prog="tspend", description=textwrap.fill(
               DESCRIPTION.format(cli_md=doc("docs/reference/cli.md")), 88, break_long_words=False), epilog=EXIT_STATUSES,
               formatter_class=PlainRawDescriptionFormatter)
    p.add_argument("--version", action="version", version=f"tspend {__version__}",
                   help="print tspend's version and exit")
    p.add_argument("--scenario-path", action="append", default=[], metavar="DIR",
                   help=f"a folder of your own scenarios, searched (in the order given, "
                        f"repeatable) before the folders of ${SCENARIO_PATH_VARIABLE}, "
                        f"./scenarios and the shipped ones; 'tspend list' shows the search path")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND",
                           help="one of the commands below ('tspend COMMAND --help')")
    for module in command_modules():
        known = set(sub.choices)
        module.add_parser(sub)
        for added in set(sub.choices) - known:  # whatever names the module registered
            sub.choices[added].set_defaults(handler=module.cmd)
    return p


#: commands that load MuJoCo models outside a run's own handling of MuJoCo's warnings
_MUJOCO_COMMANDS = ("plan", "excite", "identify", "tune", "figures", "compare")


def _native_logs(command: str):
    """For :data:`_MUJOCO_COMMANDS`: MuJoCo's warnings collected into the one-line error,
    never a ``MUJOCO_LOG.TXT`` in the working folder (other commands pay no MuJoCo import)."""
    from contextlib import nullcontext

    from tspend.runtime.native_logs import mujoco_warnings_in_errors

    return mujoco_warnings_in_errors(True) if command in _MUJOCO_COMMANDS else nullcontext()


def _prepend_scenario_path(folders: list[str]) -> None:
    """--scenario-path: put the folders before those of $TSPEND_SCENARIO_PATH, in this
    process and in every worker process it starts (a sweep's pool reads the same path)."""
    if folders:
        rest = os.environ.get(SCENARIO_PATH_VARIABLE, "")
        os.environ[SCENARIO_PATH_VARIABLE] = os.pathsep.join([*folders, *([rest] if rest else [])])


def main(argv: list[str] | None = None) -> int:
    global _EARLY_GUARD
    # first: a signal from here on has its exit status (the program's guard is in place
    # since this module was imported)
    guard, _EARLY_GUARD = _EARLY_GUARD or SignalGuard().install(), None
    real_stdout = sys.stdout
    sys.stdout = ReaderGoneTolerant(real_stdout)
    args: argparse.Namespace | None = None
    saved_path = os.environ.get(SCENARIO_PATH_VARIABLE)
    try:
        guard.arm()  # a signal recorded while the modules loaded ends the command here
        from tspend.runtime.native_logs import quiet_rerun

        quiet_rerun()
        args = build_parser().parse_args(argv)
        args.guard = guard
        _prepend_scenario_path(args.scenario_path)
        from tspend.cli.extras import check_needed

        check_needed(args)  # a missing optional package: one line naming its extra, no work
        # warnings (numpy's overflow on the way to a bad value, say) would add lines to
        # the one-line error: kept, and printed after a command that succeeds
        with warnings.catch_warnings(record=True) as caught, _native_logs(args.command):
            args.warnings = caught
            status = args.handler(args)
        release_warnings(args)
        failure = sys.stdout.failure()
        if failure is not None:  # the command's printed output is lost: 5 wins (reliability.md)
            raise failure
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
            if saved_path is None:
                os.environ.pop(SCENARIO_PATH_VARIABLE, None)
            else:
                os.environ[SCENARIO_PATH_VARIABLE] = saved_path
        else:
            # the program itself: the interpreter's shutdown resets Python handlers to the
            # default action, so a late second signal would kill the process and lose the
            # exit status.  Its work is done: ignore them for the last milliseconds.
            guard.ignore_from_now_on()


if __name__ == "__main__":
    sys.exit(main())
