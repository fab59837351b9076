"""tspend.studies.stats against hand-computed cases and scipy's published examples."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from tspend.studies import stats


def frame(rows):
    """A sweep-shaped table from (scenario, controller, seed, status, rmse_ss) tuples."""
    base = dict(message="", version="0.1.0", scenario_hash="h", wall_s=0.1, sim_s=20.0,
                steps=20000)
    return pd.DataFrame.from_records([
        dict(base, scenario=s, controller=k, seed=seed, status=st, rmse_ss=v, rmse=v)
        for s, k, seed, st, v in rows])


# -- Wilcoxon -----------------------------------------------------------------------------
def test_wilcoxon_p_value_of_scipys_published_example():
    # scipy.stats.wilcoxon's documentation (Hollander & Wolfe): differences in height of
    # cross- and self-fertilised plants; exact two-sided p = 0.041259765625 (W = 24)
    d = np.array([6, 8, 14, 16, 23, 24, 28, 29, 41, -48, 49, 56, 60, -67, 75], float)
    b = np.linspace(100.0, 200.0, d.size)
    r = stats.paired_difference(b + d, b, n_resamples=999)
    assert r.p_value == pytest.approx(0.041259765625, abs=1e-15)
    assert r.median_difference == 24.0                      # 8th of the 15 sorted d
    assert r.wins == 2 and r.win_rate == pytest.approx(2 / 15)   # A lower only at -48, -67
    assert r.verdict == "B"                                  # B lower, p < 0.05, CI > 0


def test_wilcoxon_hand_computed_all_one_sign():
    # n = 5, every d < 0: W+ = 0; of the 2^5 equally likely sign patterns under H0 one
    # has W+ = 0 and one W- = 0, so the exact two-sided p = 2/32
    a = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    r = stats.paired_difference(a, a + [0.5, 1.5, 2.5, 3.5, 4.5], n_resamples=999)
    assert r.p_value == pytest.approx(2 / 32)
    assert r.wins == 5
    assert r.verdict == ""            # 0.0625 is not below 0.05: no difference shown


# -- bootstrap ----------------------------------------------------------------------------
def test_bootstrap_interval_covers_true_median_difference_at_its_level():
    # paired differences with a known median 0.3 (symmetric noise around it); over 200
    # independent synthetic studies a 95% interval must cover 0.3 about 95% of the time
    rng = np.random.default_rng(12345)
    true = 0.3
    covered = 0
    studies = 200
    for k in range(studies):
        b = rng.lognormal(0.0, 1.0, 30)
        a = b + true + rng.normal(0.0, 0.5, 30)
        r = stats.paired_difference(a, b, seed=k, n_resamples=2000)
        covered += r.ci_low <= true <= r.ci_high
    assert 0.88 <= covered / studies <= 0.995


def test_bootstrap_interval_is_seeded_and_excludes_a_far_value():
    rng = np.random.default_rng(7)
    b = rng.uniform(1, 2, 25)
    a = b - 1.0 + rng.normal(0, 0.1, 25)
    r1 = stats.paired_difference(a, b, seed=3)
    r2 = stats.paired_difference(a, b, seed=3)
    assert (r1.ci_low, r1.ci_high) == (r2.ci_low, r2.ci_high)
    assert r1.ci_low <= -1.0 + 0.1 and r1.ci_high >= -1.0 - 0.1
    assert r1.ci_high < 0 and r1.verdict == "A"


# -- divergence and failures ----------------------------------------------------------------
def test_quartiles_with_infinite_values_follow_linear_interpolation():
    # positions 0.75, 1.5, 2.25 of [1, 2, 3, inf]: 1.75, 2.5, and 3 + 0.25 (inf - 3) = inf
    assert stats.quartiles([1.0, 2.0, 3.0, math.inf]) == (1.75, 2.5, math.inf)
    assert stats.median([1.0, math.inf, math.inf]) == math.inf
    assert stats.median([1.0, 2.0, math.inf]) == 2.0


def test_a_diverged_run_is_the_worst_outcome_never_dropped():
    rows = []
    for seed in range(10):
        rows.append(("s", "A", seed, "diverged" if seed in (2, 5) else "completed", 0.01))
        rows.append(("s", "B", seed, "completed", 0.02))
    t = frame(rows)
    comp = stats.compare(t, ["A", "B"], metrics=["rmse_ss"], n_resamples=999)
    summ = comp.summary.set_index("controller")
    assert summ.loc["A", "diverged"] == 2 and summ.loc["A", "n"] == 10
    assert summ.loc["A", "median"] == 0.01 and summ.loc["A", "q3"] == 0.01
    # Q3 of [0.01] * 8 + [inf] * 2 sits at position 6.75, among the finite values
    pair = comp.pairs.iloc[0]
    assert pair.pairs == 10 and pair.unpaired == 0
    assert pair.wins == 8 and pair.a_diverged == 2      # the two diverged seeds are losses
    # the Wilcoxon statistic sees the two +inf differences as the largest positive ranks:
    # ranks 9, 10 positive, 1..8 tied negative (all |d| = 0.01 -> mean rank 4.5)
    from scipy.stats import wilcoxon
    d = np.array([-0.01] * 8 + [np.inf] * 2)
    assert pair.p_value == pytest.approx(wilcoxon(d).pvalue)


def test_both_diverged_is_a_tie_and_failed_runs_are_counted_not_paired():
    rows = [("s", "A", 0, "diverged", 1.0), ("s", "B", 0, "diverged", 2.0),
            ("s", "A", 1, "failed", None), ("s", "B", 1, "completed", 0.5),
            ("s", "A", 2, "completed", 0.1), ("s", "B", 2, "completed", 0.3),
            ("s", "A", 3, "completed", 0.2), ("s", "B", 3, "completed", 0.1)]
    comp = stats.compare(frame(rows), metrics=["rmse_ss"], n_resamples=999)
    pair = comp.pairs.iloc[0]
    assert pair.pairs == 3 and pair.unpaired == 1
    assert pair.wins == 0.5 + 1 + 0                      # tie, win, loss
    summ = comp.summary.set_index("controller")
    assert summ.loc["A", "failed"] == 1 and summ.loc["A", "runs"] == 4
    assert summ.loc["A", "n"] == 3                       # diverged kept (as inf), failed out
    md = stats.markdown(comp)
    assert "1 unpaired" in md and "| A | 4 | 0 | 1 (25%) | 1 (25%) |" in md
    json.dumps(stats.to_json(comp), allow_nan=False)     # inf/nan encoded, valid JSON


def test_seed_independent_controllers_are_one_observation_not_a_test():
    rows = [(("s", k, seed, "completed", v)) for seed in range(8)
            for k, v in (("A", 1.0), ("B", 2.0))]
    pair = stats.compare(frame(rows), metrics=["rmse"], n_resamples=999).pairs.iloc[0]
    assert pair.deterministic and math.isnan(pair.p_value)
    assert pair.verdict == "A" and pair.median_difference == -1.0


def test_pairs_are_formed_per_scenario_and_grid_point_by_seed():
    rng = np.random.default_rng(0)
    recs = []
    for scn in ("s1", "s2"):
        for gamma in (0.1, 1.0):
            for seed in (3, 1, 2, 0):   # out of order: pairing is by seed, not position
                for k in ("A", "B"):
                    v = seed + (10.0 if k == "B" and scn == "s2" else 0.0) + rng.uniform(0, .1)
                    recs.append(dict(scenario=scn, controller=k, seed=seed, status="completed",
                                     message="", rmse_ss=v, **{"controller.gamma": gamma}))
    comp = stats.compare(pd.DataFrame.from_records(recs), metrics=["rmse_ss"], n_resamples=999)
    assert comp.group_columns == ["scenario", "controller.gamma"]
    assert len(comp.pairs) == 4 and (comp.pairs.pairs == 4).all()
    s2 = comp.pairs[comp.pairs.scenario == "s2"]
    assert (s2.median_difference.between(-10.1, -9.9)).all() and (s2.wins == 4).all()


def test_unknown_metric_and_duplicate_runs_are_errors():
    t = frame([("s", "A", 0, "completed", 1.0), ("s", "B", 0, "completed", 1.0)])
    with pytest.raises(ValueError, match="unknown metric"):
        stats.compare(t, metrics=["speed"])
    with pytest.raises(ValueError, match="not in the table"):
        stats.compare(t, ["A", "C"])
    dup = pd.concat([t, t])
    with pytest.raises(ValueError, match="more than one run"):
        stats.compare(dup, metrics=["rmse_ss"])


def test_a_consistent_but_tiny_difference_is_flagged_negligible():
    b = np.linspace(1.0, 2.0, 12)
    r = stats.paired_difference(b * 0.998, b, n_resamples=999)
    assert r.verdict == "A" and r.negligible
    r = stats.paired_difference(b * 0.9, b, n_resamples=999)
    assert r.verdict == "A" and not r.negligible


# -- Holm ---------------------------------------------------------------------------------
def test_holm_hand_worked_example():
    # m = 4 p-values; sorted 0.01, 0.02, 0.03, 0.04 scaled by 4, 3, 2, 1: 0.04, 0.06,
    # 0.06, 0.04, then made monotone: 0.04, 0.06, 0.06, 0.06.  nan (no test) stays out of m.
    p = [0.03, math.nan, 0.01, 0.04, 0.02]
    adj = stats.holm(p)
    assert math.isnan(adj[1])
    assert adj[[2, 4, 0, 3]] == pytest.approx([0.04, 0.06, 0.06, 0.06], abs=1e-15)
    assert stats.holm([0.5, 0.9]) == pytest.approx([1.0, 1.0])   # capped at 1
    assert np.isnan(stats.holm([math.nan])).all() and stats.holm([]).size == 0


def test_holm_equals_statsmodels_multipletests():
    multipletests = pytest.importorskip("statsmodels.stats.multitest").multipletests
    rng = np.random.default_rng(3)
    for m in (1, 2, 7, 40):
        p = np.concatenate([rng.uniform(0, 0.05, m // 2), rng.uniform(0, 1, m - m // 2)])
        p[rng.integers(0, m)] = p[0]  # a tie
        reject, expected, _, _ = multipletests(p, alpha=0.05, method="holm")
        got = stats.holm(p)
        assert got == pytest.approx(expected, rel=1e-13, abs=1e-15)
        assert np.array_equal(got < 0.05, reject)


# -- the exact test on outcomes -------------------------------------------------------------
def test_outcome_test_is_the_binomial_on_discordant_seeds():
    from scipy.stats import binomtest

    a = np.array([1, 1, 1, 1, 1, 1, 0, 0, 1, 0], bool)   # A ended badly on 7 seeds
    b = np.array([0, 0, 0, 0, 0, 0, 1, 0, 1, 0], bool)   # B on 2; both on seed 8
    t = stats.outcome_test(a, b)
    assert (t.pairs, t.a_bad, t.b_bad, t.a_only, t.b_only) == (10, 7, 2, 6, 1)
    assert t.p_value == binomtest(6, 7, 0.5).pvalue
    assert t.p_value == pytest.approx(2 * 8 / 128, abs=1e-15)   # P(X<=1)+P(X>=6), n = 7
    assert math.isnan(stats.outcome_test(a, a).p_value)          # no discordant seed


def test_terminations_score_worst_and_enter_the_outcome_test():
    rows = [("s", "A", s, "completed", 1.0 + 0.01 * s) for s in range(8)]
    rows += [("s", "B", s, "fell" if s < 6 else "completed", 0.5) for s in range(8)]
    comp = stats.compare(frame(rows), ["A", "B"], ["rmse_ss"], n_resamples=200)
    pair = comp.pairs.iloc[0]
    assert pair.b_diverged == 6 and pair.a_worse == 2 and pair.b_worse == 6
    assert pair.worst_ratio == pytest.approx(1.07 / 0.5) and pair.best_ratio == 0.0
    out = comp.outcomes.iloc[0]
    assert (out.a_only, out.b_only) == (0, 6) and out.p_value == pytest.approx(2 / 64)
    assert comp.summary.set_index("controller").loc["B", "terminated"] == 6
    md = stats.markdown(comp)
    assert "| A vs B | 8 | 0 | 6 | 0 | 6 |" in md and "6/8 (worst ∞×)" in md


def test_compare_adjusts_every_p_value_of_one_call_and_verdicts_follow_p_holm():
    # two scenarios x 3 kinds x 2 metrics: one Holm family over all rows; a verdict that
    # holds on the raw p but not on p_holm is dropped
    rng = np.random.default_rng(0)
    rows = []
    for scen, shift in (("s1", 0.02), ("s2", 0.5)):
        for seed in range(8):
            base = rng.uniform(1, 2)
            for kind, extra in (("A", 0.0), ("B", shift), ("C", rng.normal(0, 0.3))):
                rows.append(("%s" % scen, kind, seed, "completed", base + extra + 0.01 * seed))
    comp = stats.compare(frame(rows), ["A", "B", "C"], ["rmse_ss", "rmse"], n_resamples=300)
    pairs = comp.pairs
    tested = pairs[~pairs.p_value.isna()]
    assert (tested.p_holm >= tested.p_value - 1e-15).all()
    assert np.allclose(stats.holm(pairs.p_value.to_numpy()), pairs.p_holm, equal_nan=True)
    for r in pairs.itertuples():
        if r.verdict:
            assert r.p_holm < 0.05
    # s1: A vs B with 8 seeds all one sign, p = 2/256 raw; times ~12 tests it no longer holds
    row = pairs[(pairs.scenario == "s1") & (pairs.a == "A") & (pairs.b == "B")].iloc[0]
    assert row.p_value < 0.05 and row.verdict_unadjusted == "A"
    assert row.p_holm > 0.05 and row.verdict == ""


def test_duplicate_scenarios_are_flagged():
    rows = []
    for seed in range(4):
        for k in ("A", "B"):
            v = 1.0 + seed + (k == "B")
            rows += [("ode", k, seed, "completed", v), ("mujoco", k, seed, "completed",
                                                        v * (1 + 1e-14)),
                     ("other", k, seed, "completed", v * (1 + 1e-9))]
    comp = stats.compare(frame(rows), ["A", "B"], ["rmse_ss"], n_resamples=200)
    assert [(d["a"], d["b"], d["runs"]) for d in comp.duplicates] == [("ode", "mujoco", 8)]
    assert "Duplicate experiment:** ode and mujoco" in stats.markdown(comp)
    assert stats.to_json(comp)["duplicates"][0]["a"] == "ode"
