"""Tuning curves of the fair comparison: best score so far against trials, per kind.

    python benchmarks/tuning_curves.py            # print the section
    python benchmarks/tuning_curves.py --write    # also write the data, figure and section

Reads the studies' journal that ``benchmarks/fair_results.py`` keeps
(``docs/results/fair/tune.journal``: every trial of every Optuna study, in order; read from
a copy, so no lock file lands beside it) and, per scenario and kind, each study in the order
it ran (a second study is the re-tune after the range was widened at an edge), the best
training score after each trial (median rmse over the training seeds; a run that fell,
diverged or failed scores worst, inf). ``--write`` writes
``docs/results/fair/tuning_curves.json`` (the curves), ``docs/results/figures/
tuning_curves.png`` and the section between the markers of docs/results.md;
tools/check_claims.py rebuilds that section from the JSON. Under ``TSPEND_BENCH_SHORT=1``
(tools/check_docs.py) ``--write`` goes to the working folder instead.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import tempfile
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from short_mode import short  # noqa: E402

FAIR = ROOT / "docs" / "results" / "fair"
DATA = FAIR / "tuning_curves.json"
FIGURE = ROOT / "docs" / "results" / "figures" / "tuning_curves.png"
PAGE = ROOT / "docs" / "results.md"
BEGIN = "<!-- benchmarks/tuning_curves.py: begin (generated; rerun it, do not edit) -->"
END = "<!-- benchmarks/tuning_curves.py: end -->"
#: fractions of a study's trials at which the table reads the curve
AT = (0.25, 0.5, 0.75, 1.0)


def curves(journal: Path) -> list[dict]:
    """Per study, in the journal's order: scenario, kind, round, parameters searched, the
    trials' scores and the best so far after each."""
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    warnings.simplefilter("ignore")
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    out, rounds = [], {}
    with tempfile.TemporaryDirectory() as d:
        copy = Path(d) / "tune.journal"
        shutil.copyfile(journal, copy)
        storage = JournalStorage(JournalFileBackend(str(copy)))
        for s in optuna.get_all_study_summaries(storage):
            # names are tspend-SCENARIO-KIND-HASH (tspend.studies.tune)
            scenario, kind = _name(s.study_name)
            study = optuna.load_study(study_name=s.study_name, storage=storage)
            trials = sorted((t for t in study.trials if t.value is not None),
                            key=lambda t: t.number)
            scores = [float(t.value) for t in trials]
            best, run = [], math.inf
            for v in scores:
                run = min(run, v)
                best.append(run)
            key = (scenario, kind)
            rounds[key] = rounds.get(key, 0) + 1
            out.append({"study": s.study_name, "scenario": scenario, "kind": kind,
                        "round": rounds[key],
                        "parameters": len(trials[0].params) if trials else 0,
                        "scores": scores, "best": best})
    return out


def _name(study: str) -> tuple[str, str]:
    from tspend.controllers import KINDS

    body = study.removeprefix("tspend-").rsplit("-", 1)[0]
    for kind in sorted(KINDS, key=len, reverse=True):
        if body.endswith("-" + kind):
            return body[: -len(kind) - 1], kind
    raise ValueError(f"{study}: no controller kind in the study's name")


def _fmt(v: float) -> str:
    return "inf" if math.isinf(v) else f"{v:.3g}"


def section(data: list[dict]) -> str:
    """docs/results.md's section, from the curves."""
    lines = ["Best training score so far (median rmse over the training seeds, rad; inf: every "
             "trial so far had a run that fell, diverged or failed) after a quarter, half, "
             "three quarters and all of each study's trials, and the trial that last improved "
             "it. A kind's second study is its re-tune after an optimum sat in the outer 5 % of "
             "its range (the range widened). From `docs/results/fair/tune.journal` by "
             "`python benchmarks/tuning_curves.py --write` (the curves: "
             "`results/fair/tuning_curves.json`; the figure: "
             "`results/figures/tuning_curves.png`).", ""]
    for scenario in dict.fromkeys(c["scenario"] for c in data):
        lines += [f"**{scenario}**", "",
                  "| kind | study | parameters | trials | " + " | ".join(
                      f"best after {int(100 * a)} %" for a in AT) + " | last improvement at trial |",
                  "|---|---|---|---|" + "---|" * len(AT) + "---|"]
        for c in (c for c in data if c["scenario"] == scenario):
            n, best = len(c["best"]), c["best"]
            cells = [_fmt(best[max(0, math.ceil(a * n) - 1)]) if n else "n/a" for a in AT]
            last = next((i + 1 for i in range(n - 1, -1, -1)
                         if i == 0 or best[i] < best[i - 1]), 0)
            lines.append(f"| {c['kind']} | {c['round']} | {c['parameters']} | {n} | "
                         + " | ".join(cells) + f" | {last} |")
        lines.append("")
    lines.append("![best training score so far against trials, per kind and scenario]"
                 "(results/figures/tuning_curves.png)")
    return "\n".join(lines).strip()


def figure(data: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenarios = list(dict.fromkeys(c["scenario"] for c in data))
    fig, axes = plt.subplots(1, len(scenarios), figsize=(6 * len(scenarios), 4.2), squeeze=False)
    for ax, scenario in zip(axes[0], scenarios):
        for c in (c for c in data if c["scenario"] == scenario):
            y = [v if math.isfinite(v) else float("nan") for v in c["best"]]
            label = c["kind"] + ("" if c["round"] == 1 else f" (re-tune {c['round']})")
            ax.plot(range(1, len(y) + 1), y, marker=".", label=label)
        ax.set_yscale("log")
        ax.set_xlabel("trial")
        ax.set_ylabel("best median rmse so far (rad)")
        ax.set_title(scenario)
        ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--journal", default=str(FAIR / "tune.journal"),
                    help="the studies' journal (default docs/results/fair/tune.journal)")
    ap.add_argument("--write", action="store_true",
                    help="write the curves, the figure and docs/results.md's section")
    a = ap.parse_args()
    journal = Path(a.journal)
    if not journal.is_file():
        ap.error(f"--journal: no file {journal}")
    data = curves(journal)
    text = section(data)
    print(text)
    if a.write:
        here = short()
        data_path = Path(DATA.name) if here else DATA
        fig_path = Path(FIGURE.name) if here else FIGURE
        page = Path(PAGE.name) if here else PAGE
        data_path.write_text(json.dumps(data, indent=1) + "\n")
        figure(data, fig_path)
        if here:
            page.write_text(f"{BEGIN}\n{text}\n{END}\n")
            return 0
        doc = page.read_text(encoding="utf-8")
        if BEGIN in doc:
            head, rest = doc.split(BEGIN, 1)
            doc = head + BEGIN + "\n" + text + "\n" + END + rest.split(END, 1)[1]
        else:
            doc = doc.rstrip("\n") + ("\n\n## Tuning curves\n\n" + BEGIN + "\n" + text + "\n"
                                      + END + "\n")
        page.write_text(doc, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
