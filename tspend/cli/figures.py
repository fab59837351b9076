"""``tspend figures``: the paper's figures redrawn from runs, box plots of a comparison
and heat maps of a two-key sweep, as PNG and PDF with their data as CSV.

    tspend figures paper [--seed N] [--duration S] [--controller K1,K2]
    tspend figures box RUNS.parquet [--metric M1,M2] [--controller K1,K2]
    tspend figures heatmap RUNS.parquet --x KEY --y KEY [--metric M] [--controller K]

``RUNS.parquet`` is the table of ``tspend sweep --out`` or ``tspend compare --out``.
Files are written under ``--out DIR`` (default ``figures``); an existing file is never
replaced unless ``--overwrite`` is given.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from tspend.cli.common import DeprecatedFlag
from tspend.runtime.errors import ScenarioError


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("figures", help="draw figures (PNG, PDF and CSV) from runs or "
                              "a sweep table",
                              description="Figures as PNG and PDF with their data "
                                          "as CSV: the paper's, box plots of a comparison, "
                                          "heat maps of a two-key sweep.")
    sub = p.add_subparsers(dest="figure", required=True, metavar="FIGURE",
                           help="which figures: paper, box or heatmap")

    def common(q):
        q.add_argument("--out", default="figures", metavar="DIR",
                       help="directory for the files (default: figures)")
        q.add_argument("--pdf", action=DeprecatedFlag, why="PDF is always written beside the PNG",
                       help="deprecated, does nothing: PDF is always written beside the PNG "
                            "(kept one release for old scripts, with a warning)")
        q.add_argument("--overwrite", action="store_true", help="replace existing files")
        q.add_argument("--controller", metavar="K1,K2,...", help="controller kinds to draw")
        q.add_argument("--debug", action="store_true", help="show tracebacks")

    pp = sub.add_parser("paper", help="x1, x2 against the reference for Examples 1-3, u of "
                        "Example 2, its membership functions before and after adaptation",
                        description="The paper's figures redrawn from runs of its examples "
                                    "(ex1_nonaffine_case1, ex1_nonaffine_case2, ex2_duffing, "
                                    "ex3_pendulum_ode at their own seeds, or --seed): x1 and "
                                    "x2 against the reference for Examples 1-3, the control u "
                                    "of Example 2 and its membership functions before and "
                                    "after adaptation; each as PNG and PDF with its data as "
                                    "CSV under --out DIR.")
    common(pp)
    pp.add_argument("--seed", type=int, metavar="N", help="seed (default: each scenario's)")
    pp.add_argument("--duration", type=float, metavar="S", help="override run.duration")
    pp.add_argument("--every", type=int, default=10, metavar="N",
                    help="draw every Nth sample of x (default 10; u is drawn in full)")

    bp = sub.add_parser("box", help="box plots across seeds of a sweep/compare table",
                        description="Box plots across seeds of one metric per figure, one box "
                                    "per controller, from a table of tspend sweep or tspend "
                                    "compare --out.")
    common(bp)
    bp.add_argument("table", metavar="RUNS.parquet",
                    help="a table written by tspend sweep or tspend compare --out")
    bp.add_argument("--metric", default="rmse_ss", metavar="M1,M2,...",
                    help="one figure per metric (default rmse_ss)")
    from tspend.cli.common import add_deprecated_alias

    add_deprecated_alias(bp, "--metrics", "--metric", "M1,M2,...")  # --metrics is a file elsewhere

    hp = sub.add_parser("heatmap", help="median of a metric over a two-key sweep",
                        description="The median over seeds of one metric on the grid of two "
                                    "--grid keys of a tspend sweep table.")
    common(hp)
    hp.add_argument("table", metavar="RUNS.parquet",
                    help="a table written by tspend sweep over two --grid keys")
    hp.add_argument("--x", required=True, metavar="KEY", help="grid column on the x axis")
    hp.add_argument("--y", required=True, metavar="KEY", help="grid column on the y axis")
    hp.add_argument("--metric", default="rmse_ss", metavar="M", help="the metric whose median is drawn (default rmse_ss)")
    return p


def _kinds(text: str | None) -> list[str] | None:
    return [k.strip() for k in text.split(",") if k.strip()] if text else None


def _read(path: str):
    import pandas as pd

    if not Path(path).exists():
        raise ScenarioError(f"{path}: no such file")
    read_table = pd.read_parquet
    if Path(path + ".journal").exists():  # a sweep still running: its unfolded rows too
        from tspend.sweep.table import read_table
    try:
        table = read_table(path)
    except (OSError, ValueError) as exc:
        raise ScenarioError(f"{path}: not a readable Parquet table ({exc})") from None
    if len(table) == 0 or "controller" not in table.columns:
        raise ScenarioError(f"{path}: no runs in the table")
    return table


def cmd(args: argparse.Namespace) -> int:
    from tspend.cli.common import controller_help
    from tspend.controllers import load
    from tspend.studies.figures import Figures, box_figure, heatmap_figure, paper_figures
    from tspend.studies.stats import COMPARED_METRICS

    if controller_help(args):
        return 0
    out = Figures(Path(args.out), overwrite=args.overwrite)
    kinds = _kinds(args.controller)
    if args.figure == "paper":
        kinds = kinds or ["second_type", "first_type"]
        for kind in kinds:
            load(kind)  # a built-in kind, file.py:Class or package.module:Class (exit 2 if not)
        if args.every < 1:
            raise ScenarioError(f"--every: must be >= 1, got {args.every}")
        if args.duration is not None and not args.duration > 0:
            raise ScenarioError(f"--duration: must be positive, got {args.duration}")
        paper_figures(out, kinds, seed=args.seed, duration=args.duration,
                             every=args.every)
    else:
        table = _read(args.table)
        metrics = [m.strip() for m in args.metric.split(",")]
        bad = [m for m in metrics if m not in COMPARED_METRICS]
        if bad:
            raise ScenarioError(f"--metric {','.join(bad)}: unknown; allowed: "
                                f"{', '.join(COMPARED_METRICS)}")
        present = set(table["controller"])
        if kinds and not set(kinds) <= present:
            raise ScenarioError(f"--controller: {', '.join(sorted(set(kinds) - present))} not "
                                f"in {args.table} (it has {', '.join(sorted(present))})")
        stem = Path(args.table).stem
        if args.figure == "box":
            names = [f"{stem}_box_{m}" for m in metrics]
            out.check(names)
            for m, n in zip(metrics, names):
                box_figure(out, table, m, n, kinds)
        else:
            name = f"{stem}_heatmap_{metrics[0]}"
            out.check([name])
            heatmap_figure(out, table, args.x, args.y, metrics[0], name, kinds)
    for p in out.written:
        print(p)
    return 0
