"""Paired statistics over a sweep's rows: which controller is better, and how sure we are.

The input is a sweep table (:func:`tspend.sweep.sweep`): one row per run with
``scenario``, ``controller``, ``seed``, ``status``, every metric and any grid columns.
Runs of two controllers on the same scenario, grid point and seed are a *pair*: they
share the initial draw, the reference and the disturbance, so their difference is the
controllers' alone.  The methods are described in ``docs/statistics.md``:

* per scenario, controller and metric: the median and the quartiles Q1, Q3 over seeds;
* per pair of controllers (A, B) and metric, over the paired seeds: the median of the
  differences ``d = A - B`` with a percentile-bootstrap 95% confidence interval
  (``scipy.stats.bootstrap``, seeded), the median ratio A/B, the win rate of A (ties
  count one half) and the two-sided Wilcoxon signed-rank p-value
  (``scipy.stats.wilcoxon``, zero differences dropped), and a verdict.

Every metric compared here is "lower is better".  How each outcome enters:

* ``completed``: its metric value;
* ``diverged`` and the task's terminations (``fell``, ``rail_end``, ``joint_limit``,
  ``state_bound``): the worst possible value, ``+inf``, for every metric.  The metrics
  of a run that ended early cover only the time before the stop, so its finite values
  would flatter it.  Ranks, medians, quartiles and the Wilcoxon test handle ``+inf`` as "worse than
  any finite value"; a median or quartile that falls on (or between) infinite values is
  ``inf``.  Two runs that both diverged are a tie (``d = 0``);
* ``failed``, ``timeout`` (killed past the sweep's ``--run-timeout``: the machine may have
  been slow) or ``interrupted`` (an exception or a stop: no verdict on the controller):
  left out of the pairs, and counted in the ``failed`` column of the summary and the
  ``unpaired`` column of the pairs, so nothing is dropped silently.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from itertools import combinations
from typing import Any, Iterable, Sequence

import numpy as np

from tspend.loop.metrics import METRIC_KEYS
from tspend.task import TERMINATIONS

#: metrics a comparison can use (all "lower is better"); the rest of METRIC_KEYS
#: describe the run (its length, wall time, seed), not the controller
COMPARED_METRICS = tuple(k for k in METRIC_KEYS
                         if k not in ("wall_s", "sim_s", "steps", "seed", "max_abs_u_command",
                                      "control_energy_command"))
#: what ``tspend compare`` shows unless asked otherwise
DEFAULT_METRICS = ("rmse", "rmse_ss", "max_abs_e_ss", "control_energy", "tv_u_per_s")
#: columns of a sweep row that are not grid values
ROW_COLUMNS = frozenset(("scenario", "controller", "seed", "status", "message", "version",
                         "scenario_hash", "recording", "job_s", "run_key", "wall_s", "sim_s",
                         "steps", "max_abs_u_command", "control_energy_command")
                        + COMPARED_METRICS)
#: outcomes that say nothing about the controller: counted, never paired
NOT_PAIRED = ("failed", "timeout", "interrupted")
#: the task ended the run early (issue 19's terminations): the pole fell, the cart reached
#: the rail's end, a joint its range, a state its bound
TERMINATED = TERMINATIONS
#: outcomes that score +inf (worst) on every metric
#: (a controller that failed, "controller_error", is as bad as one that diverged)
WORST = ("diverged", "controller_error") + TERMINATED
#: outcomes that count as "ended badly" in the paired exact test on outcomes (an
#: interrupted run says nothing about anything: that seed is left out of the test)
BAD = WORST + ("failed", "timeout")
#: two scenarios whose runs agree to this (relative and absolute) on every metric and
#: seed are one experiment counted twice
DUPLICATE_TOL = 1e-12


# -- order statistics that accept +-inf ---------------------------------------------------
def _order_statistic(fn, values: np.ndarray, *args, **kwargs) -> np.ndarray | float:
    """``fn(values)`` (a median, quantile or bootstrap) with +-inf treated as the extreme
    order statistics they are: numpy's interpolation would give nan for inf - inf.

    The infinities are replaced by +-1e300, so they sort last (first); any result beyond
    the largest finite magnitude involved one of them and is mapped back to +-inf.
    """
    values = np.asarray(values, dtype=float)
    finite = values[np.isfinite(values)]
    if finite.size == values.size:
        return fn(values, *args, **kwargs)
    big = 1e300
    bound = float(np.abs(finite).max()) if finite.size else 0.0
    out = np.asarray(fn(np.clip(np.nan_to_num(values, posinf=big, neginf=-big), -big, big),
                        *args, **kwargs), dtype=float)
    out = np.where(out > bound, np.inf, np.where(out < -bound, -np.inf, out))
    return out if out.ndim else float(out)


def median(values: Sequence[float]) -> float:
    return float(_order_statistic(np.median, np.asarray(values, dtype=float)))


def quartiles(values: Sequence[float]) -> tuple[float, float, float]:
    """(Q1, median, Q3), numpy's default (linear) interpolation."""
    q = _order_statistic(np.quantile, np.asarray(values, dtype=float), [0.25, 0.5, 0.75])
    return float(q[0]), float(q[1]), float(q[2])


# -- the rows ------------------------------------------------------------------------------
def grid_columns(table) -> list[str]:
    """The sweep table's grid columns (every column that is not a fixed row column)."""
    from tspend.loop.metrics import is_machine_column

    # the flattened machine metrics (joints.slider.max_abs, plant.M ...) are outcomes
    return [c for c in table.columns if c not in ROW_COLUMNS and not is_machine_column(c)]


def outcome_values(table, metric: str) -> np.ndarray:
    """The metric of each row as a comparison sees it: diverged runs and runs the task
    ended (fell, rail_end ...) ``+inf``, runs that failed or were interrupted ``nan``
    (left out), a completed run's missing value nan."""
    if metric not in COMPARED_METRICS:
        raise ValueError(f"unknown metric {metric!r}; allowed: {', '.join(COMPARED_METRICS)}")
    status = table["status"].to_numpy()
    values = table[metric].to_numpy(dtype=float, na_value=np.nan) if metric in table else \
        np.full(len(table), np.nan)
    values = np.where(np.isin(status, WORST), np.inf, values)
    return np.where(np.isin(status, NOT_PAIRED), np.nan, values)


def _group_columns(table) -> list[str]:
    return ["scenario"] + grid_columns(table)


def _ordered_controllers(table, controllers: Iterable[str] | None) -> list[str]:
    present = list(dict.fromkeys(table["controller"]))
    if controllers is None:
        return present
    wanted = list(dict.fromkeys(controllers))
    missing = [k for k in wanted if k not in present]
    if missing:
        raise ValueError(f"controller(s) {', '.join(missing)} not in the table; it has "
                         f"{', '.join(map(str, present))}")
    return wanted


# -- per controller ------------------------------------------------------------------------
def summarize(table, metrics: Sequence[str] = DEFAULT_METRICS,
              controllers: Iterable[str] | None = None):
    """Median and quartiles per scenario (and grid point), controller and metric.

    One row each, with the counts ``runs``, ``completed``, ``terminated`` (fell,
    rail_end, joint_limit, state_bound), ``diverged``, ``failed`` (failed, timeout or
    interrupted) and, over completed and diverged runs (diverged as ``+inf``),
    ``median``, ``q1``, ``q3``.
    """
    import pandas as pd

    kinds = _ordered_controllers(table, controllers)
    groups = _group_columns(table)
    records = []
    for key, part in table.groupby(groups, sort=False, dropna=False):
        key = key if isinstance(key, tuple) else (key,)
        for kind in kinds:
            rows = part[part["controller"] == kind]
            status = rows["status"].to_numpy()
            counts = dict(runs=len(rows), completed=int((status == "completed").sum()),
                          terminated=int(np.isin(status, TERMINATED).sum()),
                          diverged=int((status == "diverged").sum()),
                          failed=int(np.isin(status, NOT_PAIRED).sum()))
            for metric in metrics:
                v = outcome_values(rows, metric)
                v = v[~np.isnan(v)]
                q1, med, q3 = quartiles(v) if v.size else (math.nan,) * 3
                records.append(dict(zip(groups, key), controller=kind, metric=metric,
                                    **counts, n=int(v.size), median=med, q1=q1, q3=q3))
    return pd.DataFrame.from_records(records)


# -- per pair ------------------------------------------------------------------------------
@dataclass(frozen=True)
class PairedResult:
    """A against B on one metric over the paired seeds (d = A - B; lower is better)."""

    pairs: int                    # seeds where both have a verdict
    unpaired: int                 # seeds where either failed, was interrupted or is missing
    median_difference: float
    ci_low: float
    ci_high: float
    median_ratio: float           # median of A/B per seed
    wins: float                   # seeds where A < B, ties counting one half
    win_rate: float
    p_value: float                # Wilcoxon signed-rank, two-sided; nan when undefined
    deterministic: bool           # A and B the same at every seed: one observation, no test
    verdict: str                  # "A", "B" or "" (no difference shown)
    negligible: bool = False      # a verdict, but the median ratio is within 1 +- negligible
    a_diverged: int = 0           # seeds where A scored +inf (diverged or terminated)
    b_diverged: int = 0
    a_worse: int = 0              # seeds where A > B: "A worse on k of N seeds"
    b_worse: int = 0
    worst_ratio: float = math.nan  # max over seeds of A/B: A's worst seed against B
    best_ratio: float = math.nan   # min over seeds of A/B: B's worst seed is 1 / this
    ties: int = 0                 # seeds where d = 0 (both ended counts as a tie)
    all_ended: bool = False       # every run of both ended (diverged or ended by the task)
    notes: tuple[str, ...] = field(default=())


def _ratio(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        r = a / b
    same = (a == b)  # 0/0 and inf/inf: equal outcomes
    return np.where(same, 1.0, r)


def paired_difference(a: Sequence[float], b: Sequence[float], *, seed: int = 0,
                      n_resamples: int = 9999, confidence: float = 0.95,
                      alpha: float = 0.05, negligible: float = 0.01) -> PairedResult:
    """Compare paired outcomes ``a[i]``, ``b[i]`` (same seed; +inf for a diverged run,
    nan for a run with no verdict, which drops the pair).

    The bootstrap resamples the paired differences (percentile method, ``n_resamples``,
    generator seeded with ``seed``) for the median difference; the Wilcoxon signed-rank
    test drops zero differences (``zero_method="wilcox"``) and is exact for small samples
    without ties, normal-approximated otherwise (scipy's ``method="auto"``).  The verdict
    names the better controller when the p-value is below ``alpha`` *and* the interval
    excludes 0; when neither controller's outcome varies with the seed there is a single
    observation, no test, and the verdict is the sign of that one difference.  A verdict
    whose median ratio A/B lies within ``1 +- negligible`` is flagged ``negligible``: real
    (the same sign at most seeds) but too small to matter.
    """
    from scipy import stats

    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.shape != b.shape:
        raise ValueError(f"paired samples differ in length: {a.size} and {b.size}")
    keep = ~(np.isnan(a) | np.isnan(b))
    unpaired = int((~keep).sum())
    a, b = a[keep], b[keep]
    n = a.size
    nan = math.nan
    if n == 0:
        return PairedResult(0, unpaired, nan, nan, nan, nan, 0.0, nan, nan, False, "")
    both_inf = np.isinf(a) & np.isinf(b) & (np.sign(a) == np.sign(b))
    with np.errstate(invalid="ignore"):
        d = np.where(both_inf, 0.0, a - b)
    wins = float((d < 0).sum() + 0.5 * (d == 0).sum())
    med = median(d)
    # a ratio needs values of one sign; every tspend metric is >= 0
    with np.errstate(divide="ignore"):  # log 0 = -inf: A at 0, or B diverged
        ratios = _ratio(a, b) if (a >= 0).all() and (b >= 0).all() else None
        ratio = float(np.exp(median(np.log(ratios)))) if ratios is not None else nan
    # seed-independent: the same outcome at every seed from runs that did not end (an
    # ended run's +inf says nothing of how alike the runs were)
    finite = bool(np.isfinite(a).all() and np.isfinite(b).all())
    deterministic = finite and (bool(n > 1 and np.all(a == a[0]) and np.all(b == b[0])) or n == 1)
    all_ended = bool(np.isposinf(a).all() and np.isposinf(b).all())
    if np.all(d == 0) and not deterministic:
        # every pair ties: nothing to test and nobody wins
        lo = hi = med
        p = nan
        verdict = ""
    elif deterministic:
        lo = hi = med
        p = nan
        verdict = "A" if med < 0 else "B" if med > 0 else ""
    else:
        if np.all(d == d[0]):
            lo = hi = med
        else:
            with np.errstate(over="ignore", invalid="ignore"):  # its standard error of 1e300s
                ci = _order_statistic(
                    lambda x: np.array(stats.bootstrap(
                        (x,), np.median, n_resamples=n_resamples, confidence_level=confidence,
                        method="percentile", vectorized=True,
                        rng=np.random.default_rng(seed)).confidence_interval), d)
            lo, hi = float(ci[0]), float(ci[1])
        p = float(stats.wilcoxon(d, zero_method="wilcox").pvalue)
        verdict = ""
        if p < alpha and hi < 0:
            verdict = "A"
        elif p < alpha and lo > 0:
            verdict = "B"
    return PairedResult(
        pairs=n, unpaired=unpaired, median_difference=med, ci_low=lo, ci_high=hi,
        median_ratio=ratio, wins=wins, win_rate=wins / n, p_value=p,
        deterministic=deterministic, verdict=verdict,
        negligible=bool(verdict and abs(ratio - 1.0) < negligible),
        a_diverged=int(np.isposinf(a).sum()), b_diverged=int(np.isposinf(b).sum()),
        a_worse=int((d > 0).sum()), b_worse=int((d < 0).sum()),
        worst_ratio=float(ratios.max()) if ratios is not None else nan,
        best_ratio=float(ratios.min()) if ratios is not None else nan,
        ties=int((d == 0).sum()), all_ended=all_ended)


def paired_outcomes(rows, a: str, b: str, metric: str) -> tuple[np.ndarray, np.ndarray, list]:
    """Outcomes of ``a`` and ``b`` aligned by seed within one scenario/grid point (a seed
    one of them lacks is nan on that side, so it counts as unpaired)."""
    import pandas as pd

    values = pd.Series(outcome_values(rows, metric), index=rows.index)
    frame = pd.DataFrame({"seed": rows["seed"].to_numpy(),
                          "controller": rows["controller"].to_numpy(), "v": values.to_numpy()})
    if frame.duplicated(["seed", "controller"]).any():
        raise ValueError("more than one run per seed and controller in one scenario/grid "
                         "point: cannot pair them")
    wide = frame.pivot(index="seed", columns="controller", values="v")
    wide = wide.reindex(columns=[a, b])
    wide = wide.sort_index()
    return wide[a].to_numpy(dtype=float), wide[b].to_numpy(dtype=float), list(wide.index)


# -- multiple comparisons -----------------------------------------------------------------
def holm(p_values: Sequence[float]) -> np.ndarray:
    """Holm's step-down adjusted p-values (Holm 1979), controlling the family-wise error.

    With the m defined p-values sorted, ``p_(1) <= .. <= p_(m)``, the adjusted value of
    the i-th is ``max_{j <= i} min(1, (m - j + 1) p_(j))``.  A nan (no test was made:
    a seed-independent pair) stays nan and is not counted in m.  Rejecting where the
    adjusted value is below alpha rejects exactly what Holm's procedure rejects at alpha.
    """
    p = np.asarray(p_values, dtype=float)
    out = np.full(p.shape, np.nan)
    defined = np.flatnonzero(~np.isnan(p))
    m = defined.size
    if m == 0:
        return out
    order = defined[np.argsort(p[defined], kind="stable")]
    scaled = np.minimum(1.0, (m - np.arange(m)) * p[order])
    out[order] = np.maximum.accumulate(scaled)
    return out


# -- outcomes: which runs ended badly --------------------------------------------------------
@dataclass(frozen=True)
class OutcomeTest:
    """A against B on "ended badly" (fell, rail_end, joint_limit, state_bound, diverged or
    failed) over the paired seeds: McNemar's exact test, i.e. the two-sided binomial test
    of the discordant pairs against 1/2."""

    pairs: int                    # seeds with an outcome on both sides (not interrupted)
    a_bad: int                    # seeds where A ended badly
    b_bad: int
    a_only: int                   # discordant: A ended badly, B did not
    b_only: int                   # discordant: B ended badly, A did not
    p_value: float                # nan when there is no discordant pair (nothing to test)


def outcome_test(a_bad: Sequence[bool], b_bad: Sequence[bool]) -> OutcomeTest:
    """McNemar's exact test on paired binary outcomes (True: the run ended badly).

    Only discordant seeds carry information: under the null hypothesis (A and B end badly
    equally often) each discordant seed is A's with probability 1/2, so the number of
    A-only seeds is Binomial(a_only + b_only, 1/2); the p-value is the two-sided exact
    binomial (``scipy.stats.binomtest``).  No discordant seed: no test (p = nan).
    """
    from scipy import stats

    a = np.asarray(a_bad, dtype=bool)
    b = np.asarray(b_bad, dtype=bool)
    if a.shape != b.shape:
        raise ValueError(f"paired outcomes differ in length: {a.size} and {b.size}")
    a_only, b_only = int((a & ~b).sum()), int((b & ~a).sum())
    discordant = a_only + b_only
    p = float(stats.binomtest(a_only, discordant, 0.5).pvalue) if discordant else math.nan
    return OutcomeTest(pairs=int(a.size), a_bad=int(a.sum()), b_bad=int(b.sum()),
                       a_only=a_only, b_only=b_only, p_value=p)


def paired_status(rows, a: str, b: str) -> tuple[np.ndarray, np.ndarray]:
    """Whether each paired seed's run of ``a`` and of ``b`` ended badly (seeds where either
    is missing or was interrupted are left out)."""
    status = {k: dict(zip(rows.loc[rows["controller"] == k, "seed"],
                          rows.loc[rows["controller"] == k, "status"])) for k in (a, b)}
    seeds = sorted(s for s in status[a] if s in status[b]
                   and "interrupted" not in (status[a][s], status[b][s]))
    return (np.array([status[a][s] in BAD for s in seeds], dtype=bool),
            np.array([status[b][s] in BAD for s in seeds], dtype=bool))


# -- duplicate experiments -----------------------------------------------------------------
def find_duplicates(table, tol: float = DUPLICATE_TOL) -> list[dict]:
    """Pairs of scenarios (at one grid point) that are one experiment counted twice: the
    same controllers and seeds, the same status on every run and every metric equal to
    ``tol`` (``|x - y| <= tol (1 + |y|)``; nan equals nan).  Each entry:
    ``{"a", "b", grid values..., "runs"}``."""
    metrics = [m for m in COMPARED_METRICS if m in table.columns]
    grid = grid_columns(table)
    found = []
    parts = table.groupby(grid, sort=False, dropna=False) if grid else [((), table)]
    for key, part in parts:
        key = key if isinstance(key, tuple) else (key,)
        frames = {}
        for scen, rows in part.groupby("scenario", sort=False):
            rows = rows.sort_values(["controller", "seed"])
            frames[scen] = (list(zip(rows["controller"], rows["seed"])),
                            rows["status"].to_numpy(), rows[metrics].to_numpy(dtype=float,
                                                                                na_value=np.nan))
        for a, b in combinations(frames, 2):
            ka, sa, va = frames[a]
            kb, sb, vb = frames[b]
            if ka != kb or not ka or not np.array_equal(sa, sb):
                continue
            same = (np.abs(va - vb) <= tol * (1.0 + np.abs(vb))) | (np.isnan(va) & np.isnan(vb))
            with np.errstate(invalid="ignore"):
                same |= (va == vb)  # the same infinity
            if same.all():
                found.append(dict(a=str(a), b=str(b), **dict(zip(grid, key)), runs=len(ka)))
    return found


@dataclass
class Comparison:
    """What :func:`compare` found: one summary row per controller and metric, one pairs
    row per pair of controllers and metric, per scenario and grid point."""

    summary: Any                  # pandas.DataFrame
    pairs: Any                    # pandas.DataFrame
    controllers: list[str]
    metrics: list[str]
    group_columns: list[str]
    settings: dict
    outcomes: Any = None          # pandas.DataFrame: per pair the exact test on outcomes
    duplicates: list = field(default_factory=list)   # find_duplicates(table)


def compare(table, controllers: Iterable[str] | None = None,
            metrics: Sequence[str] = DEFAULT_METRICS, *, seed: int = 0,
            n_resamples: int = 9999, confidence: float = 0.95, alpha: float = 0.05,
            negligible: float = 0.01,
            pairs: Sequence[tuple[str, str]] | None = None) -> Comparison:
    """Every pair of ``controllers`` (in the order given: A before B) on every scenario
    and grid point of ``table``, on every metric.  ``pairs`` restricts the pairs.

    The p-values of one call (every pair, metric, scenario and grid point, and every
    pair's exact test on outcomes) are one family: ``p_holm`` is Holm's adjustment over
    it, and the verdicts use ``p_holm`` (``verdict_unadjusted`` is what the raw p-value
    would have said).
    """
    import pandas as pd

    if len(table) == 0:
        raise ValueError("the table has no rows")
    for m in metrics:
        if m not in COMPARED_METRICS:
            raise ValueError(f"unknown metric {m!r}; allowed: {', '.join(COMPARED_METRICS)}")
    kinds = _ordered_controllers(table, controllers)
    pair_list = list(pairs) if pairs is not None else list(combinations(kinds, 2))
    groups = _group_columns(table)
    summary = summarize(table, metrics, kinds)
    records, outcome_records = [], []
    for key, part in table.groupby(groups, sort=False, dropna=False):
        key = key if isinstance(key, tuple) else (key,)
        for a, b in pair_list:
            t = outcome_test(*paired_status(part, a, b))
            outcome_records.append(dict(zip(groups, key), a=a, b=b, **t.__dict__))
            for metric in metrics:
                va, vb, _ = paired_outcomes(part, a, b, metric)
                r = paired_difference(va, vb, seed=seed, n_resamples=n_resamples,
                                      confidence=confidence, alpha=alpha,
                                      negligible=negligible)
                rec = dict(zip(groups, key), a=a, b=b, metric=metric)
                rec.update({k: getattr(r, k) for k in PairedResult.__dataclass_fields__
                            if k != "notes"})
                records.append(rec)
    pair_frame = pd.DataFrame.from_records(records)
    outcomes = pd.DataFrame.from_records(outcome_records)
    n_rows = len(pair_frame)
    family = np.concatenate([pair_frame["p_value"].to_numpy(dtype=float) if n_rows else [],
                             outcomes["p_value"].to_numpy(dtype=float) if len(outcomes) else []])
    adjusted = holm(family)
    if n_rows:
        pair_frame.insert(pair_frame.columns.get_loc("p_value") + 1, "p_holm", adjusted[:n_rows])
        raw = pair_frame["verdict"].to_numpy(dtype=object)
        pair_frame["verdict_unadjusted"] = [
            {"A": a, "B": b}.get(v, "") for v, a, b in zip(raw, pair_frame["a"], pair_frame["b"])]
        pair_frame["verdict"] = [
            _holm_verdict(r, alpha) for r in pair_frame.itertuples(index=False)]
        pair_frame["negligible"] = [
            bool(v and abs(r - 1.0) < negligible)
            for v, r in zip(pair_frame["verdict"], pair_frame["median_ratio"])]
    if len(outcomes):
        outcomes["p_holm"] = adjusted[n_rows:]
        outcomes["verdict"] = [
            (r.b if r.a_only > r.b_only else r.a) if r.p_holm < alpha else ""
            for r in outcomes.itertuples(index=False)]
    return Comparison(summary=summary, pairs=pair_frame,
                      controllers=kinds, metrics=list(metrics), group_columns=groups,
                      settings=dict(seed=seed, n_resamples=n_resamples,
                                    confidence=confidence, alpha=alpha, negligible=negligible,
                                    bootstrap="percentile", test="wilcoxon signed-rank, "
                                    "two-sided, zero differences dropped",
                                    correction=f"holm over {int((~np.isnan(family)).sum())} "
                                               "p-values (every pair, metric, scenario and "
                                               "outcome test of this call)",
                                    outcome_test="mcnemar exact (two-sided binomial on "
                                                 "discordant seeds)",
                                    diverged="+inf (worst), as fell, rail_end, joint_limit, "
                                             "state_bound",
                                    failed="left out, counted"),
                      outcomes=outcomes, duplicates=find_duplicates(table))


def _holm_verdict(r, alpha: float) -> str:
    """The better kind by the adjusted p-value: p_holm < alpha and the interval on one
    side of 0; a seed-independent pair keeps the sign of its one difference."""
    if r.deterministic:
        return {"A": r.a, "B": r.b}.get(r.verdict, "")
    if r.p_holm < alpha and r.ci_high < 0:
        return r.a
    if r.p_holm < alpha and r.ci_low > 0:
        return r.b
    return ""


# -- presentation --------------------------------------------------------------------------
def fmt(v: float, digits: int = 3) -> str:
    """A number in ``digits`` significant figures; inf as ∞, nan as n/a."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "n/a"
    if math.isinf(v):
        return "∞" if v > 0 else "-∞"
    if v == 0:
        return "0"
    return f"{v:.{digits}g}"


def fmt_ratio(v: float) -> str:
    """A ratio near 1 with three decimals (1.004), otherwise three significant figures."""
    if v is None or math.isnan(v) or math.isinf(v) or not 0.1 <= v < 10:
        return fmt(v)
    return f"{v:.3f}"


def _fmt_p(p: float) -> str:
    if p is None or math.isnan(p):
        return "n/a"
    return "<1e-4" if p < 1e-4 else f"{p:.2g}"


def _group_title(row, groups: list[str]) -> str:
    parts = [str(row["scenario"])]
    parts += [f"{g} = {row[g]}" for g in groups[1:]]
    return ", ".join(parts)


def _select(frame, groups: list[str], key: dict):
    sel = np.ones(len(frame), bool)
    for g in groups:
        sel &= (frame[g] == key[g]).to_numpy()
    return frame[sel]


def _share(k: int, n: int) -> str:
    return f"{k} ({100.0 * k / n:.0f}%)" if n and k else str(k)


def _tail(k: int, n: int, worst: float) -> str:
    """"3/20 (worst 13.6×)": seeds where a side was worse, and its worst seed's ratio."""
    if not k:
        return f"0/{n}"
    return f"{k}/{n} (worst {fmt_ratio(worst)}×)"


def _wins(r) -> str:
    """"5/8": seeds where A was lower; with ties "2/8, 3 tied"; "none (all tied)" when every
    pair ties (a tie is nobody's win)."""
    ties = int(getattr(r, "ties", 0))
    if not r.pairs:
        return "0/0"
    if ties == r.pairs:
        return "none (all tied)"
    if ties:
        return f"{r.b_worse}/{r.pairs}, {ties} tied"
    return f"{r.wins:g}/{r.pairs}"


def markdown(comp: Comparison, seeds_text: str = "") -> str:
    """The comparison as Markdown: per scenario (and grid point) a table of median
    [Q1, Q3] per controller and metric with the share of runs that ended badly, the
    exact test on outcomes per pair, then one table of paired verdicts per pair."""
    lines: list[str] = []
    groups = comp.group_columns
    summary, pairs = comp.summary, comp.pairs
    family = comp.settings.get("correction", "")
    for dup in comp.duplicates:
        where = ", ".join(f"{g} = {dup[g]}" for g in groups[1:] if g in dup)
        lines.append(f"> **Duplicate experiment:** {dup['a']} and {dup['b']}"
                     + (f" ({where})" if where else "") + f" agree to {DUPLICATE_TOL:g} on "
                     f"every metric of all {dup['runs']} runs: one experiment, counted twice "
                     "(the Holm family is larger than it should be, so p_holm is conservative).")
        lines.append("")
    keys = summary[groups].drop_duplicates().to_dict("records")
    for key in keys:
        part = _select(summary, groups, key)
        lines.append(f"### {_group_title(key, groups)}" + (f" (seeds {seeds_text})" if seeds_text else ""))
        lines.append("")
        lines.append("Median [Q1, Q3] over seeds; a run that diverged or was ended by the task "
                     "(fell, rail_end, joint_limit, state_bound) counts as ∞ (worst); a failed "
                     "run is left out.")
        lines.append("")
        lines.append("| controller | runs | ended (task) | diverged | failed | "
                     + " | ".join(comp.metrics) + " |")
        lines.append("|---|---:|---:|---:|---:|" + "---:|" * len(comp.metrics))
        for kind in comp.controllers:
            rows = part[part["controller"] == kind].set_index("metric")
            if rows.empty:
                continue
            first = rows.iloc[0]
            cells = [f"{fmt(r['median'])} [{fmt(r['q1'])}, {fmt(r['q3'])}]"
                     for r in (rows.loc[m] for m in comp.metrics)]
            n = int(first.runs)
            lines.append(f"| {kind} | {n} | {_share(int(first.terminated), n)} | "
                         f"{_share(int(first.diverged), n)} | {_share(int(first.failed), n)} | "
                         + " | ".join(cells) + " |")
        lines.append("")
        if pairs.empty:  # one controller: nothing to pair
            continue
        outcomes = _select(comp.outcomes, groups, key) if comp.outcomes is not None else None
        if outcomes is not None and len(outcomes) and (outcomes["a_bad"] + outcomes["b_bad"]).any():
            lines.append("Runs that ended badly (ended by the task, diverged or failed), paired "
                         "by seed; p: McNemar's exact test (binomial on the discordant seeds), "
                         "p_holm: Holm-adjusted.")
            lines.append("")
            lines.append("| A vs B | pairs | A bad | B bad | only A | only B | p | p_holm | fewer |")
            lines.append("|---|---:|---:|---:|---:|---:|---:|---:|---|")
            for r in outcomes.itertuples():
                lines.append(f"| {r.a} vs {r.b} | {r.pairs} | {r.a_bad} | {r.b_bad} | {r.a_only} "
                             f"| {r.b_only} | {_fmt_p(r.p_value)} | {_fmt_p(r.p_holm)} | "
                             f"{r.verdict or '—'} |")
            lines.append("")
        ppart = _select(pairs, groups, key)
        if ppart.empty:
            continue
        lines.append("Paired by seed, d = A − B (negative: A lower, better); "
                     "95% bootstrap CI of the median d; p: Wilcoxon signed-rank; p_holm: "
                     f"Holm-adjusted ({family}), which the verdict uses; A worse / B worse: on "
                     "how many seeds, and the ratio on that side's worst seed.")
        lines.append("")
        lines.append("| A vs B | metric | pairs | median d [95% CI] | median A/B | A wins | "
                     "A worse | B worse | p | p_holm | better |")
        lines.append("|---|---|---:|---|---:|---:|---|---|---:|---:|---|")
        for r in ppart.itertuples():
            extra = []
            if r.unpaired:
                extra.append(f"{r.unpaired} unpaired")
            if r.deterministic:
                extra.append("seed-independent: one observation")
            if getattr(r, "all_ended", False):
                extra.append("every run ended")
            elif r.ties == r.pairs and r.pairs:
                extra.append("every pair tied")
            p = _fmt_p(r.p_value) + (f" ({'; '.join(extra)})" if extra else "")
            b_worst = 1.0 / r.best_ratio if r.best_ratio else math.inf
            lines.append(f"| {r.a} vs {r.b} | {r.metric} | {r.pairs} | {fmt(r.median_difference)} "
                         f"[{fmt(r.ci_low)}, {fmt(r.ci_high)}] | {fmt_ratio(r.median_ratio)} | "
                         f"{_wins(r)} | {_tail(r.a_worse, r.pairs, r.worst_ratio)} | "
                         f"{_tail(r.b_worse, r.pairs, b_worst)} | {p} | {_fmt_p(r.p_holm)} | "
                         f"{verdict_text(r)} |")
        lines.append("")
    return "\n".join(lines)


def verdict_text(r) -> str:
    """``second_type``, ``second_type (negligible)`` or ``—``."""
    if not r.verdict:
        return "—"
    return f"{r.verdict} (negligible)" if r.negligible else r.verdict


def json_number(v: Any) -> Any:
    """JSON has no infinity: +-inf become the strings "inf" / "-inf", nan null."""
    if isinstance(v, (float, np.floating)):
        v = float(v)
        if math.isnan(v):
            return None
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return v
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, np.bool_):
        return bool(v)
    return v


def to_json(comp: Comparison) -> dict:
    """The comparison as plain JSON types (infinities as the strings "inf", "-inf")."""
    def records(df):
        return [{k: json_number(v) for k, v in rec.items()} for rec in df.to_dict("records")]

    outcomes = comp.outcomes if comp.outcomes is not None else None
    return {"controllers": comp.controllers, "metrics": comp.metrics,
            "group_columns": comp.group_columns, "settings": comp.settings,
            "summary": records(comp.summary), "pairs": records(comp.pairs),
            "outcomes": records(outcomes) if outcomes is not None else [],
            "duplicates": [{k: json_number(v) for k, v in d.items()} for d in comp.duplicates]}
