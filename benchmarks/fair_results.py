"""The fair comparison: every kind tuned on an equal budget, compared on randomised machines.

    nice python benchmarks/fair_results.py                    # the budget the page states
    nice python benchmarks/fair_results.py --trials-per-parameter 2 --train-seeds 100:102 \\
        --test-seeds 0:4 --confirm-seeds 200:204 --out /tmp/fair --page /tmp/fair.md \\
        --readme /tmp/readme.md                               # a quick look

For every scenario (default: ``ex3_pendulum_ode_randomized`` and
``pendulum_mujoco_randomized``, whose ``[randomize]`` tables draw the initial state, the
pole's mass and half-length, the cart's mass and the actuator's gain at every seed) and
every controller kind, :func:`tspend.studies.tune.equal_budget` tunes the kind with the
same number of Optuna TPE trials *per setting it searches* on the same training seeds
(objective: the median ``rmse`` over them, a run that fell or diverged scoring worst),
moves out any edge of a range whose optimum lies in its outer 5 % and tunes again
(``--widen-rounds``), then runs the tuned kind on two sets of seeds disjoint from the
training ones: the test seeds and a confirmation set fixed before any wording.
:func:`tspend.studies.stats.compare` pairs the runs of each set by seed (each seed one
drawn machine, the same for every kind) over every pair of kinds, with Holm's correction
over each set's whole family.  A headline claim (:data:`HEADLINES`) is "shown" only when
both sets give the same verdict (Holm p < 0.05, interval excluding 0, not negligible);
otherwise it is worded "not shown".

It writes, in ``--out``: the test runs (``runs.parquet``), the statistics
(``comparison.json`` on the test seeds, ``comparison_confirm.json`` on the confirmation
seeds), the headline claims with their figures on both sets (``claims.json``, what
``tools/check_claims.py`` checks the README and the page against), the tuned scenarios (``tuned/SCENARIO-KIND.toml``, each runnable
and headed by its budget and scores) and the studies' journal (``tune.journal``: a rerun
resumes the trials); and it replaces the section between the markers below in the page
(docs/results.md; ``benchmarks/results.py`` keeps that section when it rewrites the rest)
and the claims between :data:`README_BEGIN` and :data:`README_END` in ``--readme``.
Every sentence of the section is generated from the statistics; the earlier claims it
re-examines are the verdicts of ``docs/results/comparison.json`` (the hand-tuned baselines
on the fixed machine) on the scenarios these randomise.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ("ex3_pendulum_ode_randomized", "pendulum_mujoco_randomized")
#: the fixed-machine scenario each randomised one re-examines
EARLIER = {"ex3_pendulum_ode_randomized": "ex3_pendulum_ode",
           "pendulum_mujoco_randomized": "pendulum_mujoco"}
KINDS = ("second_type", "first_type", "pd", "lqr", "sliding_mode", "feedback_linearization",
         "wang_indirect")
METRICS = ("rmse", "rmse_ss", "max_abs_e_ss", "control_energy", "tv_u_per_s")
BEGIN = "<!-- benchmarks/fair_results.py: begin (generated; rerun it, do not edit) -->"
END = "<!-- benchmarks/fair_results.py: end -->"
README_BEGIN = "<!-- benchmarks/fair_results.py claims: begin (generated from docs/results/fair/claims.json) -->"
README_END = "<!-- benchmarks/fair_results.py claims: end -->"
#: the claims the README states, each (scenario, A, B, metric): a verdict on A against B
HEADLINES = (
    ("pendulum_mujoco_randomized", "second_type", "pd", "rmse"),
    ("pendulum_mujoco_randomized", "second_type", "pd", "control_energy"),
    ("pendulum_mujoco_randomized", "second_type", "lqr", "rmse_ss"),
    ("ex3_pendulum_ode_randomized", "second_type", "lqr", "rmse_ss"),
    ("pendulum_mujoco_randomized", "second_type", "feedback_linearization", "rmse_ss"),
    ("ex3_pendulum_ode_randomized", "second_type", "feedback_linearization", "rmse_ss"),
    ("pendulum_mujoco_randomized", "second_type", "first_type", "rmse"),
    ("pendulum_mujoco_randomized", "second_type", "first_type", "rmse_ss"),
)


def splice(page: str, section: str, begin: str = BEGIN, end: str = END) -> str:
    """``page`` with the marked section replaced by ``section`` (inserted before the first
    ``## `` heading when the page has no markers yet)."""
    block = f"{begin}\n{section.rstrip()}\n{end}"
    if begin in page and end in page:
        head, rest = page.split(begin, 1)
        return head + block + rest.split(end, 1)[1]
    at = page.find("\n## ")
    if at < 0:
        return page.rstrip() + "\n\n" + block + "\n"
    return page[:at + 1] + block + "\n\n" + page[at + 1:]


def draws_text(scn) -> str:
    """The scenario's ``[randomize]`` in words (from the parsed table, not typed here)."""
    from tspend.studies.stats import fmt

    out = []
    for d in scn.randomize:
        if d.dist == "uniform":
            what = f"uniform [{fmt(d.a)}, {fmt(d.b)}]"
        else:
            what = f"normal({fmt(d.a)}, {fmt(d.b)}) truncated to [{fmt(d.low)}, {fmt(d.high)}]"
        out.append(f"`{d.name}` {what}" + (" × nominal" if d.relative else ""))
    return "; ".join(out)


def sentence(r) -> str:
    """One surviving verdict with its figures."""
    from tspend.studies.stats import fmt, fmt_ratio, _fmt_p

    better, worse = (r.a, r.b) if r.verdict == r.a else (r.b, r.a)
    ratio = r.median_ratio if r.verdict == r.a else 1.0 / r.median_ratio
    wins = r.wins if r.verdict == r.a else r.pairs - r.wins
    ph = _fmt_p(r.p_holm)
    return (f"{r.scenario}, `{r.metric}`: **{better}** better than {worse} (lower at {wins:g} "
            f"of {r.pairs} seeds, median ratio {fmt_ratio(ratio)}, median difference "
            f"{r.a} − {r.b} = {fmt(r.median_difference)} [{fmt(r.ci_low)}, {fmt(r.ci_high)}], "
            f"Holm-adjusted p {ph if ph.startswith('<') else '= ' + ph})")


def earlier_claims(comp, path: Path) -> tuple[list[str], list[str]]:
    """The earlier page's verdicts (recomputed with Holm over its own family) on the
    scenarios re-examined here, each checked against this comparison: (hold, fail)."""
    import numpy as np
    import pandas as pd

    from tspend.studies.stats import _fmt_p, fmt_ratio, holm

    if not path.is_file():
        return [], []
    doc = json.loads(path.read_text())
    old = pd.DataFrame(doc["pairs"])
    old["p_holm"] = holm(old["p_value"].to_numpy(dtype=float))
    new = comp.pairs
    holds, fails = [], []
    for scn, earlier in EARLIER.items():
        rows = old[(old.scenario == earlier) & (old.verdict != "") & (~old.negligible.astype(bool))
                   & old.metric.isin(comp.metrics)]
        for r in rows.itertuples():
            if r.a not in comp.controllers or r.b not in comp.controllers:
                continue
            m = new[(new.scenario == scn) & (new.metric == r.metric)
                    & (((new.a == r.a) & (new.b == r.b)) | ((new.a == r.b) & (new.b == r.a)))]
            if m.empty:
                continue
            n = m.iloc[0]
            ratio = n.median_ratio if n.a == r.verdict else 1.0 / n.median_ratio
            had = (f"{earlier}: {r.verdict} better than {r.b if r.verdict == r.a else r.a} on "
                   f"`{r.metric}` (earlier: median ratio {fmt_ratio(r.median_ratio if r.verdict == r.a else 1 / r.median_ratio)}, "
                   f"p {_fmt_p(r.p_value)}, Holm {_fmt_p(r.p_holm)}"
                   + (", seed-independent: one observation" if r.deterministic else "") + ")")
            now = (f"tuned, randomised ({scn}): "
                   + (f"{n.verdict} better" if n.verdict else "no difference shown")
                   + f", median ratio {fmt_ratio(ratio)}, Holm p {_fmt_p(n.p_holm)}")
            held = n.verdict == r.verdict and not n.negligible
            if n.verdict == r.verdict and n.negligible:
                now += " (the same side, but by less than 1%: negligible)"
            late_holm = not r.deterministic and not (r.p_holm < 0.05)
            line = f"{had} → {now}" + ("; did not survive Holm even then" if late_holm else "")
            (holds if held else fails).append(line)
    return holds, fails


def _earlier_rows() -> int:
    """How many rows the earlier page's comparison holds (its Holm family)."""
    path = ROOT / "docs" / "results" / "comparison.json"
    return len(json.loads(path.read_text())["pairs"]) if path.is_file() else 0


def _short(v) -> str:
    """A tuned value in 3 significant figures (lists and matrices entry by entry)."""
    from tspend.studies.stats import fmt

    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_short(x) for x in v) + "]"
    return fmt(v) if isinstance(v, float) else str(v)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "fair"))
    ap.add_argument("--page", default=str(ROOT / "docs" / "results.md"))
    ap.add_argument("--scenarios", default=",".join(SCENARIOS))
    ap.add_argument("--controller", default=",".join(KINDS), help="kinds K1,K2,...")
    ap.add_argument("--trials-per-parameter", type=int, default=8,
                    help="Optuna trials per setting a kind searches (the fair budget)")
    ap.add_argument("--start-trials", type=int, default=8,
                    help="space-filling (scrambled Sobol) trials every kind starts with "
                         "before TPE guides it, on top of the per-setting budget; 8 puts a "
                         "point in each eighth of every range (0: TPE's own random start)")
    ap.add_argument("--trials", type=int, default=None,
                    help="the same trials for every kind instead (the old, unfair budget)")
    ap.add_argument("--widen-rounds", type=int, default=2,
                    help="times a range whose optimum lies in its outer 5 %% is widened and "
                         "the kind tuned again")
    ap.add_argument("--train-seeds", default="100:104")
    ap.add_argument("--test-seeds", default="0:20")
    ap.add_argument("--confirm-seeds", default="200:220",
                    help="the second test set, fixed before the wording, that confirms a claim")
    ap.add_argument("--readme", default=str(ROOT / "README.md"),
                    help="the file whose marked claims section is rewritten")
    ap.add_argument("--metric", default="rmse", help="the metric the tuning minimises")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--fresh", action="store_true", help="forget the studies in --out")
    ap.add_argument("--render", action="store_true",
                    help="run nothing: rewrite the page from the runs and tuned settings "
                         "kept in --out")
    args = ap.parse_args(argv)
    for name in ("trials_per_parameter", "trials", "widen_rounds", "jobs", "start_trials"):
        v = getattr(args, name)
        if v is not None and not (0 <= v <= 1000) or (name not in ("widen_rounds",
                                                                    "start_trials") and v == 0):
            ap.error(f"--{name.replace('_', '-')}: {v} is outside 1..1000")

    import pandas as pd

    import tspend
    from tspend.scenario import load_scenario
    from tspend.studies.stats import compare, to_json
    from tspend.studies.tune import budget_trials, equal_budget, position, score
    from tspend.sweep.executors import make_executor
    from tspend.sweep.plan import parse_seeds

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    saved = out / "comparison.json"
    if args.render:
        rows, scenarios, kinds, tuned, train, test, confirm, budget = load_saved(out)
    else:
        journal = out / "tune.journal"
        if args.fresh:
            journal.unlink(missing_ok=True)
        scenarios = [load_scenario(s.strip()) for s in args.scenarios.split(",") if s.strip()]
        kinds = [k.strip() for k in args.controller.split(",") if k.strip()]
        train, test = parse_seeds(args.train_seeds), parse_seeds(args.test_seeds)
        confirm = parse_seeds(args.confirm_seeds)
        if set(confirm) & (set(test) | set(train)):
            ap.error("--confirm-seeds: must be disjoint from the test and training seeds")
        started = time.perf_counter()
        trials_of = {k: args.trials if args.trials is not None
                     else budget_trials(k, args.trials_per_parameter,
                                        start_trials=args.start_trials) for k in kinds}
        runs = len(scenarios) * sum(trials_of[k] * len(train) + len(test) + len(confirm)
                                    for k in kinds)
        print(f"fair results: {len(scenarios)} scenarios x {len(kinds)} kinds, trials "
              + ", ".join(f"{k} {n}" for k, n in trials_of.items())
              + f" x {len(train)} train seeds + {len(test)} + {len(confirm)} test seeds = "
              f"{runs} runs at least (more where a range is widened)", file=sys.stderr)
        executor = make_executor(args.jobs)
        try:
            rows, results = equal_budget(scenarios, kinds, trials=args.trials,
                                         trials_per_parameter=None if args.trials is not None
                                         else args.trials_per_parameter,
                                         train_seeds=train, test_seeds=[*test, *confirm],
                                         metric=args.metric, executor=executor,
                                         storage=str(journal), progress=True,
                                         widen_rounds=args.widen_rounds,
                                         start_trials=args.start_trials)
        finally:
            executor.close()
        runs = sum(sum(r.rounds) * len(train) + len(test) + len(confirm)
                   for r in results.values())
        budget = dict(trials=args.trials, trials_per_parameter=args.trials_per_parameter
                      if args.trials is None else None, metric=args.metric,
                      wall_s=time.perf_counter() - started, jobs=args.jobs, runs=runs,
                      start_trials=args.start_trials)
        rows.to_parquet(out / "runs.parquet")
        (out / "tuned").mkdir(exist_ok=True)
        for (scn, kind), r in results.items():
            (out / "tuned" / f"{scn}-{kind}.toml").write_text(r.text)
        # the test score as tune states it: the median of the metric over the test seeds
        tuned = {(scn, kind): {"values": r.values, "train_score": r.train_score,
                               "test_score": score(rows[(rows.scenario == scn)
                                                        & (rows.controller == kind)
                                                        & rows.seed.isin(test)], args.metric),
                               "rounds": list(r.rounds),
                               "space": {key: {"low": sp.low, "high": sp.high, "log": sp.log,
                                               "optimum": r.drawn[key],
                                               "position": position(sp, r.drawn[key])}
                                         for key, sp in r.space.items()}}
                 for (scn, kind), r in results.items()}

    page, readme = Path(args.page), Path(args.readme)
    doc, doc2, claims, section, readme_section = build(
        rows, scenarios, kinds, tuned, train, test, confirm, budget, out, page, readme)
    saved.write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n")
    if doc2 is not None:
        (out / "comparison_confirm.json").write_text(json.dumps(doc2, indent=1,
                                                                allow_nan=False) + "\n")
    (out / "claims.json").write_text(json.dumps(claims, indent=1, allow_nan=False) + "\n")
    claims_figure(claims, CLAIMS_FIGURE)
    found = tried_positions(out, scenarios, tuned, train, budget["metric"],
                            budget.get("start_trials") or 0)
    if found:
        trials_figure(found, tuned, TRIALS_FIGURE)
    old = page.read_text() if page.is_file() else "# Results\n"
    page.write_text(splice(old, section))
    if readme.is_file() and README_BEGIN in readme.read_text():
        readme.write_text(splice(readme.read_text(), readme_section, README_BEGIN, README_END))
    print(f"wrote {page} ({budget['wall_s']:.0f} s of runs)", file=sys.stderr)
    return 0


def load_saved(out: Path):
    """What a run kept in ``out``: (rows, scenarios, kinds, tuned, train, test, confirm,
    budget), as :func:`build` takes them."""
    import pandas as pd

    from tspend.scenario import load_scenario

    doc = json.loads((out / "comparison.json").read_text())
    rows = pd.read_parquet(out / "runs.parquet")
    scenarios = [load_scenario(s) for s in doc["scenarios"]]
    budget = dict(trials=doc["trials"], trials_per_parameter=doc.get("trials_per_parameter"),
                  metric=doc["metric"], wall_s=doc["wall_s"], jobs=doc.get("jobs", 2),
                  runs=doc["runs"], start_trials=doc.get("start_trials", 0))
    tuned = {tuple(k.split("/")): v for k, v in doc["tuned"].items()}
    return (rows, scenarios, doc["controllers"], tuned, doc["train_seeds"], doc["test_seeds"],
            doc.get("confirm_seeds", []), budget)


def tried_positions(out: Path, scenarios, tuned: dict, train, metric: str,
                    start_trials: int = 0) -> dict:
    """Per (scenario, kind): per searched setting, the positions (0 the low end, 1 the high
    end of its last round's range) of every trial that round tried, read from the kept
    journal (``tune.journal``, opened from a copy: reading leaves the kept one untouched).
    Empty when there is no journal or no optuna."""
    import shutil
    import tempfile

    try:
        import optuna
        from optuna.storages import JournalStorage
        from optuna.storages.journal import JournalFileBackend
    except ImportError:
        return {}
    from tspend.controllers import search_space
    from tspend.studies.tune import position, study_name

    if not (out / "tune.journal").is_file():
        return {}
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    found = {}
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / "tune.journal"
        shutil.copyfile(out / "tune.journal", copy)
        storage = JournalStorage(JournalFileBackend(str(copy)))
        names = {s.study_name for s in storage.get_all_studies()}
        for scn in scenarios:
            for kind in [k for (sc, k) in tuned if sc == scn.name]:     # tuned's order
                kept = tuned[(scn.name, kind)].get("space", {})
                space = {k: v._replace(low=kept[k]["low"], high=kept[k]["high"])
                         for k, v in search_space(kind).items() if k in kept}
                name = study_name(scn, kind, metric, train, space, start_trials)
                if name not in names:
                    continue
                trials = optuna.load_study(study_name=name, storage=storage).trials
                found[(scn.name, kind)] = {
                    k: [position(sp, t.params[k]) for t in trials if k in t.params]
                    for k, sp in space.items()}
    return found


def trials_figure(found: dict, tuned: dict, png: Path) -> Path:
    """Each study's tried points against its range, one row per searched setting (0 the
    low end, 1 the high end; the tuned optimum a cross)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [(scn, kind, key, at) for (scn, kind), keys in found.items()
            for key, at in keys.items()]
    fig, ax = plt.subplots(figsize=(9, 0.28 * len(rows) + 1.2), constrained_layout=True)
    for y, (scn, kind, key, at) in enumerate(rows):
        ax.plot(at, [y] * len(at), "|", color="C0", ms=9)
        opt = tuned[(scn, kind)]["space"][key]["position"]
        ax.plot([opt], [y], "x", color="C3", ms=8)
    ax.set_yticks(range(len(rows)), [f"{SHORT_NAMES.get(s, s)} {k}: {key}"
                                     for s, k, key, _ in rows], fontsize=7)
    ax.set_xlim(-0.02, 1.02)
    ax.invert_yaxis()
    ax.set_xlabel("position in the range searched (log scale for a log range); x: the optimum")
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=100)
    plt.close(fig)
    return png


def build(rows, scenarios, kinds, tuned, train, test, confirm, budget, out: Path, page: Path,
          readme: Path):
    """Everything written from the runs: (comparison doc, confirmation doc or None, claims,
    the page's section, the README's claims section).  tools/check_claims.py calls it on
    the kept runs and compares with what is committed."""
    import tspend
    from tspend.cli.compare import seeds_text
    from tspend.studies.stats import compare, to_json

    comp = compare(rows[rows.seed.isin(test)], kinds, METRICS)
    doc = to_json(comp)
    doc.update(train_seeds=train, test_seeds=test, confirm_seeds=confirm,
               scenarios=[s.name for s in scenarios], version=tspend.__version__, **budget,
               tuned={f"{s}/{k}": v for (s, k), v in tuned.items()})
    comp2 = doc2 = None
    if confirm:
        comp2 = compare(rows[rows.seed.isin(confirm)], kinds, METRICS)
        doc2 = to_json(comp2)
        doc2.update(confirm_seeds=confirm, scenarios=[s.name for s in scenarios])
    claims = headline_claims(comp, comp2, test, confirm)
    # the optima still in the outer 5 % of their ranges after the widening rounds
    claims["at_edge"] = [f"{scn}/{kind}/{key}" for (scn, kind), t in tuned.items()
                         for key, sp in t.get("space", {}).items()
                         if not 0.05 <= sp["position"] <= 0.95]
    claims.update(run_facts(rows, test, confirm))
    claims["trials_per_parameter"] = budget.get("trials_per_parameter")
    claims["start_trials"] = budget.get("start_trials") or 0
    claims["train_seeds"] = seeds_text(train)
    found = tried_positions(out, scenarios, tuned, train, budget["metric"],
                            budget.get("start_trials") or 0)
    section = render(comp, scenarios, tuned, train, test, budget, out, page, claims, found)
    return doc, doc2, claims, section, readme_claims(claims, page, readme)


def _verdict_figures(r) -> dict:
    """One pair's figures on one seed set, as the claims file keeps them (a run that fell or
    diverged scores inf: kept as the string "inf", which float() reads back)."""
    def num(v) -> float | str:
        v = float(v)
        return v if math.isfinite(v) else str(v)

    return {"verdict": r.verdict or "", "negligible": bool(r.negligible), "pairs": int(r.pairs),
            "median_ratio": num(r.median_ratio), "median_difference": num(r.median_difference),
            "ci_low": num(r.ci_low), "ci_high": num(r.ci_high), "p_holm": num(r.p_holm),
            "wins": num(r.wins)}


def headline_claims(comp, comp2, test, confirm, headlines=HEADLINES) -> dict:
    """Each of ``headlines`` (scenario, A, B, metric) on both seed sets: shown when both
    give the same verdict (significant after Holm, interval excluding 0, not negligible)."""
    from tspend.cli.compare import seeds_text

    out = {"test_seeds": seeds_text(test), "confirm_seeds": seeds_text(confirm),
           "family_test": comp.settings["correction"],
           "family_confirm": comp2.settings["correction"] if comp2 is not None else "",
           "claims": []}
    for scn, a, b, metric in headlines:
        sets = []
        for c in (comp, comp2):
            if c is None:
                continue
            m = c.pairs[(c.pairs.scenario == scn) & (c.pairs.metric == metric)
                        & (c.pairs.a == a) & (c.pairs.b == b)]
            if m.empty:
                continue
            sets.append(_verdict_figures(m.iloc[0]))
        if not sets:
            continue
        v = {s["verdict"] for s in sets}
        shown = (len(sets) == 2 and len(v) == 1 and "" not in v
                 and not any(s["negligible"] for s in sets))
        out["claims"].append({"key": f"{scn}/{a}/{b}/{metric}", "scenario": scn, "a": a,
                              "b": b, "metric": metric, "shown": shown,
                              "better": sets[0]["verdict"] if shown else "",
                              "test": sets[0], "confirm": sets[1] if len(sets) > 1 else None})
    return out


def claim_sentence(c: dict, test_text: str, confirm_text: str) -> str:
    """A headline claim in words, every figure from the claims file."""
    from tspend.studies.stats import fmt, fmt_ratio, _fmt_p

    def figs(s: dict, seeds: str) -> str:
        ph = _fmt_p(float(s["p_holm"]))
        return (f"seeds {seeds}: difference {c['a']} − {c['b']} "
                f"{fmt(float(s['median_difference']))} [{fmt(float(s['ci_low']))}, "
                f"{fmt(float(s['ci_high']))}], median ratio "
                f"{fmt_ratio(float(s['median_ratio']))}, Holm p "
                f"{ph if ph.startswith('<') else '= ' + ph}")

    parts = [figs(c["test"], test_text)] + ([figs(c["confirm"], confirm_text)]
                                            if c["confirm"] else [])
    what = f"`{c['metric']}` on {c['scenario']}, {c['a']} against {c['b']}"
    if c["shown"]:
        worse = c["b"] if c["better"] == c["a"] else c["a"]
        head = f"**shown**: {c['better']} better than {worse} on `{c['metric']}` ({c['scenario']})"
    else:
        verdicts = [s["verdict"] or "none" for s in (c["test"], c["confirm"]) if s]
        head = (f"**not shown**: {what} (verdicts on the two sets: {', '.join(verdicts)})")
    return f"{head}; " + "; ".join(parts) + f" <!-- claim: {c['key']} -->"


#: how the README's table names a scenario
SHORT_NAMES = {"pendulum_mujoco_randomized": "MuJoCo", "ex3_pendulum_ode_randomized": "ODE"}
#: the figure of the claims' paired differences (PNG, its data beside it as CSV)
CLAIMS_FIGURE = ROOT / "docs" / "results" / "figures" / "fair_claims.png"
#: the figure of each study's tried points against its range
TRIALS_FIGURE = ROOT / "docs" / "results" / "figures" / "fair_trials.png"


def run_facts(rows, test, confirm) -> dict:
    """What the claims rest on beyond the statistics, per scenario and kind, on the test
    and the confirmation seeds: the runs that fell or diverged (``falls``) and the median
    share of samples at the actuator's limit in % (``saturated_percent``)."""
    facts: dict = {"falls": {}, "saturated_percent": {},
                   "seeds_per_set": [len(test), len(confirm)]}
    for (scn, kind), part in rows.groupby(["scenario", "controller"], sort=False):
        sets = [part[part.seed.isin(seeds)] for seeds in (test, confirm)]
        falls = [int(s.status.isin(["fell", "diverged"]).sum()) for s in sets]
        facts["falls"].setdefault(scn, {})[kind] = falls
        facts["saturated_percent"].setdefault(scn, {})[kind] = [
            round(100.0 * float(s.saturated_fraction.median()), 6) for s in sets]
    return facts


def context_notes(claims: dict) -> list[str]:
    """The facts a reader needs beside the claims: which tuned kinds fell (a fall scores
    worst, so a claim against them is not shown), and which sit at the actuator's limit."""
    from tspend.studies.stats import fmt

    notes = []
    for scn, kinds in claims.get("falls", {}).items():
        fell: dict[tuple, list[str]] = {}     # the same counts, named once
        for k, n in kinds.items():
            if any(n):
                fell.setdefault(tuple(n), []).append(k)
        if fell:
            rest = ("no other kind fell" if sum(map(len, fell.values())) < len(kinds)
                    else "every kind fell")
            notes.append(
                f"On {scn}, tuned " + "; ".join(
                    f"{' and '.join(ks)} fell on {n[0]} of {claims['seeds_per_set'][0]} "
                    f"machines (seeds {claims['test_seeds']}) and {n[1]} of "
                    f"{claims['seeds_per_set'][1]} ({claims['confirm_seeds']})"
                    for n, ks in fell.items())
                + f", {rest}: a fall scores worst, so a claim against a kind that fell is "
                "not shown there.")
    for scn, kinds in claims.get("saturated_percent", {}).items():
        at = {k: v for k, v in kinds.items() if max(v) > 0}
        if at:
            notes.append(
                f"On {scn}, the share of samples at the actuator's limit (median, the two "
                f"sets): " + ", ".join(f"{k} {fmt(v[0])} % and {fmt(v[1])} %"
                                      for k, v in at.items())
                + ". A kind at the limit for its first samples removes the initial error "
                "at the limit, whatever its law: where those kinds' `rmse` agree to three "
                "digits, `rmse` measures the actuator's limit, and `rmse_ss` compares the "
                "laws.")
    return notes


def _cell(s: dict | None) -> str:
    from tspend.studies.stats import _fmt_p, fmt_ratio

    if not s:
        return "—"
    return f"{fmt_ratio(float(s['median_ratio']))} (p {_fmt_p(float(s['p_holm']))})"


def readme_claims(claims: dict, page: Path, readme: Path) -> str:
    """The README's claims, generated from the claims file: a table of the verdicts on both
    seed sets, the figure of the paired differences, the facts the claims rest on."""
    rel = Path(os.path.relpath(page.resolve(), readme.parent.resolve())).as_posix()
    fig = Path(os.path.relpath(CLAIMS_FIGURE.resolve(), readme.parent.resolve())).as_posix()
    per = claims.get("trials_per_parameter")
    lines = [f"Every kind tuned on training seeds {claims.get('train_seeds', '')}"
             + (f" with {per} Optuna trials per setting it searches" if per else "")
             + (f" after {claims['start_trials']} space-filling ones" if claims.get(
                 "start_trials") else " (before the space-filling start: TPE's random start "
                "only, so a one-setting kind saw part of its range)")
             + f" ([{rel}]({rel}): budget, ranges, optima), then run on the test seeds "
             f"{claims['test_seeds']} and on {claims['confirm_seeds']}, fixed before this "
             f"wording; a seed draws the machine and its initial state. Cell: median ratio "
             f"of the first kind to the second over the paired seeds (Holm-adjusted p, "
             f"{claims['family_test'].split(' (')[0]}); shown only when both sets give the "
             f"same verdict (p < 0.05, 95 % bootstrap interval excluding 0).", "",
             f"| claim | seeds {claims['test_seeds']} | seeds {claims['confirm_seeds']} | "
             f"shown? |", "|---|---|---|---|"]
    for c in claims["claims"]:
        verdict = f"**shown**: {c['better']} lower" if c["shown"] else "not shown"
        lines.append(f"| `{c['metric']}` ({SHORT_NAMES.get(c['scenario'], c['scenario'])}): "
                     f"{c['a']} / {c['b']} <!-- claim: {c['key']} --> | {_cell(c['test'])} | "
                     f"{_cell(c['confirm'])} | {verdict} |")
    lines += ["", " ".join(context_notes(claims) + [
        f"![Each claim's median paired difference with its 95 % interval on both seed "
        f"sets]({fig})"])]
    return "\n".join(lines)


def claims_figure(claims: dict, png: Path) -> Path:
    """Each claim's median paired difference (first kind − second) with its 95 % bootstrap
    interval on both seed sets, one panel a claim (an infinite end drawn to the panel's
    edge); the figures beside it as CSV."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 4, figsize=(13, 5.2), constrained_layout=True)
    for ax, c in zip(axes.flat, claims["claims"]):
        for y, (name, seeds) in enumerate((("test", claims["test_seeds"]),
                                           ("confirm", claims["confirm_seeds"]))):
            s = c[name]
            if not s:
                continue
            mid, lo, hi = (float(s[k]) for k in ("median_difference", "ci_low", "ci_high"))
            finite = [v for v in (mid, lo, hi) if math.isfinite(v)]
            span = max(map(abs, finite)) * 1.2 or 1.0
            lo, hi = max(lo, -span), min(hi, span)
            ax.errorbar([mid], [y], xerr=[[mid - lo], [hi - mid]], fmt="o", capsize=4,
                        color="C0" if c["shown"] else "0.5")
        ax.axvline(0.0, color="k", lw=0.8)
        ax.set_yticks([0, 1], [claims["test_seeds"], claims["confirm_seeds"]])
        ax.set_ylim(-0.6, 1.6)
        ax.set_title(f"{c['metric']} ({SHORT_NAMES.get(c['scenario'], c['scenario'])})\n"
                     f"{c['a']} − {c['b']}: {'shown' if c['shown'] else 'not shown'}",
                     fontsize=8)
        ax.tick_params(labelsize=7)
        ax.ticklabel_format(axis="x", style="sci", scilimits=(-2, 3))
    for ax in list(axes.flat)[len(claims["claims"]):]:
        ax.axis("off")
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    plt.close(fig)
    png.with_suffix(".csv").write_text(claims_figure_data(claims))
    return png


def claims_figure_data(claims: dict) -> str:
    """The figure's data as CSV: per claim and seed set, the median paired difference, its
    interval and Holm p (tools/check_claims.py rebuilds it from claims.json)."""
    rows = ["claim,seeds,median_difference,ci_low,ci_high,p_holm,shown"]
    for c in claims["claims"]:
        for name, seeds in (("test", claims["test_seeds"]), ("confirm", claims["confirm_seeds"])):
            s = c[name]
            if s:
                rows.append(",".join([c["key"], seeds, *(repr(float(s[k])) for k in (
                    "median_difference", "ci_low", "ci_high", "p_holm")), str(c["shown"])]))
    return "\n".join(rows) + "\n"


def pair_table(comp, scenario: str) -> list[str]:
    """Per pair of kinds, per metric: the better kind by the Holm-corrected verdict and the
    median ratio of the worse to the better (— : no difference shown)."""
    from tspend.studies.stats import _fmt_p, fmt_ratio

    pairs = comp.pairs[comp.pairs.scenario == scenario]
    lines = ["| A vs B | " + " | ".join(comp.metrics) + " |",
             "|---|" + "---|" * len(comp.metrics)]
    for (a, b), part in pairs.groupby(["a", "b"], sort=False):
        cells = []
        for m in comp.metrics:
            r = part[part.metric == m].iloc[0]
            if not r.verdict:
                cells.append("—")
                continue
            ratio = r.median_ratio if r.verdict == a else 1.0 / r.median_ratio
            cells.append(f"**{r.verdict}** {fmt_ratio(ratio)}× (p {_fmt_p(r.p_holm)})"
                         + (", negligible" if r.negligible else ""))
        lines.append(f"| {a} vs {b} | " + " | ".join(cells) + " |")
    return lines


def render(comp, scenarios, tuned, train, test, budget, out: Path, page: Path,
           claims: dict | None = None, found: dict | None = None) -> str:
    """The page's section, every sentence from the statistics."""
    import tspend
    from tspend.cli.compare import seeds_text
    from tspend.studies.stats import fmt, markdown

    def rel(p) -> str:
        return Path(os.path.relpath(Path(p).resolve(), page.parent.resolve())).as_posix()

    trials, metric = budget["trials"], budget["metric"]
    per = budget.get("trials_per_parameter")
    start = budget.get("start_trials") or 0
    if per and start:
        budget_text = (f"**Budget, the same search for every kind:** {start} space-filling "
                       f"trials (a scrambled Sobol sequence, sampler seed 0: one point in each "
                       f"1/{start} of every range searched, whatever the number of settings), "
                       f"then {per} Optuna TPE trials per setting the kind searches, guided by "
                       f"every earlier score, × {len(train)} training seeds "
                       f"({seeds_text(train)}): a kind searching five settings gets "
                       f"{start} + {5 * per} trials, a kind searching one {start} + {per}. "
                       f"Where an optimum lay in the outer 5 % of its range, that edge was "
                       f"moved out and the kind tuned again with its full budget (the rounds "
                       f"column).")
    elif per:
        budget_text = (f"**Budget, the same per setting searched:** {per} Optuna TPE trials "
                       f"(sampler seed 0) per setting a kind searches, × {len(train)} training "
                       f"seeds ({seeds_text(train)}): a kind searching five settings (the "
                       f"paper's kinds: eta, gamma, Q, the pole of lambda, the boundary layer) "
                       f"gets {5 * per} trials, a kind searching one (PD's bandwidth, LQR's R, "
                       f"feedback linearisation's pole) {per}. Where an optimum lay in the outer "
                       f"5 % of its range, that edge was moved out and the kind tuned again "
                       f"with its full budget (the rounds column). Every closed-loop pole a "
                       f"search sets (PD's bandwidth, the poles of lambda, the sliding surface's "
                       f"pole) starts from the same range, 0.2-1000 rad/s (1000: the 1 ms "
                       f"sample's own limit); LQR's R sets its poles through the Riccati "
                       f"equation, so it has no pole range of its own.")
    else:
        budget_text = (f"**Budget, the same trials for every kind:** {trials} Optuna TPE trials "
                       f"(sampler seed 0) × {len(train)} training seeds ({seeds_text(train)}), "
                       f"whatever the number of settings a kind searches.")
    lines = [
        "## Fair comparison: every kind tuned on an equal budget, on randomised machines",
        "",
        f"Generated by `nice python benchmarks/fair_results.py` (tspend {tspend.__version__}; "
        f"{budget['runs']} runs of 20 s in {budget['wall_s'] / 60:.1f} min on a shared 2-core "
        f"machine, `--jobs {budget['jobs']}`; `--render` rewrites this section from the kept "
        f"runs). Test runs: `{rel(out / 'runs.parquet')}`; statistics: "
        f"`{rel(out / 'comparison.json')}`; the tuned scenarios, each runnable and headed by "
        f"its budget and scores: `{rel(out / 'tuned')}/`.",
        "",
        budget_text + f" Each trial minimises the median `{metric}` over the training seeds (a "
        f"run that fell or diverged scores worst)"
        + ("" if start else "; TPE's first 10 trials are random, so a kind searching one "
           "setting with fewer trials had a random search, over the part of its range the "
           "tried column shows")
        + f". The tuned kinds are then compared on the "
        f"{len(test)} test seeds "
        f"{seeds_text(test)}, disjoint from the training ones, paired by seed, over every "
        f"pair of kinds, with Holm's correction ({comp.settings['correction']}). A verdict "
        f"needs Holm-adjusted p < 0.05 and a 95% bootstrap interval of the median difference "
        f"excluding 0. Every kind is tuned on `{metric}` alone, so a kind may buy accuracy "
        f"with control effort (the `control_energy` and `tv_u_per_s` columns show the price), "
        f"and two kinds with the same search space (`second_type`, `first_type`) draw the "
        f"same trial points: where they end at different settings, their difference is the "
        f"tuning's as much as the law's.",
        "",
        "**What a seed varies here:** the machine and its initial state (`[randomize]`, "
        "[scenario-file.md](reference/scenario-file.md#randomize)), the same for every kind "
        "at that seed, and the adaptive controllers' initial parameters. The controllers are "
        "designed on the nominal machine.",
        "",
    ]
    for s in scenarios:
        lines.append(f"- `{s.name}`: {draws_text(s)}.")
    lines += ["", f"### Tuned settings (train and test score: median {metric})", "",
              "| scenario | kind | tuned | train | test |", "|---|---|---|---:|---:|"]
    for (scn, kind), t in tuned.items():
        vals = ", ".join(f"{k} = {_short(v)}" for k, v in t["values"].items())
        lines.append(f"| {scn} | {kind} | {vals} | {fmt(t['train_score'])} | "
                     f"{fmt(t['test_score'])} |")
    if any("space" in t for t in tuned.values()):
        lines += ["", "### Optima and ranges", "",
                  "Each searched number, the range of its last tuning round and where the "
                  "optimum lies in it (0 % the low end, 100 % the high end; on the log scale "
                  "for a log range). An optimum in the outer 5 % is marked: where it is at a "
                  "setting's own limit (a boundary layer of 0) the range cannot be widened.", "",
                  "| scenario | kind | setting | range | optimum | position | tried (lowest-"
                  "highest position) | rounds (trials) |",
                  "|---|---|---|---|---:|---:|---|---|"]
        found = found or {}
        for (scn, kind), t in tuned.items():
            for key, sp in t.get("space", {}).items():
                edge = sp["position"] < 0.05 or sp["position"] > 0.95
                at = found.get((scn, kind), {}).get(key)
                tried = (f"{100 * min(at):.1f}-{100 * max(at):.1f} % ({len(at)})" if at
                         else "—")
                lines.append(f"| {scn} | {kind} | {key} | {fmt(sp['low'])}-{fmt(sp['high'])} "
                             f"{'log' if sp['log'] else 'linear'} | {fmt(sp['optimum'])} | "
                             f"{100 * sp['position']:.1f} %{' (at the edge)' if edge else ''} | "
                             f"{tried} | {', '.join(map(str, t.get('rounds', [])))} |")
        if found:
            lines += ["", f"![Each study's tried points against its range]"
                          f"({rel(TRIALS_FIGURE)})", "",
                      "*Each study's tried points (the last round's) against its range; x: "
                      "the tuned optimum.*"]
    if claims and claims.get("claims"):
        lines += ["", "### Headline claims on both seed sets", "",
                  f"Test seeds {claims['test_seeds']} ({claims['family_test']}); confirmation "
                  f"seeds {claims['confirm_seeds']}, fixed before any wording "
                  f"({claims['family_confirm']}). Shown only when both sets give the same "
                  f"verdict.", ""]
        lines += [f"- {claim_sentence(c, claims['test_seeds'], claims['confirm_seeds'])}."
                  for c in claims["claims"]]
        lines += [""] + context_notes(claims)
    lines += ["", "### Verdicts that survive Holm's correction", "",
              "Per pair and metric, the better kind, the median ratio worse/better over the "
              "test seeds and the Holm-adjusted p (— : no difference shown).", ""]
    for s in scenarios:
        lines += [f"**{s.name}**", ""] + pair_table(comp, s.name) + [""]
    paper = comp.pairs[(comp.pairs.verdict != "") & (~comp.pairs.negligible)
                       & ((comp.pairs.a == "second_type") | (comp.pairs.b == "second_type"))]
    if len(paper):
        lines += ["The paper's controller (`second_type`) against each tuned kind, in words:",
                  ""]
        lines += [f"- {sentence(r)}." for r in paper.sort_values(["scenario", "b"]).itertuples()]
    holds, fails = earlier_claims(comp, ROOT / "docs" / "results" / "comparison.json")
    lines += ["", "### Earlier claims re-examined", "",
              "The verdicts below were stated on the fixed machine with hand-tuned baselines "
              "(the rest of this page, `docs/results/comparison.json`; the Holm p there is "
              f"recomputed over that page's {_earlier_rows()} rows). Each is checked against "
              "the tuned "
              "kinds on the randomised machine above.", "",
              f"**No longer hold ({len(fails)}):**", ""]
    lines += [f"- {f}." for f in fails] or ["- none."]
    lines += ["", f"**Still hold ({len(holds)}):**", ""]
    lines += [f"- {h}." for h in holds] or ["- none."]
    tables = ("\n" + markdown(comp, seeds_text(test))).replace("\n### ", "\n#### ").strip()
    lines += ["", "### Tables", "", tables]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
