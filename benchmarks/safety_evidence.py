"""The CBF safety filter's evidence at a glance (docs/safety.md): a verdict table on two
seed sets and one figure, from benchmarks/safety_filter.py's kept runs.

    python benchmarks/safety_filter.py                      # seeds 0-19 (the test set)
    python benchmarks/safety_filter.py --first-seed 200     # seeds 200-219 (confirmation)
    python benchmarks/safety_evidence.py                    # the table, figure and section

For each machine and kind, bare against behind the filter (barrier (S1), ``hocbf``) on the
same seeds: the runs the task ended (McNemar's exact test on the paired outcomes, Holm's
correction over every test of the seed set: :func:`tspend.studies.stats.compare`) and the
samples outside a constraint behind the filter. A claim is "shown" only when both seed
sets say it: fewer runs ended behind the filter with Holm p < 0.05, or 0 samples outside
on every filtered run. tools/check_claims.py rebuilds the section from the CSVs.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
PAGE = ROOT / "docs" / "safety.md"
FIGURE = ROOT / "docs" / "results" / "figures" / "safety_claims.png"
BEGIN = "<!-- benchmarks/safety_evidence.py: begin (generated; rerun it, do not edit) -->"
END = "<!-- benchmarks/safety_evidence.py: end -->"
MACHINES = {"cartpole_rail": "cart-pole, rail 1 m, randomised", "furuta_arm": "Furuta, arm stop"}
#: (name, first seed, the CSV's suffix): the test set, then the confirmation set
SEED_SETS = (("0-19", 0, ""), ("200-219", 200, "_seeds200"))


def tables():
    """Per seed set, every machine's runs (the benchmark's CSVs), one table."""
    import pandas as pd

    out = []
    for _, _, suffix in SEED_SETS:
        parts = [pd.read_csv(RESULTS / f"safety_filter_{m}_hocbf{suffix}.csv") for m in MACHINES]
        out.append(pd.concat(parts, ignore_index=True))
    return out


def verdicts(table) -> dict:
    """(machine, kind) -> ended bare, ended filtered, runs, Holm p, samples outside filtered."""
    from tspend.studies.stats import compare

    # only what is compared: any other column would be read as a grid point
    table = table[["scenario", "controller", "seed", "status", "rmse", "violations"]]
    kinds = [k for k in dict.fromkeys(table.controller) if not k.endswith("+cbf")]
    comp = compare(table, [n for k in kinds for n in (k + "+cbf", k)], ("rmse", "violations"),
                   n_resamples=999, pairs=[(k + "+cbf", k) for k in kinds])
    found = {}
    for r in comp.outcomes.itertuples():
        if not r.pairs:  # a kind this machine does not run (no policy for the Furuta)
            continue
        part = table[(table.scenario == r.scenario) & (table.controller == r.a)]
        found[(r.scenario, r.b)] = {"bare": int(r.b_bad), "filtered": int(r.a_bad),
                                    "runs": int(r.pairs), "p_holm": float(r.p_holm),
                                    "outside": int(part.violations.sum())}
    return found


def claims() -> list[dict]:
    """Each (machine, kind): its figures on both sets and the two verdicts."""
    sets = [verdicts(t) for t in tables()]
    rows = []
    for key in sets[0]:
        both = [s.get(key) for s in sets]
        fewer = all(v and v["filtered"] < v["bare"] and v["p_holm"] < 0.05 for v in both)
        inside = all(v and v["outside"] == 0 for v in both)
        rows.append({"machine": key[0], "kind": key[1], "sets": both, "fewer_ended": fewer,
                     "none_outside": inside})
    return rows


def _cell(v: dict | None) -> str:
    from tspend.studies.stats import _fmt_p

    if not v:
        return "—"
    return (f"{v['bare']}/{v['runs']} → {v['filtered']}/{v['runs']} (p {_fmt_p(v['p_holm'])}); "
            f"outside {v['outside']}")


def section(rows: list[dict]) -> str:
    import os

    fig = Path(os.path.relpath(FIGURE, PAGE.parent)).as_posix()
    names = [s[0] for s in SEED_SETS]
    lines = ["Runs the task ended, bare → behind the filter (S1) on the same seeds (McNemar's "
             "exact test, p Holm-adjusted over each set's family: every pair's outcome, rmse "
             "and violations tests; n/a: no seed ended differently), and the samples outside "
             "a constraint over the filtered runs. Shown only when both seed sets say it.", "",
             f"| machine | kind | seeds {names[0]} | seeds {names[1]} | fewer runs ended? | "
             f"0 samples outside? |", "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {MACHINES[r['machine']]} | `{r['kind']}` | {_cell(r['sets'][0])} | "
                     f"{_cell(r['sets'][1])} | {'**shown**' if r['fewer_ended'] else 'not shown'}"
                     f" | {'**shown**' if r['none_outside'] else 'not shown'} |")
    lines += ["", f"![Runs ended, bare and filtered, per machine and kind, both seed "
                  f"sets]({fig})"]
    return "\n".join(lines)


def figure(rows: list[dict]) -> Path:
    """Runs ended bare and behind the filter, per machine and kind, on both seed sets."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 3.2), constrained_layout=True)
    labels, width = [], 0.2
    for i, r in enumerate(rows):
        labels.append(f"{r['machine']}\n{r['kind']}")
        for j, (name, v) in enumerate(zip([s[0] for s in SEED_SETS], r["sets"])):
            if v:
                x = i + (j - 0.5) * 2 * width
                ax.bar(x - width / 2, v["bare"], width, color="0.6",
                       label="bare" if i == j == 0 else None)
                ax.bar(x + width / 2, v["filtered"], width, color="C0",
                       label="filtered (S1)" if i == j == 0 else None)
                ax.text(x, max(v["bare"], v["filtered"]) + 0.3, name, ha="center", fontsize=6)
    ax.set_xticks(range(len(rows)), labels, fontsize=7)
    ax.set_ylabel("runs the task ended (of 20)")
    ax.legend(fontsize=7)
    FIGURE.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGURE, dpi=110)
    plt.close(fig)
    return FIGURE


def main(argv: list[str] | None = None) -> int:
    argparse.ArgumentParser(
        description="docs/safety.md's verdict table and figure from the kept runs of "
                    "benchmarks/safety_filter.py (seeds 0-19 and 200-219); no option.",
        epilog="example: python benchmarks/safety_evidence.py").parse_args(argv)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from fair_results import splice

    rows = claims()
    figure(rows)
    PAGE.write_text(splice(PAGE.read_text(), section(rows), BEGIN, END))
    print(f"wrote {PAGE.relative_to(ROOT)} and {FIGURE.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
