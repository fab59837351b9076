"""The evidence of docs/controllers.md's baselines, at a glance: a table of verdicts on two
seed sets and one figure.

    nice python benchmarks/controller_evidence.py              # runs the confirmation set
    python benchmarks/controller_evidence.py --render           # from the kept runs only

Every kind as shipped (its ``[controllers.KIND]`` tables, the fixed machine, 20 s at
1 ms). The test seeds are docs/results/runs.parquet's, seeds 0-19, made by
benchmarks/results.py; the confirmation seeds, 200-219, fixed before the wording, are run
here into :data:`CONFIRM_RUNS` (resumable). Each set is compared alone
(:func:`tspend.studies.stats.compare`: the pairs of :data:`CLAIMS` on their scenarios,
every metric, Holm's correction over that family), and a claim is "shown" only when both
sets give the same verdict. The baselines draw nothing from the seed; the paper's kind
draws its initial consequents, so the pairs differ from seed to seed.

It writes :data:`CLAIMS_JSON`, the figure (:data:`FIGURE`, its data beside it as CSV) and
the section of docs/controllers.md between :data:`BEGIN` and :data:`END`;
tools/check_claims.py rebuilds that section from the kept runs and compares.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))

TEST_RUNS = ROOT / "docs" / "results" / "runs.parquet"
CONFIRM_RUNS = ROOT / "docs" / "results" / "controllers_confirm.parquet"
CLAIMS_JSON = ROOT / "docs" / "results" / "controller_claims.json"
FIGURE = ROOT / "docs" / "results" / "figures" / "controller_claims.png"
PAGE = ROOT / "docs" / "controllers.md"
BEGIN = "<!-- benchmarks/controller_evidence.py: begin (generated; rerun it, do not edit) -->"
END = "<!-- benchmarks/controller_evidence.py: end -->"
TEST_SEEDS, CONFIRM_SEEDS = list(range(0, 20)), list(range(200, 220))
METRICS = ("rmse", "rmse_ss", "max_abs_e_ss", "control_energy", "tv_u_per_s")
#: each (scenario, A, B, metric): a claim of the page on A against B
CLAIMS = (
    ("ex1_nonaffine_case1", "sliding_mode", "second_type", "rmse_ss"),
    ("ex1_nonaffine_case2", "sliding_mode", "second_type", "rmse_ss"),
    ("pendulum_mujoco", "sliding_mode", "second_type", "rmse_ss"),
    ("pendulum_mujoco", "wang_indirect", "second_type", "rmse_ss"),
    ("pendulum_mujoco", "wang_indirect", "second_type", "tv_u_per_s"),
    ("ex1_nonaffine_case2", "wang_indirect", "second_type", "rmse_ss"),
    ("ex2_duffing", "wang_indirect", "second_type", "rmse_ss"),
)
SCENARIOS = tuple(dict.fromkeys(c[0] for c in CLAIMS))
KINDS = ("second_type", "sliding_mode", "wang_indirect")
PAIRS = tuple(dict.fromkeys((a, b) for _, a, b, _ in CLAIMS))


def run_confirmation(jobs: int, fresh: bool) -> None:
    """The confirmation seeds' runs, every scenario and kind of :data:`CLAIMS` (the table
    :data:`CONFIRM_RUNS` resumes: a run kept there is not run again)."""
    from tspend.sweep import sweep

    if fresh:
        CONFIRM_RUNS.unlink(missing_ok=True)
    sweep(list(SCENARIOS), seeds=CONFIRM_SEEDS, controllers=list(KINDS), jobs=jobs,
          out=CONFIRM_RUNS, progress=True)


def comparisons():
    """(test comparison, confirmation comparison), each over its own family."""
    import pandas as pd

    from tspend.studies.stats import compare

    out = []
    for path, seeds in ((TEST_RUNS, TEST_SEEDS), (CONFIRM_RUNS, CONFIRM_SEEDS)):
        t = pd.read_parquet(path)
        t = t[t.scenario.isin(SCENARIOS) & t.controller.isin(KINDS) & t.seed.isin(seeds)]
        out.append(compare(t, list(KINDS), METRICS, pairs=list(PAIRS)))
    return out


def claims() -> dict:
    """Each claim's figures on both sets (fair_results' record of a verdict)."""
    from fair_results import headline_claims

    comp, comp2 = comparisons()
    return headline_claims(comp, comp2, TEST_SEEDS, CONFIRM_SEEDS, headlines=CLAIMS)


def section(found: dict) -> str:
    """The page's section: the verdict table, the figure, the few lines under them."""
    import os

    from fair_results import _cell

    fig = Path(os.path.relpath(FIGURE, PAGE.parent)).as_posix()
    lines = [f"Each kind as shipped, on its fixed machine; test seeds {found['test_seeds']} "
             f"(docs/results/runs.parquet) and confirmation seeds {found['confirm_seeds']}, "
             f"fixed before this wording. Cell: median ratio A / B over the paired seeds "
             f"(Holm-adjusted p, {found['family_test'].split(' (')[0]}); shown only when both "
             f"sets give the same verdict.", "",
             f"| claim: A / B | seeds {found['test_seeds']} | seeds "
             f"{found['confirm_seeds']} | shown? |", "|---|---|---|---|"]
    for c in found["claims"]:
        verdict = f"**shown**: {c['better']} lower" if c["shown"] else "not shown"
        lines.append(f"| `{c['metric']}` ({c['scenario']}): {c['a']} / {c['b']} | "
                     f"{_cell(c['test'])} | {_cell(c['confirm'])} | {verdict} |")
    lines += ["", f"![Each claim's median paired difference with its 95 % interval on both "
                  f"seed sets]({fig})"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description="The baselines' evidence of docs/controllers.md on two seed sets.",
        epilog="example: nice python benchmarks/controller_evidence.py --jobs 2")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (1-64)")
    ap.add_argument("--fresh", action="store_true",
                    help="forget the kept confirmation runs and run them again")
    ap.add_argument("--render", action="store_true",
                    help="run nothing: rewrite the claims, figure and section from the kept runs")
    args = ap.parse_args(argv)
    if not 1 <= args.jobs <= 64:
        ap.error(f"--jobs {args.jobs}: outside 1..64")
    from fair_results import claims_figure, splice

    if not args.render:
        run_confirmation(args.jobs, args.fresh)
    found = claims()
    CLAIMS_JSON.write_text(json.dumps(found, indent=1, allow_nan=False) + "\n")
    claims_figure(found, FIGURE)
    PAGE.write_text(splice(PAGE.read_text(), section(found), BEGIN, END))
    print(f"wrote {PAGE.relative_to(ROOT)}, {CLAIMS_JSON.relative_to(ROOT)}, "
          f"{FIGURE.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
