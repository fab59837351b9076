"""``tspend compare``: every controller on every scenario at the same seeds, paired by seed.

The runs are a sweep (:func:`tspend.sweep.sweep`: local worker pool or a Dask cluster,
resumable with ``--out``); the statistics are :mod:`tspend.studies.stats` (median [Q1, Q3] per
controller and the share of runs that ended badly; per pair the median paired difference
with a bootstrap 95% interval, the win rate, on how many seeds each side was worse and
its worst seed's ratio, the Wilcoxon signed-rank p-value and its Holm adjustment over the
whole call, which the verdicts use, and McNemar's exact test on the outcomes; duplicate
experiments flagged).  The Markdown table goes to stdout,
``--metrics PATH.json`` writes the same figures, ``--out`` keeps the sweep's Parquet table.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tspend.cli.common import add_metrics_option
from tspend.runtime.errors import ScenarioError


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "compare", help="compare controller kinds over seeds, paired (Markdown table)",
        description="Every controller kind on every scenario at the same seeds, paired by "
                    "seed: median [Q1, Q3] per kind; per pair the median difference with a "
                    "bootstrap 95% interval, the win rate, k-of-N worse seeds, the Wilcoxon "
                    "p-value and its Holm adjustment (p_holm, over every pair, metric and "
                    "scenario of the call; verdicts use it), and McNemar's exact test on runs "
                    "that fell, diverged or failed.")
    p.add_argument("scenarios", nargs="+", metavar="SCENARIO",
                   help="scenario names (see 'tspend list') or .toml paths")
    p.add_argument("--controller", metavar="K1,K2,...",
                   help="controller kinds, compared in this order (default: every built-in "
                        "kind), or path/to/file.py:Class, package.module:Class; "
                        "'--controller help' lists them")
    p.add_argument("--seeds", default="0:20", metavar="A:B",
                   help="seeds A to B-1 (or N1,N2,...); default 0:20")
    p.add_argument("--metric", metavar="M1,M2,...",
                   help="metrics to compare (default: rmse,rmse_ss,max_abs_e_ss,"
                        "control_energy,tv_u_per_s; an unknown name lists them)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario key for every run (repeatable)")
    p.add_argument("--duration", type=float, metavar="S", help="override run.duration")
    add_metrics_option(p, "the statistics", old="--json")
    p.add_argument("--out", metavar="PATH.parquet",
                   help="keep the sweep's table of runs (rerunning resumes it)")
    p.add_argument("--jobs", type=int, metavar="N", help="worker processes (default: cores)")
    p.add_argument("--dask", metavar="ADDRESS",
                   help="run on a Dask cluster ('local' starts one on this machine)")
    p.add_argument("--resamples", type=int, default=9999, metavar="N",
                   help="bootstrap resamples (default 9999)")
    p.add_argument("--stats-seed", type=int, default=0, metavar="N",
                   help="seed of the bootstrap's generator (default 0)")
    p.add_argument("--tune", type=int, metavar="N",
                   help="equal budget: first tune every kind with N trials (Optuna TPE) on "
                        "--tune-seeds, then compare the tuned kinds on --seeds")
    p.add_argument("--tune-seeds", metavar="A:B",
                   help="training seeds of --tune, disjoint from --seeds (default: the 5 "
                        "seeds after the last of --seeds)")
    p.add_argument("--tune-metric", metavar="M", help="the metric --tune minimises "
                                                      "(default rmse)")
    p.add_argument("--progress", action="store_true", help="show the sweep's progress")
    from tspend.cli.sweep import add_run_timeout_option

    add_run_timeout_option(p)
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    return p


def _list(text: str | None) -> list[str] | None:
    if text is None:
        return None
    items = [t.strip() for t in text.split(",") if t.strip()]
    return items or None


def _old_metric_list(args: argparse.Namespace) -> None:
    """``--metrics M1,M2`` named the metrics compared before ``--metrics`` meant the JSON
    file (every command's figures): a value not ending in ``.json`` is read the old way for
    one release, with a deprecation line."""
    value = args.metrics
    if value is None or value.lower().endswith(".json") or args.metric is not None:
        return
    from tspend.cli.common import say
    from tspend.studies.stats import COMPARED_METRICS

    if not all(item in COMPARED_METRICS for item in (_list(value) or ["?"])):
        # not a list of metrics: a path, checked (and refused in one line) as the new
        # --metrics is
        return

    say("warning: --metrics M1,M2 (the metrics compared) is deprecated and goes in the next "
        "release; use --metric M1,M2 (--metrics PATH.json now writes the statistics)")
    args.metric, args.metrics = value, None


def parse_options(args: argparse.Namespace) -> dict:
    """Everything checked before a single run starts (bad input: ScenarioError)."""
    from tspend.cli.common import check_writable, parse_set_value
    from tspend.controllers import KINDS, load
    from tspend.studies.stats import COMPARED_METRICS, DEFAULT_METRICS
    from tspend.sweep.plan import parse_seeds

    specs = _list(args.controller) or list(KINDS)
    # rows and statistics name a plug-in (file.py:Class) by its kind
    kinds = [load(spec).name for spec in specs]
    if len(set(kinds)) < 2:
        raise ScenarioError("--controller: name at least two different kinds to compare")
    _old_metric_list(args)
    metrics = _list(args.metric) or list(DEFAULT_METRICS)
    bad = [m for m in metrics if m not in COMPARED_METRICS]
    if bad:
        raise ScenarioError(f"--metric {','.join(bad)}: unknown metric; allowed: "
                            f"{', '.join(COMPARED_METRICS)}")
    seeds = parse_seeds(args.seeds)
    grid: dict[str, list] = {}
    for item in args.set:
        key, value = parse_set_value(item)
        grid[key] = [value]
    if args.duration is not None:
        if not args.duration > 0:
            raise ScenarioError(f"--duration: must be a positive number of seconds, got "
                                f"{args.duration}")
        grid["run.duration"] = [float(args.duration)]
    from tspend.runtime.bounds import MAX_RESAMPLES, MAX_RUNS, MAX_TRIALS
    from tspend.sweep import check_dask_address, check_jobs

    if not 100 <= args.resamples <= MAX_RESAMPLES:
        raise ScenarioError(f"--resamples: from 100 to {MAX_RESAMPLES}, got {args.resamples}")
    if not 0 <= args.stats_seed <= 2**63 - 1:
        raise ScenarioError(f"--stats-seed: from 0 to 2^63 - 1, got {args.stats_seed}")
    if args.tune is not None and not 1 <= args.tune <= MAX_TRIALS:
        raise ScenarioError(f"--tune: trials from 1 to {MAX_TRIALS}, got {args.tune}")
    runs = len(seeds) * len(kinds) * len(args.scenarios)
    if runs > MAX_RUNS:
        raise ScenarioError(f"compare: {runs} runs (scenarios x seeds x controllers), more "
                            f"than {MAX_RUNS}")
    check_jobs(args.jobs)
    from tspend.sweep import check_run_timeout

    check_run_timeout(args.run_timeout)
    if args.dask is not None:
        check_dask_address(args.dask)
    json_path = Path(args.metrics) if args.metrics else None
    if json_path is not None:
        check_writable(json_path, "metrics")
    tune = None
    if args.tune is not None:
        tune = _tune_options(args, kinds, seeds)
    return dict(kinds=kinds, specs=specs, metrics=metrics, seeds=seeds, grid=grid or None,
                json_path=json_path, tune=tune)


def _tune_options(args: argparse.Namespace, kinds: list[str], seeds: list[int]) -> dict:
    from tspend.controllers import search_space
    from tspend.studies.stats import COMPARED_METRICS
    from tspend.studies.tune import DEFAULT_METRIC, check_seeds
    from tspend.sweep.plan import parse_seeds

    if args.tune < 1:
        raise ScenarioError(f"--tune: trials must be >= 1, got {args.tune}")
    if args.out:
        raise ScenarioError("--out: not with --tune (the tuned runs are not a resumable sweep)")
    empty = [k for k in kinds if not search_space(k)]
    if empty:
        raise ScenarioError(f"--tune: {', '.join(empty)} declare(s) nothing to tune")
    train = (parse_seeds(args.tune_seeds) if args.tune_seeds else
             list(range(max(seeds) + 1, max(seeds) + 6)))
    try:
        check_seeds(train, seeds)
    except ScenarioError:
        raise ScenarioError("--tune-seeds: must be disjoint from --seeds (the tuned kinds are "
                            "compared on seeds they were not tuned on)") from None
    metric = args.tune_metric or DEFAULT_METRIC
    if metric not in COMPARED_METRICS:
        raise ScenarioError(f"--tune-metric {metric}: unknown metric; allowed: "
                            f"{', '.join(COMPARED_METRICS)}")
    return dict(trials=args.tune, seeds=train, metric=metric)


def seeds_text(seeds: list[int]) -> str:
    if seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}-{seeds[-1]}" if len(seeds) > 1 else str(seeds[0])
    return ",".join(map(str, seeds))


def run_comparison(scenarios, kinds, seeds, metrics, *, grid=None, out=None, jobs=None,
                   dask=None, progress=False, resamples=9999, stats_seed=0, specs=None,
                   run_timeout=None):
    """Sweep every kind over ``seeds`` on ``scenarios`` and compare them: (table, Comparison).

    ``specs``: what runs, when it differs from the kinds' names (plug-ins, ``file.py:Class``).
    """
    from tspend.studies.stats import compare
    from tspend.sweep import sweep

    timeout = {} if run_timeout is None else {"run_timeout": run_timeout}
    table = sweep(scenarios, grid=grid, seeds=seeds, controllers=specs or kinds, jobs=jobs,
                  dask=dask, out=out, record="none", progress=progress, **timeout)
    # a resumed --out table may hold other runs too: compare what was asked for
    table = table[table["controller"].isin(kinds) & table["seed"].isin(seeds)]
    return table, compare(table, kinds, metrics, seed=stats_seed, n_resamples=resamples)


def run_tuned_comparison(scenarios, kinds, seeds, metrics, tune, *, grid=None, jobs=None,
                         dask=None, progress=False, resamples=9999, stats_seed=0,
                         run_timeout=None):
    """Equal budget: tune every kind (``tune``: trials, seeds, metric) on every scenario,
    then compare the tuned kinds on ``seeds``: (table, Comparison, tuned results)."""
    from tspend.scenario import load_scenario, override
    from tspend.studies.stats import compare
    from tspend.studies.tune import equal_budget

    loaded = []
    for name in scenarios:
        scn = load_scenario(name)
        changes = {k: v[0] for k, v in (grid or {}).items()}
        loaded.append(override(scn, **changes) if changes else scn)
    table, tuned = equal_budget(loaded, kinds, trials=tune["trials"], train_seeds=tune["seeds"],
                                test_seeds=seeds, metric=tune["metric"], jobs=jobs, dask=dask,
                                progress=progress, run_timeout=run_timeout)
    return table, compare(table, kinds, metrics, seed=stats_seed, n_resamples=resamples), tuned


def tuned_markdown(tuned: dict, tune: dict) -> str:
    """The tuned settings and train scores, one row per scenario and kind."""
    from tspend.studies.stats import fmt

    lines = [f"### Tuned on an equal budget: {tune['trials']} trials per kind on training "
             f"seeds {seeds_text(tune['seeds'])}, objective median {tune['metric']}", "",
             "| scenario | controller | tuned settings | train score |", "|---|---|---|---:|"]
    for (scn, kind), r in tuned.items():
        def shown(v):
            if isinstance(v, float):
                return fmt(v, 4)
            if isinstance(v, list):
                return "[" + ", ".join(shown(x) for x in v) + "]"
            return str(v)

        values = ", ".join(f"{k} = {shown(v)}" for k, v in r.values.items()
                           if k != "adaptation")
        lines.append(f"| {scn} | {kind} | {values} | {fmt(r.train_score, 4)} |")
    return "\n".join(lines) + "\n\n"


def cmd(args: argparse.Namespace) -> int:
    import json

    from tspend.cli.common import controller_help, write_json
    from tspend.studies.stats import json_number, markdown, to_json

    if controller_help(args):
        return 0
    opts = parse_options(args)
    tuned = None
    if opts["tune"] is not None:
        table, comp, tuned = run_tuned_comparison(
            args.scenarios, opts["kinds"], opts["seeds"], opts["metrics"], opts["tune"],
            grid=opts["grid"], jobs=args.jobs, dask=args.dask, progress=args.progress,
            resamples=args.resamples, stats_seed=args.stats_seed, run_timeout=args.run_timeout)
        sys.stdout.write(tuned_markdown(tuned, opts["tune"]))
    else:
        table, comp = run_comparison(args.scenarios, opts["kinds"], opts["seeds"],
                                     opts["metrics"], grid=opts["grid"], out=args.out,
                                     jobs=args.jobs, dask=args.dask, progress=args.progress,
                                     resamples=args.resamples, stats_seed=args.stats_seed,
                                     specs=opts["specs"], run_timeout=args.run_timeout)
    sys.stdout.write(markdown(comp, seeds_text(opts["seeds"])))
    if opts["json_path"] is not None:
        doc = to_json(comp)
        if tuned is not None:
            doc["tuned"] = [dict(scenario=scn, controller=kind, values=r.values,
                                 train_score=json_number(r.train_score), trials=r.trials,
                                 train_seeds=r.train_seeds, metric=r.metric)
                            for (scn, kind), r in tuned.items()]
        doc["seeds"] = opts["seeds"]
        doc["scenarios"] = list(args.scenarios)
        # a partial file renamed into place: a full disk never truncates the previous one
        write_json(opts["json_path"], json.loads(json.dumps(doc, allow_nan=False)))
    if args.out:
        print(f"runs: {args.out}", file=sys.stderr)
    from tspend.cli.sweep import incomplete_status

    return incomplete_status(table)
