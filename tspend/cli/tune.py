"""``tspend tune``: tune one controller kind on a scenario (Optuna, seeded TPE) and write
the tuned scenario; the logic is :mod:`tspend.studies.tune`.

Everything is checked before the first run: the kind, the budget, the seeds (train and
test disjoint), the metric, the output (a ``.toml`` file; an existing one is replaced only
when it is a tuned scenario of the same kind, and only by a complete file).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tspend.runtime.errors import ScenarioError


def add_parser(subparsers) -> argparse.ArgumentParser:
    from tspend.cli.common import bounded_int

    p = subparsers.add_parser(
        "tune", help="tune a controller kind's settings on a scenario (Optuna)",
        description="Search the kind's declared settings (Optuna, seeded TPE sampler); each "
                    "trial scores the median of the metric over the training seeds (runs that "
                    "fell, diverged or failed count as worst). Writes the scenario with the "
                    "tuned [controllers.KIND] table ([controller] for the paper's kinds) and "
                    "prints the train and test scores.")
    p.add_argument("scenario", metavar="SCENARIO", help="scenario name or .toml path")
    p.add_argument("--controller", required=True, metavar="KIND", help="the kind to tune")
    p.add_argument("--trials", required=True, type=bounded_int(1, 100_000), metavar="N",
                   help="trials in all (a resumed --storage study counts those done)")
    p.add_argument("--seeds", required=True, metavar="A:B", help="training seeds A to B-1")
    p.add_argument("--test-seeds", metavar="C:D",
                   help="held-out seeds to score the tuned settings on (disjoint from --seeds)")
    p.add_argument("--metric", metavar="M", help="the metric to minimise (default rmse)")
    p.add_argument("--out", required=True, metavar="FILE.toml", help="the tuned scenario")
    p.add_argument("--storage", metavar="URL",
                   help="Optuna storage making the study resumable: an RDB URL "
                        "(sqlite:///tune.db) or a file path (a journal file)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--jobs", type=bounded_int(1, 4096), metavar="N",
                       help="worker processes (default: cores)")
    where.add_argument("--dask", metavar="ADDRESS",
                       help="run on a Dask cluster ('local' starts one on this machine)")
    p.add_argument("--sampler-seed", type=bounded_int(0, 2**32 - 1), default=0, metavar="N",
                   help="seed of the TPE sampler (default 0)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario key (kept in the tuned scenario; repeatable)")
    p.add_argument("--duration", type=float, metavar="S", help="override run.duration")
    from tspend.cli.sweep import add_run_timeout_option

    add_run_timeout_option(p)  # a trial's run past it scores +inf, like a failed one
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    return p


def parse_options(args: argparse.Namespace) -> dict:
    """Everything checked before a single run starts (bad input: ScenarioError)."""
    from tspend.cli.common import parse_set_value
    from tspend.controllers import KINDS
    from tspend.controllers import search_space
    from tspend.scenario import load_scenario, override
    from tspend.studies.stats import COMPARED_METRICS
    from tspend.studies.tune import DEFAULT_METRIC, check_seeds
    from tspend.sweep.plan import parse_seeds

    kind = args.controller.strip()
    if kind not in KINDS:
        raise ScenarioError(f"--controller {kind}: unknown kind; allowed: {', '.join(KINDS)}")
    if not search_space(kind):
        raise ScenarioError(f"--controller {kind}: the kind declares nothing to tune")
    metric = args.metric or DEFAULT_METRIC
    if metric not in COMPARED_METRICS:
        raise ScenarioError(f"--metric {metric}: unknown metric; allowed: "
                            f"{', '.join(COMPARED_METRICS)}")
    seeds = parse_seeds(args.seeds)
    test_seeds = parse_seeds(args.test_seeds) if args.test_seeds else []
    check_seeds(seeds, test_seeds)
    changes = {}
    for item in args.set:
        key, value = parse_set_value(item)
        changes[key] = value
    if args.duration is not None:
        if not args.duration > 0:
            raise ScenarioError(f"--duration: must be a positive number of seconds, got "
                                f"{args.duration}")
        changes["run.duration"] = float(args.duration)
    from tspend.sweep import check_dask_address, check_jobs

    check_jobs(args.jobs)
    from tspend.sweep import check_run_timeout

    check_run_timeout(args.run_timeout)
    if args.dask is not None:
        check_dask_address(args.dask)
    scenario = load_scenario(args.scenario)
    if changes:
        scenario = override(scenario, **changes)
    return dict(kind=kind, metric=metric, seeds=seeds, test_seeds=test_seeds,
                scenario=scenario)


def check_out(path: str, kind: str) -> None:
    """An existing ``--out`` is replaced only when it is a tuned scenario of ``kind``."""
    from tspend.studies.tune import tuned_kind

    p = Path(path)
    if not p.is_file():
        return
    try:
        head = p.read_text(encoding="utf-8", errors="replace")[:4096]
    except OSError as exc:
        raise ScenarioError(f"--out {path}: cannot be read: {exc.strerror}") from None
    found = tuned_kind(head)
    if found is None:
        raise ScenarioError(f"--out {path}: exists and was not written by tspend tune; "
                            f"refusing to replace it")
    if found[0] != kind:
        raise ScenarioError(f"--out {path}: holds a tuned '{found[0]}' scenario, not "
                            f"'{kind}'; choose another --out")


def cmd(args: argparse.Namespace) -> int:
    from tspend.cli.common import Claimed, plan, scenario_inputs
    from tspend.cli.sweep import _stop_requests
    from tspend.loop.runner import RunInterrupted
    from tspend.runtime.outputs import OutputRequest, display
    from tspend.studies.tune import tune

    opts = parse_options(args)
    kind, scenario = opts["kind"], opts["scenario"]
    plans = plan([OutputRequest("--out", "scenario", ".toml", args.out)],
                 scenario_inputs(scenario))
    check_out(args.out, kind)
    with _stop_requests(args) as stop, Claimed(plans) as outs:
        try:
            result = tune(scenario, kind, trials=args.trials, seeds=opts["seeds"],
                          test_seeds=opts["test_seeds"], metric=opts["metric"], jobs=args.jobs,
                          dask=args.dask, storage=args.storage,
                          sampler_seed=args.sampler_seed, progress=True, stop=stop,
                          run_timeout=args.run_timeout)
        except RunInterrupted as exc:
            kept = (f"the trials done are kept in {args.storage}; the same command resumes"
                    if args.storage else "nothing kept (no --storage)")
            print(f"tspend: tune interrupted by {exc.signal_name}; {kept}", file=sys.stderr)
            return exc.exit_status
        out = outs["--out"]
        out.write(result.text.encode())
        problem = outs.complete(out)
        if problem:
            raise ScenarioError(problem)
    m = result.metric
    print(f"{kind} on {result.base_name}: {result.trials} trials x {len(result.train_seeds)} "
          f"training seeds")
    print(f"tuned: " + ", ".join(f"{k} = {v}" for k, v in result.values.items()))
    print(f"train score (median {m}, seeds {args.seeds}): {result.train_score:.6g}"
          + (f" (untuned {result.default_train:.6g})" if result.default_train is not None else ""))
    if result.test_seeds:
        print(f"test score (median {m}, seeds {args.test_seeds}): {result.test_score:.6g}"
              + (f" (untuned {result.default_test:.6g})" if result.default_test is not None
                 else ""))
    print(f"scenario: {display(args.out)} (tspend run {display(args.out)} --controller {kind})")
    return 0
