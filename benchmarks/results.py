"""Regenerate the results page, docs/results.md, and everything it shows.

    python benchmarks/results.py                      # 20 seeds, every controller kind
    python benchmarks/results.py --seeds 0:5 --jobs 2 --out /tmp/r --page /tmp/r.md
    python benchmarks/results.py --fresh          # after a scenario file changed

It runs (through ``tspend.sweep``, resumable: the tables are kept in ``--out``):

1. the four paper cases and the MuJoCo pendulum, every controller kind in
   ``COMPARED_KINDS``, seeds 0-19 (``runs.parquet``), and the five real-world pendulum
   scenarios (``REAL_WORLD``);
2. a heat map sweep of Example 2 over eta x gamma, second and first type, 5 seeds
   (``heatmap.parquet``);

then compares them (``tspend.studies.stats``: median [Q1, Q3], paired bootstrap intervals,
Wilcoxon p, win rates; ``comparison.json``), draws the figures (``figures/``, PNG + CSV)
and writes the page.  Every sentence of the page's verdicts is generated from the
statistics, so rerunning it can never leave a claim the numbers no longer support.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAPER_SCENARIOS = ("ex1_nonaffine_case1", "ex1_nonaffine_case2", "ex2_duffing",
                   "ex3_pendulum_ode", "pendulum_mujoco")
#: the real-world pendulum scenarios the page also holds
REAL_WORLD = ("pendulum_payload_step", "pendulum_sensor_noise", "pendulum_saturated",
              "pendulum_friction", "pendulum_finite_rail")
#: the kinds the page compares: the paper's two and its five baselines (the other kinds of
#: KINDS, swing-up, MPC, planned and learned, need machines or files these scenarios lack)
COMPARED_KINDS = ("second_type", "first_type", "pd", "lqr", "feedback_linearization",
                  "sliding_mode", "wang_indirect")
METRICS = ("rmse", "rmse_ss", "max_abs_e_ss", "control_energy", "tv_u_per_s")
HEATMAP = ("ex2_duffing", {"controller.eta": [0.1, 0.5, 2.0], "controller.gamma": [0.1, 0.3, 1.0]})


def verdict_sentences(comp, scenario: str, a: str, b: str) -> list[str]:
    """One sentence per metric: who is lower at how many seeds, by what ratio, how sure."""
    from tspend.studies.stats import fmt, fmt_ratio, _fmt_p

    pairs = comp.pairs
    rows = pairs[(pairs.scenario == scenario) & (pairs.a == a) & (pairs.b == b)]
    out = []
    for r in rows.itertuples():
        if r.pairs == 0:
            out.append(f"`{r.metric}`: no paired seeds ({r.unpaired} unpaired).")
            continue
        head = (f"`{r.metric}`: {a} lower at {r.wins:g} of {r.pairs} seeds, median ratio "
                f"{fmt_ratio(r.median_ratio)}, median difference {fmt(r.median_difference)} "
                f"[{fmt(r.ci_low)}, {fmt(r.ci_high)}]")
        if r.deterministic:
            tail = "; neither depends on the seed, so this is one observation, not a test"
        else:
            p, ph = _fmt_p(r.p_value), _fmt_p(r.p_holm)
            tail = (f", p {p}" if p.startswith("<") else f", p = {p}") + \
                (f", Holm-adjusted p {ph}" if ph.startswith("<") else f", Holm-adjusted p = {ph}")
            if r.a_worse and r.median_ratio < 1:  # A better on the median, but a losing tail
                tail += f"; {a} worse on {r.a_worse} of {r.pairs} seeds (worst {fmt_ratio(r.worst_ratio)}x)"
        if r.verdict and r.negligible:
            verdict = f"{r.verdict} lower, but by less than 1%: negligible"
        elif r.verdict:
            verdict = f"**{r.verdict} better**"
        else:
            verdict = "no difference shown"
        div = []
        if r.a_diverged or r.b_diverged:
            div.append(f"diverged: {a} {r.a_diverged}, {b} {r.b_diverged}")
        out.append(f"{head}{tail}: {verdict}" + (f" ({'; '.join(div)})" if div else "") + ".")
    return out


STATISTICS_HEADING = "## What the statistics say: second type against first type"


def statistics_section(table, scenarios, kinds, seeds):
    """(the comparison, the page's lines under :data:`STATISTICS_HEADING` up to its figures):
    the verdict sentences and the tables, all from ``table`` (tools/check_claims.py rebuilds
    them from the committed runs.parquet)."""
    from tspend.cli.compare import seeds_text
    from tspend.studies.stats import compare, markdown

    reference = "second_type"
    comp = compare(table, kinds, METRICS, pairs=[(reference, k) for k in kinds if k != reference])
    lines = [
        "",
        "The paper's claim is that adapting the membership functions (second type) "
        "beats adapting the consequents alone (first type). Per scenario, paired over "
        "the seeds (a verdict needs a Holm-adjusted Wilcoxon p < 0.05, the family being "
        "every pair, metric and scenario of the comparison, and a 95% bootstrap interval "
        "of the median difference that excludes 0):",
        "",
    ]
    for scn in scenarios:
        if "first_type" in kinds and reference in kinds:
            lines += [f"**{scn}**", ""]
            lines += [f"- {s}" for s in verdict_sentences(comp, scn, reference, "first_type")]
            lines.append("")
    lines += ["## Tables", "", markdown(comp, seeds_text(seeds)), ""]
    return comp, lines


def shape_available() -> bool:
    """The kernel's membership-shape measure and projection option are present."""
    import importlib.util
    from dataclasses import fields

    from tspend.config import ControllerConfig

    return (importlib.util.find_spec("tspend.controllers.paper.membership_shape") is not None
            and any(f.name == "shape_projection" for f in fields(ControllerConfig)))


def interpretability_section(seeds, jobs, out: Path, fig, rel) -> list[str]:
    """Example 2, second type with free sets against the shape-preserving projection:
    the sets' shape after 20 s (tspend.controllers.paper.membership_shape) and the paired accuracy cost."""
    import pandas as pd

    from tspend import load_scenario, override, run
    from tspend.cli.compare import seeds_text
    from tspend.studies.figures import SetsCapture, membership_figure
    from tspend.controllers.paper.membership_shape import membership_shape
    from tspend.studies.stats import compare, fmt, markdown
    from tspend.sweep import sweep

    scn_name, key = "ex2_duffing", "controller.shape_projection"
    labels = {"off": "second_type", "unimodal": "second_type+unimodal"}
    table = sweep(scn_name, grid={key: list(labels)}, seeds=seeds, controllers=["second_type"],
                  jobs=jobs, out=out / "shape.parquet", progress=True)
    table = table.assign(controller=table[key].map(labels)).drop(columns=[key])
    comp = compare(table, list(labels.values()), METRICS,
                   pairs=[(labels["unimodal"], labels["off"])])
    shapes = []
    for seed in seeds:
        for mode, label in labels.items():
            scn = override(load_scenario(scn_name), **{key: mode, "run.seed": seed})
            res = run(scn, keep_history=False)
            s = membership_shape(res.controller)
            shapes.append({"option": label, "seed": seed, "status": res.status,
                           "score": s["score"], "unimodal": s["unimodal"],
                           "ordered": s["ordered"]})
    shapes = pd.DataFrame(shapes)
    shapes.to_csv(out / "shape_scores.csv", index=False)
    capture = SetsCapture()
    scn = override(load_scenario(scn_name), **{key: "unimodal"})
    run(scn, sinks=[capture])
    png = membership_figure(fig, capture, "ex2_duffing_memberships_unimodal",
                            f"Example 2, second_type with shape_projection = unimodal, seed "
                            f"{scn.run.seed}")
    lines = ["## Interpretability: do the adapted sets stay fuzzy sets?", "",
             "The second type moves the B-spline control points freely, so a set can grow "
             "a second hump or overtake its neighbour. `tspend.controllers.paper.membership_shape` scores the "
             "sets after the run: the fraction of sets that are unimodal and in order (1 "
             "for the initial sets). The option `controller.shape_projection = "
             "\"unimodal\"` projects the control points so that the score stays 1. "
             f"Example 2, seeds {seeds_text(seeds)}:", "",
             "| option | score: median [min, max] | unimodal sets | ordered inputs |",
             "|---|---|---|---|"]
    for label in labels.values():
        part = shapes[shapes.option == label]
        cell = lambda c: (f"{fmt(part[c].median())} [{fmt(part[c].min())}, "  # noqa: E731
                          f"{fmt(part[c].max())}]")
        lines.append(f"| {label} | {cell('score')} | {cell('unimodal')} | {cell('ordered')} |")
    lines += ["", "The accuracy cost of keeping the shapes, paired by seed:", "",
              markdown(comp, seeds_text(seeds)), "",
              f"![memberships with the projection]({rel(png)})", "",
              "*Example 2, second type with the shape projection: membership functions "
              f"before (dashed) and after (solid)* ([data]({rel(png.with_suffix('.csv'))}))",
              ""]
    return lines


def fair_section(page: Path) -> str:
    """The section benchmarks/fair_results.py wrote into the page (without its markers),
    or "" when there is none."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from fair_results import BEGIN, END

    text = page.read_text() if page.is_file() else ""
    if BEGIN not in text or END not in text:
        return ""
    return text.split(BEGIN, 1)[1].split(END, 1)[0].strip("\n")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "results"), help="tables and figures")
    ap.add_argument("--page", default=str(ROOT / "docs" / "results.md"), help="the Markdown page")
    ap.add_argument("--seeds", default="0:20")
    ap.add_argument("--heatmap-seeds", default="0:5")
    ap.add_argument("--scenarios", default=",".join(PAPER_SCENARIOS + REAL_WORLD))
    ap.add_argument("--controller", default=",".join(COMPARED_KINDS),
                    help="kinds K1,K2,... (default: the paper's two and its five baselines)")
    ap.add_argument("--jobs", type=int)
    ap.add_argument("--no-heatmap", action="store_true")
    ap.add_argument("--fresh", action="store_true",
                    help="start the tables in --out afresh (needed when a scenario file "
                         "changed: a sweep table never mixes two versions of a scenario)")
    args = ap.parse_args(argv)

    import tspend
    from tspend.studies.figures import Figures, box_figure, heatmap_figure, paper_figures
    from tspend.studies.stats import to_json
    from tspend.sweep import sweep
    from tspend.sweep.plan import parse_seeds
    from tspend.cli.compare import seeds_text

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.fresh:
        for name in ("runs", "heatmap", "shape"):
            for p in (out / f"{name}.parquet", out / f"{name}.parquet.journal"):
                p.unlink(missing_ok=True)
    scenarios = [s.strip() for s in args.scenarios.split(",") if s.strip()]
    kinds = [k.strip() for k in args.controller.split(",") if k.strip()]
    seeds = parse_seeds(args.seeds)
    started = time.perf_counter()

    print(f"runs: {len(scenarios)} scenarios x {len(kinds)} kinds x {len(seeds)} seeds",
          file=sys.stderr)
    table = sweep(scenarios, seeds=seeds, controllers=kinds, jobs=args.jobs,
                  out=out / "runs.parquet", progress=True)
    table = table[table.controller.isin(kinds) & table.seed.isin(seeds)]
    comp, statistics = statistics_section(table, scenarios, kinds, seeds)
    doc = to_json(comp)
    doc.update(seeds=seeds, scenarios=scenarios, version=tspend.__version__)
    (out / "comparison.json").write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n")

    fig = Figures(out / "figures", overwrite=True)
    paper_pngs = paper_figures(fig, ("second_type", "first_type"))
    box_pngs = [box_figure(fig, table, m, f"box_{m}", kinds,
                           title=f"{m} over seeds {seeds_text(seeds)}")
                for m in ("rmse_ss", "control_energy", "tv_u_per_s")]
    heat_png = None
    if not args.no_heatmap:
        scn, grid = HEATMAP
        hseeds = parse_seeds(args.heatmap_seeds)
        heat = sweep(scn, grid=grid, seeds=hseeds, controllers=["second_type", "first_type"],
                     jobs=args.jobs, out=out / "heatmap.parquet", progress=True)
        keys = list(grid)
        heat_png = heatmap_figure(fig, heat, keys[1], keys[0], "rmse_ss", "heatmap_ex2_eta_gamma",
                                  title=f"{scn}: median rmse_ss over seeds "
                                        f"{seeds_text(hseeds)}")

    page = Path(args.page)
    def rel(p) -> str:  # links relative to the page
        return Path(os.path.relpath(Path(p).resolve(), page.parent.resolve())).as_posix()

    lines = [
        "# Results: second type against first type and the baselines, over seeds",
        "",
        "Generated by `python benchmarks/results.py` (tspend "
        f"{tspend.__version__}); do not edit by hand: rerun it. Every run is a row of "
        f"`{rel(out / 'runs.parquet')}`; the statistics are in "
        f"`{rel(out / 'comparison.json')}`; the methods are in "
        "[statistics.md](statistics.md).",
        "",
        f"Scenarios: {', '.join(scenarios)}. Controller kinds: {', '.join(kinds)}. "
        f"Seeds {seeds_text(seeds)} (the seed draws the initial consequents; reference, "
        "disturbance and plant are the scenario's). Each controller runs at every seed, "
        "so the comparisons are paired by seed. A diverged run counts as the worst "
        "outcome (∞); failed runs (the kind cannot run on that plant) are counted and "
        "left out of the pairs.",
        "",
        STATISTICS_HEADING,
        *statistics,
              "## Figures", "",
              "Each figure has its data beside it as CSV (same name). The paper's figures "
              "are single runs (the scenario's own seed) and illustrate; the claims above "
              "rest on the tables.", ""]
    captions = {
        "ex1_nonaffine_case1_tracking": "Example 1, case 1: x1, x2 against the reference",
        "ex1_nonaffine_case2_tracking": "Example 1, case 2: x1, x2 against the reference",
        "ex2_duffing_tracking": "Example 2: x1, x2 against the reference",
        "ex2_duffing_u": "Example 2: the control u over 0-15 s",
        "ex2_duffing_memberships": "Example 2: membership functions before and after adaptation",
        "ex3_pendulum_ode_tracking": "Example 3: θ, θ' against the reference",
    }
    for png in paper_pngs:
        lines += [f"![{captions.get(png.stem, png.stem)}]({rel(png)})", "",
                  f"*{captions.get(png.stem, png.stem)}* ([data]({rel(png.with_suffix('.csv'))}))", ""]
    for png in box_pngs:
        lines += [f"![{png.stem}]({rel(png)})", "",
                  f"*{png.stem.replace('box_', '')} across seeds, one box per kind (boxes: "
                  f"completed runs; crosses: diverged runs)* ([data]({rel(png.with_suffix('.csv'))}))", ""]
    if heat_png is not None:
        lines += [f"![heat map]({rel(heat_png)})", "",
                  "*Example 2: median rmse_ss over a grid of eta and gamma* "
                  f"([data]({rel(heat_png.with_suffix('.csv'))}))", ""]
    if shape_available():
        lines += interpretability_section(seeds, args.jobs, out, fig, rel)
    lines.append(f"Wall time to regenerate: {time.perf_counter() - started:.0f} s.")
    page.parent.mkdir(parents=True, exist_ok=True)
    text = "\n".join(lines) + "\n"
    kept = fair_section(page)
    if kept:  # benchmarks/fair_results.py's section, kept as that script wrote it
        from fair_results import splice

        text = splice(text, kept)
    old = page.read_text(encoding="utf-8") if page.is_file() else ""
    from tuning_curves import BEGIN as TC_BEGIN, END as TC_END

    if TC_BEGIN in old and TC_END in old:  # benchmarks/tuning_curves.py's section, kept
        curves = old.split(TC_BEGIN, 1)[1].split(TC_END, 1)[0]
        text = text.rstrip("\n") + f"\n\n## Tuning curves\n\n{TC_BEGIN}{curves}{TC_END}\n"
    page.write_text(text)
    print(f"wrote {page}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
