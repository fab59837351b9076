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
* ``diverged``: the worst possible value, ``+inf``, for every metric.  The metrics of a
  diverged run cover only the time before the stop, so its finite values would flatter
  it.  Ranks, medians, quartiles and the Wilcoxon test handle ``+inf`` as "worse than
  any finite value"; a median or quartile that falls on (or between) infinite values is
  ``inf``.  Two runs that both diverged are a tie (``d = 0``);
* ``failed`` or ``interrupted`` (an exception or a stop: no verdict on the controller):
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
COMPARED_METRICS = tuple(k for k in METRIC_KEYS if k not in ("wall_s", "sim_s", "steps", "seed"))
#: what ``tspend compare`` shows unless asked otherwise
DEFAULT_METRICS = ("rmse", "rmse_ss", "max_abs_e_ss", "control_energy", "tv_u_per_s")
#: columns of a sweep row that are not grid values
ROW_COLUMNS = frozenset(("scenario", "controller", "seed", "status", "message", "version",
                         "scenario_hash", "recording", "job_s", "run_key", "wall_s", "sim_s",
                         "steps") + COMPARED_METRICS)
#: outcomes that say nothing about the controller: counted, never paired
NOT_PAIRED = ("failed", "interrupted")
#: outcomes that are the controller's failure, ranked worst (+inf): a divergence, or the
#: task ending the run (the pole fell, the cart left the rail ...: tspend.task.TERMINATIONS)
ENDED_EARLY = ("diverged",) + TERMINATIONS


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
    values = np.where(np.isin(status, ENDED_EARLY), np.inf, values)
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

    One row each, with the counts ``runs``, ``completed``, ``diverged`` (diverged, or
    ended by the task: fell, rail_end ...), ``failed`` (failed or interrupted) and, over
    completed and diverged runs (diverged as ``+inf``),
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
                          diverged=int(np.isin(status, ENDED_EARLY).sum()),
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
    a_diverged: int = 0
    b_diverged: int = 0
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
        ratio = (float(np.exp(median(np.log(_ratio(a, b))))) if (a >= 0).all()
                 and (b >= 0).all() else nan)
    deterministic = bool(n > 1 and np.all(a == a[0]) and np.all(b == b[0])) or n == 1
    if deterministic:
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
        p = 1.0 if np.all(d == 0) else float(stats.wilcoxon(d, zero_method="wilcox").pvalue)
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
        a_diverged=int(np.isposinf(a).sum()), b_diverged=int(np.isposinf(b).sum()))


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


def compare(table, controllers: Iterable[str] | None = None,
            metrics: Sequence[str] = DEFAULT_METRICS, *, seed: int = 0,
            n_resamples: int = 9999, confidence: float = 0.95, alpha: float = 0.05,
            negligible: float = 0.01,
            pairs: Sequence[tuple[str, str]] | None = None) -> Comparison:
    """Every pair of ``controllers`` (in the order given: A before B) on every scenario
    and grid point of ``table``, on every metric.  ``pairs`` restricts the pairs."""
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
    records = []
    for key, part in table.groupby(groups, sort=False, dropna=False):
        key = key if isinstance(key, tuple) else (key,)
        for a, b in pair_list:
            for metric in metrics:
                va, vb, _ = paired_outcomes(part, a, b, metric)
                r = paired_difference(va, vb, seed=seed, n_resamples=n_resamples,
                                      confidence=confidence, alpha=alpha,
                                      negligible=negligible)
                rec = dict(zip(groups, key), a=a, b=b, metric=metric)
                rec.update({k: getattr(r, k) for k in PairedResult.__dataclass_fields__
                            if k != "notes"})
                rec["verdict"] = {"A": a, "B": b}.get(r.verdict, "")
                records.append(rec)
    return Comparison(summary=summary, pairs=pd.DataFrame.from_records(records),
                      controllers=kinds, metrics=list(metrics), group_columns=groups,
                      settings=dict(seed=seed, n_resamples=n_resamples,
                                    confidence=confidence, alpha=alpha, negligible=negligible,
                                    bootstrap="percentile", test="wilcoxon signed-rank, "
                                    "two-sided, zero differences dropped",
                                    diverged="+inf (worst)", failed="left out, counted"))


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


def markdown(comp: Comparison, seeds_text: str = "") -> str:
    """The comparison as Markdown: per scenario (and grid point) a table of median
    [Q1, Q3] per controller and metric, then one table of paired verdicts per pair."""
    lines: list[str] = []
    groups = comp.group_columns
    summary, pairs = comp.summary, comp.pairs
    keys = summary[groups].drop_duplicates().to_dict("records")
    for key in keys:
        sel = np.ones(len(summary), bool)
        for g in groups:
            sel &= (summary[g] == key[g]).to_numpy()
        part = summary[sel]
        lines.append(f"### {_group_title(key, groups)}" + (f" (seeds {seeds_text})" if seeds_text else ""))
        lines.append("")
        lines.append("Median [Q1, Q3] over seeds; a diverged run counts as ∞ (worst).")
        lines.append("")
        lines.append("| controller | runs | diverged | failed | " + " | ".join(comp.metrics) + " |")
        lines.append("|---|---:|---:|---:|" + "---:|" * len(comp.metrics))
        for kind in comp.controllers:
            rows = part[part["controller"] == kind].set_index("metric")
            if rows.empty:
                continue
            first = rows.iloc[0]
            cells = [f"{fmt(r['median'])} [{fmt(r['q1'])}, {fmt(r['q3'])}]"
                     for r in (rows.loc[m] for m in comp.metrics)]
            lines.append(f"| {kind} | {first.runs} | {first.diverged} | {first.failed} | "
                         + " | ".join(cells) + " |")
        lines.append("")
        if pairs.empty:  # one controller: nothing to pair
            continue
        psel = np.ones(len(pairs), bool)
        for g in groups:
            psel &= (pairs[g] == key[g]).to_numpy()
        ppart = pairs[psel]
        if ppart.empty:
            continue
        lines.append("Paired by seed, d = A − B (negative: A lower, better); "
                     "95% bootstrap CI of the median d; p: Wilcoxon signed-rank.")
        lines.append("")
        lines.append("| A vs B | metric | pairs | median d [95% CI] | median A/B | A wins | p | better |")
        lines.append("|---|---|---:|---|---:|---:|---:|---|")
        for r in ppart.itertuples():
            extra = []
            if r.unpaired:
                extra.append(f"{r.unpaired} unpaired")
            if r.deterministic:
                extra.append("seed-independent: one observation")
            p = _fmt_p(r.p_value) + (f" ({'; '.join(extra)})" if extra else "")
            lines.append(f"| {r.a} vs {r.b} | {r.metric} | {r.pairs} | {fmt(r.median_difference)} "
                         f"[{fmt(r.ci_low)}, {fmt(r.ci_high)}] | {fmt_ratio(r.median_ratio)} | "
                         f"{r.wins:g}/{r.pairs} | {p} | {verdict_text(r)} |")
        lines.append("")
    return "\n".join(lines)


def verdict_text(r) -> str:
    """``second_type``, ``second_type (negligible)`` or ``—``."""
    if not r.verdict:
        return "—"
    return f"{r.verdict} (negligible)" if r.negligible else r.verdict


def _json_number(v: Any) -> Any:
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
        return [{k: _json_number(v) for k, v in rec.items()} for rec in df.to_dict("records")]

    return {"controllers": comp.controllers, "metrics": comp.metrics,
            "group_columns": comp.group_columns, "settings": comp.settings,
            "summary": records(comp.summary), "pairs": records(comp.pairs)}
