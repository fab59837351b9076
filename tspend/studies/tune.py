"""Tuning a controller kind on a scenario with Optuna, and the equal-budget comparison.

:func:`tune` searches the kind's declared space (``SEARCH`` on its settings class, the
paper's :data:`tspend.controllers.settings.PAPER_SEARCH`; see
:class:`tspend.controllers.settings.Search`) with a seeded TPE sampler.  Each trial runs
the kind on every training seed, through the sweep's executors (a local pool or Dask),
and scores the **median of the metric over the training seeds**, a run that fell, ended
on the rail or a joint limit, diverged or failed scoring ``+inf`` (worst), as in
:mod:`tspend.studies.stats`.  Trials are asked one at a time: TPE's next choice depends
on every earlier score, so the study, and the tuned value, are the same on any executor
and number of workers; a trial's seeds run in parallel.  With a ``storage`` (an Optuna
RDB URL such as ``sqlite:///tune.db``, or a path: a journal file) the study is resumable:
the same call counts the trials already completed and runs only the rest.

The result is a complete scenario: the original's tables with its overrides applied and
the tuned values in ``[controllers.KIND]`` (``[controller]`` for the paper's kinds), as
TOML text headed by comments giving the budget and the train and test scores
(:func:`scenario_toml`).  :func:`equal_budget` tunes every kind on the same training
seeds with the same budget per parameter searched (``trials_per_parameter`` x the kind's
number of searched settings: a kind searching five settings gets five times the trials of
a kind searching one), widens a range whose optimum lies in its outer
:data:`EDGE_SHARE` and tunes again, and runs the tuned kinds on disjoint test seeds.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import tomllib
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Sequence

from tspend.runtime.errors import ScenarioError
from tspend.scenario.writer import dump_toml

#: the metric a tuning minimises unless asked otherwise
DEFAULT_METRIC = "rmse"
#: the first line of a tuned scenario: what ``--out`` checks before replacing a file
#: an optimum within this share of its range's width (log width on a log scale) of an edge
#: is "at the edge": the range may be what stopped it (issue 42)
EDGE_SHARE = 0.05
MARKER = re.compile(r'^# tspend tune: controller = "([A-Za-z0-9_]+)", scenario = "(.*)"$')


@dataclass(frozen=True)
class TuneResult:
    """What :func:`tune` found; ``text`` is the tuned scenario as TOML."""

    kind: str
    metric: str
    scenario: Any                        # the tuned tspend.config.Scenario
    base_name: str                       # the scenario tuned
    values: dict[str, Any]               # key in the file -> tuned value
    drawn: dict[str, float]              # key -> the number the sampler drew
    trials: int                          # completed trials in the study
    train_seeds: list[int]
    test_seeds: list[int]
    train_score: float
    test_score: float | None
    default_train: float | None = None   # the kind's untuned settings on the same seeds
    default_test: float | None = None
    sampler_seed: int = 0
    study_name: str = ""
    text: str = field(default="", repr=False)
    #: the ranges searched (key -> Search) in the last round, and every round's trials
    space: dict = field(default_factory=dict, repr=False)
    rounds: tuple = ()


def settings_prefix(kind: str) -> str:
    """Where ``kind``'s settings live in a scenario: ``controller`` or ``controllers.KIND``."""
    from tspend.controllers.settings import PAPER_KINDS

    return "controller" if kind in PAPER_KINDS else f"controllers.{kind}"


def _order(scenario) -> int:
    return len(scenario.controller.lam)


def tuned_changes(scenario, kind: str, drawn: dict[str, float]) -> dict[str, Any]:
    """The dotted overrides that put the drawn numbers into ``scenario`` for ``kind``."""
    from tspend.controllers import search_space
    from tspend.controllers.settings import PAPER_KINDS

    space, n, prefix = search_space(kind), _order(scenario), settings_prefix(kind)
    changes = {f"{prefix}.{key}": space[key].value(x, n) for key, x in drawn.items()}
    if kind in PAPER_KINDS:  # the file's own controller is the tuned kind
        changes["controller.adaptation"] = "first" if kind == "first_type" else "second"
    return changes


def score(rows, metric: str) -> float:
    """The objective: the median of ``metric`` over the rows' seeds; a run that did not
    complete because of the controller (fell, rail_end, joint_limit, state_bound,
    diverged, failed) counts ``+inf``."""
    import numpy as np

    from tspend.studies.stats import BAD, median

    status = rows["status"].to_numpy()
    values = rows[metric].to_numpy(dtype=float, na_value=np.nan)
    values = np.where(np.isin(status, BAD) | np.isnan(values), np.inf, values)
    return median(values) if values.size else math.inf


def check_seeds(train: Sequence[int], test: Sequence[int]) -> None:
    shared = sorted(set(train) & set(test))
    if shared:
        raise ScenarioError(f"--test-seeds: must be disjoint from the training seeds; both "
                            f"hold {', '.join(map(str, shared[:5]))}")


def study_name(scenario, kind: str, metric: str, seeds: Sequence[int],
               space: dict | None = None, start_trials: int = 0) -> str:
    """The study's identity in a storage: the scenario's text, kind, metric, seeds,
    search space (``space``: the ranges searched, default the kind's declared ones) and
    space-filling start; any change starts another study."""
    from tspend.controllers import search_space
    from tspend.loop.simulation import scenario_text

    space = search_space(kind) if space is None else space
    ident = json.dumps([scenario_text(scenario), kind, metric, list(seeds),
                        {k: list(v) for k, v in space.items()}]
                       + ([{"start_trials": start_trials}] if start_trials else []),
                       sort_keys=True)
    return f"tspend-{scenario.name}-{kind}-{hashlib.sha256(ident.encode()).hexdigest()[:12]}"


def _storage(url: str | None):
    if url is None:
        return None
    if "://" in url:
        return url
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    return JournalStorage(JournalFileBackend(url))


def _sweep_score(scenario, kind, seeds, metric, executor, stop,
                 run_timeout: float | None = None) -> float:
    from tspend.sweep import sweep

    timeout = {} if run_timeout is None else {"run_timeout": run_timeout}
    rows = sweep(scenario, seeds=list(seeds), controllers=[kind], executor=executor,
                 record="none", stop=stop, build=False, **timeout)  # tune() built it once
    return score(rows, metric)


def tune(scenario, kind: str, *, trials: int, seeds: Sequence[int],
         test_seeds: Sequence[int] = (), metric: str = DEFAULT_METRIC, executor: Any = None,
         jobs: int | None = None, dask: str | None = None, storage: str | None = None,
         sampler_seed: int = 0, progress: bool = False, defaults: bool = True,
         stop: Any = None, on_trial: Callable[[int, float], None] | None = None,
         run_timeout: float | None = None, space: dict | None = None,
         start_trials: int = 0) -> TuneResult:
    """Tune ``kind`` on ``scenario`` (a :class:`tspend.config.Scenario`): ``trials``
    trials in all (counting those already in ``storage``), scored on ``seeds``; the best
    is then scored on ``test_seeds``.  ``defaults``: also score the untuned settings.
    ``run_timeout``: the sweeps' per-run time limit (None: :func:`tspend.sweep.sweep`'s
    default); a run past it scores ``+inf``.  ``space``: the ranges to search (key ->
    :class:`tspend.controllers.settings.Search`; default the kind's declared ones).
    ``start_trials``: the first trials are that many points of a scrambled Sobol sequence
    (:func:`space_filling_start`: every range covered, one point in each ``1/start_trials``
    of it when a power of 2), and TPE guides the rest from them; 0: TPE's own random
    start (its first 10 trials)."""
    from tspend.runtime.extras import missing_extra

    problem = missing_extra("optuna", "tune")
    if problem:
        raise ScenarioError(problem)
    import optuna

    from tspend.controllers import KINDS
    from tspend.controllers import search_space
    from tspend.runtime.progress import TuneProgress
    from tspend.scenario import override
    from tspend.studies.stats import COMPARED_METRICS
    from tspend.sweep.executors import make_executor

    if kind not in KINDS:
        raise ScenarioError(f"--controller {kind}: unknown kind; allowed: {', '.join(KINDS)}")
    if metric not in COMPARED_METRICS:
        raise ScenarioError(f"--metric {metric}: unknown metric; allowed: "
                            f"{', '.join(COMPARED_METRICS)}")
    if isinstance(trials, bool) or not isinstance(trials, int) or trials < 1:
        raise ScenarioError(f"--trials: must be an integer >= 1, got {trials!r}")
    if isinstance(start_trials, bool) or not isinstance(start_trials, int) or \
            not 0 <= start_trials <= trials:
        raise ScenarioError(f"start_trials: must be an integer in 0..trials ({trials}), "
                            f"got {start_trials!r}")
    seeds, test_seeds = list(seeds), list(test_seeds)
    if not seeds:
        raise ScenarioError("--seeds: at least one training seed")
    check_seeds(seeds, test_seeds)
    space = search_space(kind) if space is None else dict(space)
    if not space:
        raise ScenarioError(f"--controller {kind}: the kind declares nothing to tune")

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    name = study_name(scenario, kind, metric, seeds, space, start_trials)
    from tspend.sweep import build_once
    from tspend.sweep.plan import make_plan

    # the model and the controller built once: a broken one is bad input, not N failed trials
    build_once(make_plan(scenario, seeds=seeds[:1], controllers=[kind]))
    try:
        study = optuna.create_study(study_name=name, storage=_storage(storage),
                                    load_if_exists=storage is not None, direction="minimize",
                                    sampler=optuna.samplers.TPESampler(
                                        seed=sampler_seed,
                                        **({"n_startup_trials": start_trials}
                                           if start_trials else {})))
    except Exception as exc:  # noqa: BLE001 - every way a storage URL or file can be wrong
        raise ScenarioError(f"--storage {str(storage)[:200]}: cannot open the study "
                            f"({type(exc).__name__}: {' '.join(str(exc).split())[:200]})") \
            from None
    done = sum(t.state == optuna.trial.TrialState.COMPLETE for t in study.trials)
    if start_trials and not study.trials:    # a resumed study has its start already
        for point in space_filling_start(space, start_trials, sampler_seed):
            study.enqueue_trial(point)
    owned = executor is None
    if owned:
        executor = make_executor(jobs, dask)
    shown = TuneProgress(trials, done, f"tune {kind}", enabled=progress)
    try:
        for _ in range(max(0, trials - done)):
            trial = study.ask()
            drawn = {k: trial.suggest_float(k, s.low, s.high, log=s.log)
                     for k, s in space.items()}
            scn = override(scenario, **tuned_changes(scenario, kind, drawn))
            value = _sweep_score(scn, kind, seeds, metric, executor, stop, run_timeout)
            study.tell(trial, value)
            shown.update(study.best_value)
            if on_trial is not None:
                on_trial(trial.number, value)
        best = study.best_trial
        drawn = {k: float(best.params[k]) for k in space}
        changes = tuned_changes(scenario, kind, drawn)
        tuned = override(scenario, **changes)
        test = (_sweep_score(tuned, kind, test_seeds, metric, executor, stop, run_timeout)
                if test_seeds else None)
        d_train = d_test = None
        if defaults:
            d_train = _sweep_score(scenario, kind, seeds, metric, executor, stop, run_timeout)
            d_test = (_sweep_score(scenario, kind, test_seeds, metric, executor, stop, run_timeout)
                      if test_seeds else None)
    finally:
        shown.close()
        if owned:
            executor.close()
    completed = sum(t.state == optuna.trial.TrialState.COMPLETE for t in study.trials)
    prefix = settings_prefix(kind) + "."
    values = {k[len(prefix):]: v for k, v in changes.items() if k.startswith(prefix)}
    result = TuneResult(kind=kind, metric=metric, scenario=tuned, base_name=scenario.name,
                        values=values, drawn=drawn, trials=completed, train_seeds=seeds,
                        test_seeds=test_seeds, train_score=float(best.value),
                        test_score=test, default_train=d_train, default_test=d_test,
                        sampler_seed=sampler_seed, study_name=name, space=space,
                        rounds=(completed,))
    return _with_text(result, scenario, changes)


# -- the tuned scenario as TOML ---------------------------------------------------------------
def _seeds_text(seeds: Sequence[int]) -> str:
    s = list(seeds)
    if s and s == list(range(s[0], s[-1] + 1)):
        return f"{s[0]}-{s[-1]}" if len(s) > 1 else str(s[0])
    return ",".join(map(str, s))


def _num(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.10g}"


def _with_text(result: TuneResult, base, changes: dict[str, Any]) -> TuneResult:
    from dataclasses import replace

    from tspend.scenario import set_dotted

    raw = tomllib.loads(base.text)
    for key, value in list(base.overrides) + list(changes.items()):
        set_dotted(raw, key, value, base.path)
    r = result
    head = [
        f'# tspend tune: controller = "{r.kind}", scenario = "{r.base_name}"',
        f"# from {_shown_path(base.path)}" + (f" with {', '.join(f'{k} = {v!r}' for k, v in base.overrides)}"
                                 if base.overrides else ""),
        f"# budget: {r.trials} trials (Optuna TPE, sampler seed {r.sampler_seed}) x "
        f"{len(r.train_seeds)} training seeds ({_seeds_text(r.train_seeds)}) = "
        f"{r.trials * len(r.train_seeds)} runs",
        f"# score: median {r.metric} over seeds (a run that fell, diverged or failed counts "
        f"as worst); lower is better",
        f"# train score (seeds {_seeds_text(r.train_seeds)}): {_num(r.train_score)}"
        + (f"; untuned: {_num(r.default_train)}" if r.default_train is not None else ""),
    ]
    if r.test_seeds:
        head.append(f"# test score (seeds {_seeds_text(r.test_seeds)}): {_num(r.test_score)}"
                    + (f"; untuned: {_num(r.default_test)}" if r.default_test is not None
                       else ""))
    head.append(f"# tuned: {', '.join(f'{k} = {v}' for k, v in r.values.items())}")
    text = "\n".join(head) + "\n\n" + dump_toml(raw)
    if tomllib.loads(text) != raw:  # the writer must give back exactly what it was given
        raise AssertionError("the tuned scenario does not read back as written")
    return replace(result, text=text)


def _shown_path(path: str) -> str:
    """The scenario's path relative to the shipped data (scenarios/x.toml) when it is there."""
    from pathlib import Path

    from tspend.shipped import data_root

    try:
        return str(Path(path).resolve().relative_to(data_root()))
    except (ValueError, OSError):
        return str(path)


def tuned_kind(text: str) -> tuple[str, str] | None:
    """(kind, scenario) of a file written by :func:`tune`, from its first line; else None."""
    first = text.split("\n", 1)[0]
    m = MARKER.match(first)
    return (m.group(1), m.group(2)) if m else None


# -- equal budget --------------------------------------------------------------------------------
def position(search, x: float) -> float:
    """Where ``x`` lies in ``search``'s range: 0 at ``low``, 1 at ``high`` (on the log scale
    for a log range)."""
    if search.log:
        return math.log(x / search.low) / math.log(search.high / search.low)
    return (x - search.low) / (search.high - search.low)


def space_filling_start(space: dict, n: int, seed: int = 0) -> list[dict[str, float]]:
    """``n`` points of a scrambled Sobol sequence over ``space`` (key ->
    :class:`tspend.controllers.settings.Search`), each coordinate mapped onto its range
    (on the log scale for a log range): for ``n`` a power of 2 every range is covered, one
    point in each ``1/n`` of it, whatever the number of settings."""
    from scipy.stats import qmc

    keys = list(space)
    unit = qmc.Sobol(d=len(keys), scramble=True, seed=seed).random(n)
    points = []
    for row in unit:
        point = {}
        for k, u in zip(keys, row):
            s = space[k]
            point[k] = (math.exp(math.log(s.low) + u * (math.log(s.high) - math.log(s.low)))
                        if s.log else s.low + u * (s.high - s.low))
        points.append(point)
    return points


def at_edge(space: dict, drawn: dict[str, float], share: float = EDGE_SHARE) -> dict[str, str]:
    """The tuned numbers within ``share`` of an edge of their range: key -> "low"/"high"."""
    out = {}
    for key, x in drawn.items():
        f = position(space[key], x)
        if f < share:
            out[key] = "low"
        elif f > 1.0 - share:
            out[key] = "high"
    return out


def widen(search, side: str):
    """``search`` with the edge ``side`` moved out by the range's width (log width on a log
    scale: ``high`` x ``high/low``); None where that edge is the setting's own limit (a
    linear range's low of 0: a boundary layer, a rate cannot be negative)."""
    if search.log:
        ratio = search.high / search.low
        return (search._replace(high=search.high * ratio) if side == "high"
                else search._replace(low=search.low / ratio))
    width = search.high - search.low
    if side == "low":
        return None if search.low == 0.0 else search._replace(low=search.low - width)
    return search._replace(high=search.high + width)


def budget_trials(kind: str, trials_per_parameter: int, space: dict | None = None,
                  start_trials: int = 0) -> int:
    """The trials ``kind`` gets: the space-filling start (the same for every kind), then
    ``trials_per_parameter`` guided trials per setting it searches."""
    from tspend.controllers import search_space

    return start_trials + trials_per_parameter * len(search_space(kind) if space is None
                                                     else space)


def equal_budget(scenarios: Iterable[Any], kinds: Sequence[str], *, trials: int | None = None,
                 trials_per_parameter: int | None = None,
                 train_seeds: Sequence[int], test_seeds: Sequence[int],
                 metric: str = DEFAULT_METRIC, executor: Any = None, jobs: int | None = None,
                 dask: str | None = None, storage: str | None = None, sampler_seed: int = 0,
                 progress: bool = False, stop: Any = None, run_timeout: float | None = None,
                 spaces: dict[str, dict] | None = None, widen_rounds: int = 0,
                 start_trials: int = 0):
    """Tune every kind on every scenario on the same ``train_seeds``, then run each tuned
    kind on ``test_seeds`` (disjoint): (rows, tuned).

    The budget: ``trials_per_parameter`` trials per setting a kind searches (the fair
    budget: a kind searching five settings gets five times a one-setting kind's), or
    ``trials`` for every kind alike.  ``spaces``: kind -> the ranges to search (key ->
    :class:`tspend.controllers.settings.Search`; default the kind's declared ones).
    ``widen_rounds``: up to this many times, a kind whose optimum lies in the outer
    :data:`EDGE_SHARE` of a range (:func:`at_edge`) has that edge moved out
    (:func:`widen`) and is tuned again from scratch with its full budget; the result's
    ``space`` is the last round's ranges and ``rounds`` every round's trials.
    ``start_trials``: every kind's search starts with that many space-filling points
    (:func:`space_filling_start`) before TPE guides it, so even a one-setting kind has
    seen its whole range; they come on top of the per-setting budget.

    ``rows`` is a sweep table (one row per scenario, kind and test seed; the ``scenario``
    column the original's name, so runs pair by seed as in ``tspend compare``); ``tuned``
    maps (scenario name, kind) to its :class:`TuneResult`.
    """
    import pandas as pd

    from tspend.controllers import search_space
    from tspend.sweep import sweep
    from tspend.sweep.executors import make_executor

    if (trials is None) == (trials_per_parameter is None):
        raise ScenarioError("equal_budget: give trials or trials_per_parameter, one of them")
    check_seeds(train_seeds, test_seeds)
    owned = executor is None
    if owned:
        executor = make_executor(jobs, dask)
    tuned: dict[tuple[str, str], TuneResult] = {}
    frames = []
    try:
        for scn in scenarios:
            for kind in kinds:
                space = dict((spaces or {}).get(kind) or search_space(kind))
                rounds: list[int] = []
                while True:
                    n = trials + start_trials if trials is not None else budget_trials(
                        kind, trials_per_parameter, space, start_trials)
                    r = tune(scn, kind, trials=n, seeds=train_seeds, metric=metric,
                             executor=executor, storage=storage, sampler_seed=sampler_seed,
                             progress=progress, defaults=False, stop=stop,
                             run_timeout=run_timeout, space=space, start_trials=start_trials)
                    rounds.append(r.trials)
                    edges = at_edge(space, r.drawn)
                    moved = {k: widen(space[k], side) for k, side in edges.items()}
                    moved = {k: v for k, v in moved.items() if v is not None}
                    if not moved or len(rounds) > widen_rounds:
                        break
                    space.update(moved)
                from dataclasses import replace

                r = replace(r, rounds=tuple(rounds))
                tuned[(scn.name, kind)] = r
                timeout = {} if run_timeout is None else {"run_timeout": run_timeout}
                rows = sweep(r.scenario, seeds=list(test_seeds), controllers=[kind],
                             executor=executor, record="none", stop=stop, **timeout)
                frames.append(rows.assign(scenario=scn.name))
    finally:
        if owned:
            executor.close()
    return pd.concat(frames, ignore_index=True), tuned


__all__ = ["TuneResult", "tune", "equal_budget", "score", "tuned_changes", "settings_prefix",
           "position", "at_edge", "widen", "budget_trials", "EDGE_SHARE",
           "space_filling_start",
           "dump_toml", "tuned_kind", "study_name", "DEFAULT_METRIC"]
