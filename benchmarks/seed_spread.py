"""The paper's four cases over seeds: median and interquartile range of rmse_ss, second
type against first type (issue 13).

Every case runs with its own scenario file (20 s, the paper's gains) for seeds 0-19 under
both controller kinds, as one sweep (``tspend.sweep``), so the run is resumable: the
table is kept at ``--out`` and a second call only runs what is missing.  Per case and
kind it prints the median rmse_ss, its quartiles, and how many seeds miss the case's
steady-state bar (the bounds of ``tests/test_paper_cases.py``); per case, the paired
comparison: in how many seeds the second type has the smaller rmse_ss, and the median
over seeds of first / second.

Run: ``python benchmarks/seed_spread.py`` (``--jobs`` workers, default one per core).
"""

from __future__ import annotations

import argparse

import numpy as np

from tspend import sweep
from short_mode import short_defaults

#: case -> its steady-state bar on rmse_ss (the bounds of tests/test_paper_cases.py)
BARS = {"ex1_nonaffine_case1": 0.12, "ex1_nonaffine_case2": 0.2, "ex2_duffing": 1e-2,
        "ex3_pendulum_ode": 5e-4}
CASES = tuple(BARS)
KINDS = ("second_type", "first_type")


def table(frame) -> str:
    lines = ["| scenario (bar) | type | median rmse_ss | IQR [q25, q75] | seeds over the bar | "
             "second better (paired) | median first/second |",
             "|---|---|---|---|---|---|---|"]
    for case in CASES:
        rows = frame[frame["scenario"] == case]
        by_kind = {k: rows[rows["controller"] == k].set_index("seed")["rmse_ss"].sort_index()
                   for k in KINDS}
        second, first = by_kind["second_type"], by_kind["first_type"]
        paired = second.index.intersection(first.index)
        better = int((second[paired] < first[paired]).sum())
        ratio = float(np.median(first[paired] / second[paired]))
        for kind in KINDS:
            v = by_kind[kind].dropna()
            q25, q50, q75 = np.percentile(v, [25, 50, 75])
            extra = (f"{better}/{len(paired)} | {ratio:.3g}" if kind == "second_type"
                     else " | ")
            over = v[v > BARS[case]]
            which = f" (seeds {', '.join(str(int(s)) for s in over.index)})" if 0 < len(over) <= 3 \
                else ""
            lines.append(f"| {case} ({BARS[case]:g}) | {kind.removesuffix('_type')} | {q50:.3g} | "
                         f"{q75 - q25:.3g} [{q25:.3g}, {q75:.3g}] | {len(over)}/{len(v)}{which} | "
                         f"{extra} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="0:20", help="seeds A:B (default 0:20, i.e. 0-19)")
    ap.add_argument("--jobs", type=int, default=None)
    ap.add_argument("--out", default="runs/seed_spread.parquet",
                    help="the sweep table (resumable; default runs/seed_spread.parquet)")
    short_defaults(ap, seeds="0:2")
    args = ap.parse_args()
    frame = sweep(list(CASES), seeds=args.seeds, controllers=list(KINDS), jobs=args.jobs,
                  out=args.out, record="none", progress=True)
    bad = frame[frame["status"] != "completed"]
    if len(bad):
        print(f"{len(bad)} runs did not complete:")
        print(bad[["scenario", "seed", "controller", "status", "message"]].to_string(index=False))
    print(table(frame))


if __name__ == "__main__":
    main()
