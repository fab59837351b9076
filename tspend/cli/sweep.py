"""``tspend sweep``: many runs of one or more scenarios, one row each in a Parquet table.

The cartesian product of ``--grid`` values, ``--seeds`` and ``--controller`` kinds runs
on a local pool of worker processes (``--jobs``) or a Dask cluster (``--dask``).  Rows
are written as runs finish; the same command after a kill runs only what is missing.
A diverged or failed run is a row (and, by default, a recording), never the end of the
sweep.  The Python API is :func:`tspend.sweep.sweep`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tspend.runtime.errors import ScenarioError


def add_parser(sub) -> None:
    from tspend.cli.common import doc

    p = sub.add_parser("sweep", help="run a grid of scenario values x seeds x controllers, "
                                     "one table row per run",
                       description="Run the product of --grid values, --seeds and --controller "
                                   "kinds, one row per run in a Parquet table (--out); the "
                                   "same command after a kill runs only what is missing.")
    p.add_argument("scenario", nargs="+", help="scenario name(s) or .toml path(s)")
    p.add_argument("--grid", action="append", default=[], metavar="KEY=V1,V2,...",
                   help="sweep a scenario key over values (TOML, as for --set; repeatable: the "
                        "product of all grids), e.g. --grid controller.eta=0.001,0.01")
    p.add_argument("--seeds", metavar="A:B",
                   help="seeds A to B-1 (e.g. 0:20), or N, or N1,N2,... (default: the "
                        "scenario's seed)")
    p.add_argument("--controller", metavar="K1,K2,...",
                   help="controller kinds to run (default: the scenario's own), or "
                        "path/to/file.py:Class, package.module:Class; "
                        "'--controller help' lists them")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a key for every run, e.g. --set run.duration=10 (repeatable)")
    p.add_argument("--duration", type=float, metavar="S", help="override run.duration")
    p.add_argument("--out", metavar="PATH.parquet",
                   help="the table: rows are added as runs finish and rows already there are "
                        "not run again (default: print the summary only)")
    p.add_argument("--jobs", type=int, metavar="N",
                   help="worker processes (default: one per core)")
    p.add_argument("--dask", metavar="ADDRESS",
                   help="run on the Dask scheduler at ADDRESS, or 'local' for a LocalCluster "
                        "(needs pip install 'tspend[dask]')")
    p.add_argument("--wait", action="store_true",
                   help="when another sweep is writing the --out table, wait for it to end "
                        "(default: refuse, exit 2)")
    p.add_argument("--record", choices=("failed", "all", "none"), default="failed",
                   help="keep a Rerun recording of the runs that diverged or failed (default), "
                        "of all runs, or of none; the path is in the row")
    p.add_argument("--backend", choices=("cpu", "mjx"), default="cpu",
                   help="cpu: one process per run (default); mjx: every seed of a scenario "
                        "and controller stepped at once by MuJoCo MJX on JAX's default device "
                        "(a GPU when JAX has one; kinds pd, lqr, policy; needs pip install "
                        f"'tspend[mjx]'; {doc('docs/accelerator.md')})")
    p.add_argument("--precision", choices=("float64", "float32"), default="float64",
                   help="the mjx backend's float width: float64 (default, as the CPU) or "
                        f"float32 (faster on a GPU; the departure is in {doc('docs/accelerator.md')})")
    add_run_timeout_option(p)
    p.add_argument("--debug", action="store_true", help="show tracebacks")


def add_run_timeout_option(p) -> None:
    """``--run-timeout S`` (sweep, compare, tune): a run past it is killed, a ``timeout`` row."""
    from tspend.runtime.bounds import DEFAULT_RUN_TIMEOUT_S

    p.add_argument("--run-timeout", type=float, metavar="S",
                   help=f"kill a run still going after S seconds of wall time; its row has "
                        f"status 'timeout' and the others go on (default "
                        f"{DEFAULT_RUN_TIMEOUT_S:g})")


#: statuses of runs that did not complete: no verdict on the controller, no metrics (a
#: controller that raised or exited ended its run before the end: a sweep of them is no
#: success)
INCOMPLETE = ("controller_error", "timeout", "failed")


def incomplete_line(frame) -> str | None:
    """``N of M runs did not complete: K timeout, J failed`` (None when every run did)."""
    counts = frame["status"].value_counts()
    parts = [f"{int(counts[s])} {s}" for s in INCOMPLETE if counts.get(s, 0)]
    if not parts:
        return None
    n = sum(int(counts.get(s, 0)) for s in INCOMPLETE)
    return f"{n} of {len(frame)} runs did not complete: {', '.join(parts)}"


def _scenarios(args: argparse.Namespace) -> list:
    from tspend.cli.common import parse_set_value
    from tspend.scenario import load_scenario, override

    changes = {}
    if args.duration is not None:
        if not args.duration > 0:
            raise ScenarioError(f"--duration: must be a positive number of seconds, got "
                                f"{args.duration}")
        changes["run.duration"] = float(args.duration)
    for item in args.set:
        key, value = parse_set_value(item)  # one line of TOML, trailing text refused
        changes[key] = value
    scenarios = [load_scenario(s) for s in args.scenario]
    return [override(s, **changes) if changes else s for s in scenarios]


def summary(frame, grid_keys: list[str]):
    """Per scenario, grid point and controller: runs by status (``completed``, each way
    the task ended runs that occurred, e.g. ``fell`` or ``rail_end``, then ``diverged``
    and ``failed``), median and IQR of rmse_ss."""
    import pandas as pd

    keys = ["scenario", *grid_keys, "controller"]
    groups = frame.groupby(keys, sort=False, dropna=False)
    from tspend.task import TERMINATIONS

    out = groups["status"].value_counts().unstack(fill_value=0)
    for status in ("completed", "diverged", "failed", "controller_error", "timeout", "refused",
                   *TERMINATIONS):
        if status not in out.columns:
            out[status] = 0
    # a run the task ended is reported by how it ended (the pole fell, the cart reached the
    # rail's end), not as a divergence: a column for each termination that occurred; a
    # controller's error and a run killed past --run-timeout too, when there were any
    ended = [s for s in TERMINATIONS if out[s].any()]
    # (refused: safety.refuse_unadmitted's start no plan was certified from)
    rare = [s for s in ("controller_error", "timeout", "refused") if out[s].any()]
    out = out[["completed", *ended, "diverged", "failed", *rare]]
    ss = groups["rmse_ss"]
    out["rmse_ss median"] = ss.median()
    out["IQR"] = ss.quantile(0.75) - ss.quantile(0.25)
    return out.reset_index() if isinstance(out, pd.DataFrame) else out


def _stop_requests(args: argparse.Namespace):
    """A context giving the StopRequest that SIGINT/SIGTERM set while the sweep runs."""
    guard = getattr(args, "guard", None)  # the CLI's signal guard, when it provides one
    if guard is not None:
        return guard.deferred()
    from tspend.cli.common import stop_on_signals

    return stop_on_signals()


def _kept(out: str | None, read_table) -> str:
    """What an interrupted sweep left: the rows its table (file and journal) holds, said as
    such; a sweep stopped before its first row finished has written no table at all."""
    if not out:
        return "nothing kept (no --out)"
    from tspend.sweep.table import journal_path

    kept = len(read_table(out))
    if not Path(out).exists():
        if not kept:
            return f"no run finished, {out} not written"
        return (f"{kept} rows kept in {journal_path(Path(out))} ({out} not written yet); the "
                f"same command finishes the rest")
    return f"{kept} rows kept in {out}; the same command finishes the rest"


def cmd(args: argparse.Namespace) -> int:
    from tspend import __version__
    from tspend.cli.common import controller_help
    from tspend.loop.runner import RunInterrupted
    from tspend.sweep import plan as sweep_plan, read_table

    if controller_help(args):
        return 0
    from tspend.sweep import check_jobs, prepare_sweep

    # everything is checked, the models built and the table locked before the banner
    check_jobs(args.jobs)
    sweep_plan.controller_list(args.controller)  # plug-ins first: scenarios may hold their tables
    scenarios = _scenarios(args)
    grid = sweep_plan.parse_grid(args.grid)
    seeds = sweep_plan.parse_seeds(args.seeds) if args.seeds is not None else None
    with _stop_requests(args) as stop:
        prepared = prepare_sweep(scenarios, grid=grid, seeds=seeds, controllers=args.controller,
                                 jobs=args.jobs, dask=args.dask, out=args.out,
                                 record=args.record, stop=stop, wait=args.wait,
                                 run_timeout=args.run_timeout, backend=args.backend,
                                 precision=args.precision)
        try:
            names = ", ".join(s.name for s in scenarios)
            print(f"tspend {__version__}: sweep of {names}" +
                  (f", table {args.out}" if args.out else ""), flush=True)
            frame = prepared.run(progress=True, stop=stop)
        except RunInterrupted as exc:
            print(f"tspend: sweep interrupted by {exc.signal_name}; {_kept(args.out, read_table)}",
                  file=sys.stderr)
            return exc.exit_status
        finally:
            prepared.close()
    if not len(frame):
        print("nothing to run")
        return 0
    import pandas as pd

    with pd.option_context("display.max_rows", 200, "display.width", 160,
                           "display.float_format", "{:.4g}".format):
        print(summary(frame, list(grid)).to_string(index=False))
    recorded = frame["recording"].dropna()
    if len(recorded):
        print(f"recordings: {len(recorded)} in {Path(recorded.iloc[0]).parent}")
    if args.out:
        print(f"table: {args.out} ({len(frame)} rows of this sweep)")
    return incomplete_status(frame)


def incomplete_status(frame) -> int:
    """Print the runs that did not complete (controller_error, timeout, failed) on stderr: their count is
    the exit status's reason, :data:`~tspend.cli.common.EXIT_INCOMPLETE`; else 0."""
    from tspend.cli.common import EXIT_INCOMPLETE

    line = incomplete_line(frame)
    if line is None:
        return 0
    print(f"tspend: {line} (see the rows' status and message)", file=sys.stderr)
    return EXIT_INCOMPLETE
