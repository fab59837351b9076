"""compare: a tie is nobody's win, "seed-independent" only for runs alike at every seed,
"every run ended" where they all ended (issue 44, part A)."""

import math

import pandas as pd

from tspend.cli.main import main
from tspend.studies import stats


def frame(rows):
    return pd.DataFrame.from_records(rows, columns=["scenario", "controller", "seed", "status",
                                                    "rmse"])


def _pair_row(md: str) -> str:
    return next(line for line in md.splitlines() if line.startswith("| A vs B | rmse"))


def test_every_run_ended_is_a_tie_not_a_win_nor_seed_independent():
    rows = [("s", k, seed, "fell", 0.3 + 0.1 * seed) for seed in range(6) for k in ("A", "B")]
    comp = stats.compare(frame(rows), ["A", "B"], metrics=["rmse"], n_resamples=999)
    pair = comp.pairs.iloc[0]
    assert pair.ties == 6 and pair.all_ended and not pair.deterministic
    assert math.isnan(pair.p_value) and pair.verdict == ""
    row = _pair_row(stats.markdown(comp))
    assert "none (all tied)" in row and "every run ended" in row
    assert "3/6" not in row and "seed-independent" not in row


def test_partial_ties_are_counted_apart_from_wins():
    a = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    b = [1.0, 2.0, 3.5, 4.5, 4.0, 7.0]   # two ties, A lower on three seeds, higher on one
    rows = [("s", k, seed, "completed", v) for seed in range(6)
            for k, v in (("A", a[seed]), ("B", b[seed]))]
    comp = stats.compare(frame(rows), ["A", "B"], metrics=["rmse"], n_resamples=999)
    pair = comp.pairs.iloc[0]
    assert pair.ties == 2 and pair.b_worse == 3 and pair.a_worse == 1
    assert "| 3/6, 2 tied |" in _pair_row(stats.markdown(comp))


def test_seed_independent_needs_runs_that_did_not_end():
    same = [("s", k, seed, "completed", v) for seed in range(5) for k, v in (("A", 1.0), ("B", 2.0))]
    pair = stats.compare(frame(same), ["A", "B"], metrics=["rmse"], n_resamples=999).pairs.iloc[0]
    assert pair.deterministic and pair.verdict == "A"
    # A ends at every seed, B runs the same at every seed: a statement over seeds, not one
    # observation
    ended = [("s", "A", seed, "fell", 1.0) for seed in range(6)] + \
            [("s", "B", seed, "completed", 2.0) for seed in range(6)]
    comp = stats.compare(frame(ended), ["A", "B"], metrics=["rmse"], n_resamples=999)
    pair = comp.pairs.iloc[0]
    assert not pair.deterministic and not pair.all_ended and not math.isnan(pair.p_value)
    assert "seed-independent" not in stats.markdown(comp)


def test_cli_compare_on_a_short_rail_names_no_winner(capsys):
    main(["compare", "pendulum_mujoco_randomized", "--controller", "pd,pd+cbf",
          "--seeds", "0:3", "--metric", "rmse,violations", "--set", "effects.rail=1.0",
          "--jobs", "1", "--resamples", "100"])
    md = capsys.readouterr().out
    rows = [line for line in md.splitlines() if line.startswith("| pd vs pd+cbf | ")
            and ("rmse" in line or "violations" in line)]
    assert len(rows) == 2
    for row in rows:
        assert "none (all tied)" in row and "every run ended" in row
        assert "wins" not in row and "seed-independent" not in row
