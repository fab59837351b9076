"""The predictive safety filter (--safety mpsc) over seeds, and its compute per sample
against the bare controller in the same run (docs/safety.md, "Predictive safety
certification").

    python benchmarks/safety_mpsc.py [--seeds 20] [--first-seed 0] [--kinds pd,second_type]
                                     [--machines cartpole_rail,furuta_arm] [--baselines]
    python benchmarks/safety_mpsc.py --timing-only [--samples 5000]    # run it three times

The machines and drawn starts are benchmarks/safety_filter.py's (MACHINES): the
randomised cart-pole on a 1 m rail (3 s), the Furuta with its arm's stop (1.5 s, x0
drawn: pendulum +/-0.15 rad, its rate +/-0.5 rad/s), and (--machines double_rail
--kinds lqr,policy --baselines) the double cart-pole with a hard +/-0.5 m box on its cart
(3 s, x0 drawn: lower link +/-0.1 rad, its rate +/-0.3 rad/s; lqr with R = 1e-4).  Each kind runs behind mpsc on
seeds F..F+N-1 (F = --first-seed; 200: the confirmation set).  The bare and cbf runs of
seeds 0.. are read from safety_filter.py's committed data
(benchmarks/results/safety_filter_<machine>_hocbf.csv) unless --baselines reruns them;
another seed set's are run here (safety_mpsc_<machine>_seeds<F>_baselines.csv).  Writes
benchmarks/results/safety_mpsc_<machine>[_seeds<F>].csv (one row per run) and its entry
of benchmarks/results/safety_mpsc.json (the summary docs/safety.md quotes).

The timing: one filtered closed loop of pendulum_finite_rail with a 1 m rail (pd), then
every recorded sample's observation replayed, interleaved, through the bare pd and the
filtered controller (pd + mpsc), wall time per call; medians and their ratio, and which
step answered (the fast path, the bisection, the QP); appended to
benchmarks/results/safety_mpsc_timing.json.

    python benchmarks/safety_mpsc.py --timing-only --timing-machine cartpole_rail --seeds 3

The randomised timing: per seed, pd behind mpsc in the closed loop (the runner's time per
sample, at normal priority, the collector running), bare pd on its observations, then a
fresh filter on the same observations paced at the control period under the rig runner's
real-time settings (SCHED_FIFO, memory locked, the collector paused: what a rig's loop
gives it); one line per seed, appended to safety_mpsc_timing.json's randomized_runs.

Every run also records the machine's steal time over it (``steal_ms``, ``paced_steal_ms``;
the rows' ``steal_ms`` column, summed per kind): on a virtual machine the hypervisor's
other guests take the CPU for spells that the filter's clock counts as its own work.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import time
import warnings
from pathlib import Path

import numpy as np
from short_mode import short, short_defaults

RESULTS = Path(__file__).resolve().parent / "results"
#: where this script writes: the committed results, or under short mode (tools/check_docs.py)
#: the working folder, so a smoke run never replaces them (it still reads safety_filter's CSV)
OUT = Path(".") if short() else RESULTS


def steal_ms() -> float:
    """The machine's steal time so far (ms; NaN where the kernel does not say): how long
    the hypervisor ran something else while this guest's virtual CPUs wanted to run
    (``/proc/stat``'s first line, every CPU, in clock ticks of 10 ms).  A thread's CPU
    clock counts it as running, so the filter counts a sample slowed by it as a step over
    its estimate, not as a wait for a core."""
    try:
        ticks = int(Path("/proc/stat").read_text().split("\n", 1)[0].split()[8])
    except (OSError, IndexError, ValueError):
        return math.nan
    return 1e3 * ticks / os.sysconf("SC_CLK_TCK")


def mpsc_rows(machine: str, kinds: list[str], seeds: int, first: int = 0,
              refuse: bool = False) -> list[dict]:
    from safety_filter import MACHINES, kinds_of
    from tspend import load_scenario, override, run

    name, changes = MACHINES[machine]
    base = override(load_scenario(name), **changes, **{"safety.filter": "mpsc",
                                                       "safety.refuse_unadmitted": refuse})
    out = []
    for kind in kinds_of(machine, kinds):
        for seed in range(first, first + seeds):
            t0, stolen = time.perf_counter(), steal_ms()
            r = run(override(base, **{"run.seed": seed}), controller=kind, keep_history=False)
            stolen = steal_ms() - stolen
            m = r.metrics
            sf = m.get("safety_filter", {})
            out.append({"scenario": machine, "controller": f"{kind}+mpsc", "seed": seed,
                        "status": r.end.status, "rmse": m["rmse"],
                        "violations": m["violations"], "max_violation": m["max_violation"],
                        "safety.intervention_share": sf.get("intervention_share"),
                        "safety.qp_ms": (sf.get("qp_ms") or {}).get("median"),
                        "safety.fallbacks": sf.get("fallbacks"),
                        "safety.no_plan": sf.get("no_plan"),
                        "safety.bisected": sf.get("bisected_samples"),
                        "safety.infeasible": sf.get("infeasible_samples"),
                        "safety.max_slack": sf.get("max_slack"),
                        "safety.fast_path": sf.get("fast_path_samples"),
                        "safety.uncertified": sf.get("uncertified_samples"),
                        "safety.certified": sf.get("certified_samples"),
                        "safety.on_plan": sf.get("on_certified_plan_samples"),
                        "safety.terminal_set": (sf.get("certificate") or {}).get("terminal_set"),
                        "safety.admitted": sf.get("start_admitted"),
                        "safety.admitted_by_robust": sf.get("start_admitted_by_robust_plan"),
                        "safety.refusal": sf.get("start_refusal"),
                        "safety.admission_ms": sf.get("admission_ms"),
                        "safety.time_p99_ms": (sf.get("time_per_sample_ms") or {}).get("p99"),
                        "safety.time_max_ms": (sf.get("time_per_sample_ms") or {}).get("max"),
                        "safety.over_budget": sf.get("over_budget_samples"),
                        **{f"safety.over_budget.{cause}": n
                           for cause, n in (sf.get("over_budget_by_cause") or {}).items()},
                        "safety.budget_ms": sf.get("budget_ms"),
                        "load_average_1min": os.getloadavg()[0],
                        "steal_ms": stolen,
                        "samples": sf.get("samples")})
            print(f"{machine} {kind}+mpsc seed {seed}: {r.end.status}, violations "
                  f"{m['violations']}, {time.perf_counter() - t0:.0f} s", flush=True)
            # written as it goes: an interrupted benchmark keeps the runs it made
            import pandas as pd

            partial = OUT / f"safety_mpsc_{machine}{tag(first, refuse)}.partial.csv"
            pd.DataFrame(out).to_csv(partial, index=False)
    return out


def tag(first: int, refuse: bool = False) -> str:
    """The file-name suffix of a seed set: none for seeds from 0, ``_seeds200`` from 200;
    ``_refuse`` after it for runs with safety.refuse_unadmitted."""
    return (f"_seeds{first}" if first else "") + ("_refuse" if refuse else "")


def baseline_rows(machine: str, kinds: list[str], seeds: int, rerun: bool,
                  first: int = 0) -> list[dict]:
    """Bare and cbf on the same seeds: safety_filter.py's rows (rerun, or its CSV; another
    seed set than 0.. is always rerun, and kept in safety_mpsc_<machine>_seeds<F>_baselines.csv)."""
    import pandas as pd

    if first:
        path = OUT / f"safety_mpsc_{machine}{tag(first)}_baselines.csv"
        if path.is_file() and not rerun:
            return pd.read_csv(path).to_dict("records")
        from safety_filter import rows

        out = rows(machine, kinds, seeds, first=first)
        pd.DataFrame(out).to_csv(path, index=False)
        return out
    kept = OUT / f"safety_mpsc_{machine}_baselines.csv"
    if rerun:
        from safety_filter import rows

        out = rows(machine, kinds, seeds)
        # kept, so that --summarize reads the rows the filter was compared with
        pd.DataFrame(out).to_csv(kept, index=False)
        return out
    table = pd.read_csv(kept if kept.is_file() else
                        RESULTS / f"safety_filter_{machine}_hocbf.csv")
    keep = [k + s for k in kinds for s in ("", "+cbf")]
    table = table[table.controller.isin(keep) & (table.seed < seeds)]
    return table.to_dict("records")


def summary(table) -> dict:
    out = {}
    for ctrl, g in table.groupby("controller", sort=False):
        row = {"runs": int(len(g)), "completed": int((g.status == "completed").sum()),
               "statuses": {s: int(n) for s, n in g.status.value_counts().items()},
               "runs_with_samples_outside": int((g.violations > 0).sum()),
               "samples_outside_max": int(g.violations.max()),
               # tracking cost: rmse over the runs that completed (an ended run's rmse
               # covers a shorter run)
               "rmse_completed_median": (float(g.rmse[g.status == "completed"].median())
                                         if (g.status == "completed").any() else None)}
        if "safety.fallbacks" in g and g["safety.fallbacks"].notna().any():
            n = g["samples"].astype(float)
            row.update({
                "intervention_share_median": float(g["safety.intervention_share"].median()),
                "time_per_sample_ms_median": float(g["safety.qp_ms"].median()),
                "fallback_share_median": float(((g["safety.fallbacks"] + g["safety.no_plan"])
                                                / n).median()),
                "infeasible_share_median": float((g["safety.infeasible"] / n).median()),
                "max_slack": float(g["safety.max_slack"].max())})
        if "safety.certified" in g and g["safety.certified"].notna().any():
            n = g["samples"].astype(float)
            row.update({
                # issue 54's columns: certified share over all samples, uncertified samples,
                # time per sample (median of run medians, largest p99, largest max)
                "certified_share": float(g["safety.certified"].sum() / n.sum()),
                # steps 1-3: certified at the sample or the earlier certified plan going on
                **({"on_certified_plan_share": float(g["safety.on_plan"].sum() / n.sum()),
                    "on_certified_plan_share_min_run": float((g["safety.on_plan"] / n).min())}
                   if "safety.on_plan" in g and g["safety.on_plan"].notna().all() else {}),
                "fallback_share": float(g["safety.fallbacks"].sum() / n.sum()),
                "uncertified_samples": int(g["safety.uncertified"].sum()),
                "runs_with_uncertified": int((g["safety.uncertified"] > 0).sum()),
                "starts_admitted": int(g["safety.admitted"].astype(bool).sum()),
                **({"starts_admitted_by_robust_plan":
                    int(g["safety.admitted_by_robust"].astype(bool).sum()),
                    "admission_ms_max": float(g["safety.admission_ms"].max())}
                   if "safety.admitted_by_robust" in g
                   and g["safety.admitted_by_robust"].notna().all() else {}),
                "time_per_sample_ms_p99_max": float(g["safety.time_p99_ms"].max()),
                "time_per_sample_ms_max": float(g["safety.time_max_ms"].max()),
                "over_budget_samples": int(g["safety.over_budget"].sum()),
                **({"over_budget_by_cause": {
                    c.rsplit(".", 1)[1]: int(g[c].sum())
                    for c in g.columns if c.startswith("safety.over_budget.")}}
                   if any(c.startswith("safety.over_budget.") for c in g.columns) else {}),
                "budget_ms": float(g["safety.budget_ms"].iloc[0]),
                "load_average_1min_median": float(g["load_average_1min"].median()),
                **({"steal_ms": float(g["steal_ms"].sum()),
                    "runs_with_steal": int((g["steal_ms"] > 0).sum())}
                   if "steal_ms" in g and g["steal_ms"].notna().all() else {})})
        out[ctrl] = row
    return out


def markdown_rows(table, machine: str) -> str:
    """The table docs/safety.md shows: per kind, bare / cbf / mpsc endings and samples
    outside, and mpsc's own counters."""
    lines = []
    for kind in dict.fromkeys(c.split("+")[0] for c in table.controller):
        cells = []
        for suffix in ("", "+cbf", "+mpsc"):
            g = table[table.controller == kind + suffix]
            ended = ", ".join(f"{n} {st}" for st, n in g.status.value_counts().items()
                              if st != "completed")
            cells.append(f"{int((g.status == 'completed').sum())}/{len(g)} completed"
                         + (f" ({ended})" if ended else "")
                         + f", outside in {int((g.violations > 0).sum())}")
        g = table[table.controller == kind + "+mpsc"]
        n = g["samples"].astype(float)
        lines.append(f"| {machine} | `{kind}` | " + " | ".join(cells) +
                     f" | {100 * g['safety.intervention_share'].median():.0f} % | "
                     f"{100 * ((g['safety.fallbacks'] + g['safety.no_plan']) / n).median():.0f} % | "
                     f"{g['safety.qp_ms'].median():.2f} ms |")
    return "\n".join(lines)


#: docs/safety.md's mpsc table: (machine key in safety_mpsc.json, its label)
DOC_ROWS = (("cartpole_rail", "cart-pole, rail 1 m (0-19)"),
            ("cartpole_rail_seeds200", "cart-pole, rail 1 m (200-219)"),
            # --refuse-unadmitted: a start no plan is certified from is refused before the run
            ("cartpole_rail_refuse", "cart-pole, rail 1 m (0-19), refusing"),
            ("cartpole_rail_seeds200_refuse", "cart-pole, rail 1 m (200-219), refusing"),
            ("furuta_arm", "Furuta, arm stop (0-19)"),
            ("furuta_arm_seeds200", "Furuta, arm stop (200-219)"),
            ("double_rail_refuse", "double cart-pole, box (0-19), refusing"),
            ("double_rail_seeds200_refuse", "double cart-pole, box (200-219), refusing"))


def doc_table(data: dict, kinds: list[str]) -> str:
    """docs/safety.md's mpsc table, every figure marked against ``safety_mpsc.json``
    (tools/check_claims.py checks them): ``--doc-table`` prints it."""
    def mark(key: str, digits: str, scale: float = 1.0) -> str:
        value = functools.reduce(lambda d, k: d[k], key.split("/"), data)
        tail = f" x{scale:g}" if scale != 1.0 else ""
        shown = int(round(value)) if digits == "d" else scale * value
        return (f"{format(shown, digits)}<!-- data: benchmarks/results/safety_mpsc.json "
                f"{key}{tail} -->")

    lines = ["| machine (seeds) | kind | bare | `cbf` (S1) | `mpsc` | on a certified plan "
             "(steps 1-3) | certified at the sample (steps 1-2) | uncertified samples (in runs) "
             "| starts admitted | time per sample: median of run medians / largest p99 / "
             "largest max | samples over the budget | load average | steal time (in runs) |",
             "|---" * 13 + "|"]
    for machine, label in DOC_ROWS:
        if machine not in data:
            continue
        for kind in [k for k in kinds if f"{k}+mpsc" in data[machine]["summary"]]:
            s = f"{machine}/summary/{kind}"
            cells = [f"{mark(f'{s}{x}/completed', 'd')}/{mark(f'{s}{x}/runs', 'd')}, outside in "
                     f"{mark(f'{s}{x}/runs_with_samples_outside', 'd')}"
                     for x in ("", "+cbf", "+mpsc")]
            m = f"{s}+mpsc"
            if "refused" in data[machine]["summary"][f"{kind}+mpsc"]["statuses"]:
                cells[-1] += f", refused {mark(f'{m}/statuses/refused', 'd')}"
            cells += [mark(f"{m}/on_certified_plan_share", ".1f", 100) + " %",
                      mark(f"{m}/certified_share", ".0f", 100) + " %",
                      f"{mark(f'{m}/uncertified_samples', 'd')} in "
                      f"{mark(f'{m}/runs_with_uncertified', 'd')}",
                      mark(f"{m}/starts_admitted", "d"),
                      f"{mark(f'{m}/time_per_sample_ms_median', '.2f')} / "
                      f"{mark(f'{m}/time_per_sample_ms_p99_max', '.2f')} / "
                      f"{mark(f'{m}/time_per_sample_ms_max', '.3g')} ms",
                      mark(f"{m}/over_budget_samples", "d"),
                      mark(f"{m}/load_average_1min_median", ".2f"),
                      f"{mark(f'{m}/steal_ms', '.0f')} ms (in {mark(f'{m}/runs_with_steal', 'd')})"
                      if "steal_ms" in data[machine]["summary"][f"{kind}+mpsc"]
                      else "not recorded"]
            lines.append(f"| {label} | `{kind}` | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def paired(table, kinds: list[str], resamples: int) -> dict:
    """McNemar on ended runs and Wilcoxon on rmse / violations (a run the task ended
    scores +inf), Holm over every comparison of the machine (tspend.studies.stats)."""
    import tspend.controllers  # noqa: F401  (first: tspend.studies.stats alone meets an import cycle)
    from tspend.studies.stats import compare, markdown

    names = [k + s for k in kinds for s in ("", "+cbf", "+mpsc")
             if (table.controller == k + s).any()]
    pairs = [(k, k + "+mpsc") for k in kinds] + [(k + "+cbf", k + "+mpsc") for k in kinds]
    pairs = [(a, b) for a, b in pairs if a in names and b in names]
    cols = ["scenario", "controller", "seed", "status", "rmse", "violations"]
    comp = compare(table[cols], names, ("rmse", "violations"), n_resamples=resamples,
                   pairs=pairs)
    # the same as numbers, keyed "A|B" and "A|B|metric" (docs/safety.md marks its
    # figures against them: a key has no spaces)
    outcomes = {f"{r.a}|{r.b}": {"pairs": int(r.pairs), "a_bad": int(r.a_bad),
                                    "b_bad": int(r.b_bad), "p_value": float(r.p_value),
                                    "p_holm": float(r.p_holm)}
                for r in comp.outcomes.itertuples(index=False)} if len(comp.outcomes) else {}
    metrics = {f"{r.a}|{r.b}|{r.metric}": {
        "pairs": int(r.pairs), "median_difference": float(r.median_difference),
        "p_value": float(r.p_value), "p_holm": float(r.p_holm), "verdict": r.verdict}
        for r in comp.pairs.itertuples(index=False)} if len(comp.pairs) else {}
    return {"pairs": [list(p) for p in pairs], "outcomes": outcomes, "metrics": metrics,
            "text": markdown(comp, "paired by seed")}


def timing(samples: int) -> dict:
    """The filter's wall time per sample against the bare controller: in the closed loops
    themselves (the runner's controller_ms, filtered and bare), and replayed on the states
    of the filtered closed loop, interleaved in this process."""
    from tspend import load_scenario, override, run
    from tspend.controllers.base import Observation
    from tspend.loop.simulation import prepare

    scn = override(load_scenario("pendulum_finite_rail"),
                   **{"effects.rail": 1.0, "run.duration": samples / 1000.0})
    r = run(override(scn, **{"safety.filter": "mpsc"}), controller="pd")
    # the closed loops themselves: the runner's own time per controller call (the inner
    # pd and the filter), filtered and bare, in this process
    loop_filt = r.metrics["controller_ms"]["median"]
    loop_bare = run(scn, controller="pd", keep_history=False).metrics["controller_ms"]["median"]
    loop_sf = r.metrics["safety_filter"]
    states, refs, ts = r.history["state"], r.history["ref"], r.history["t"]
    bare = prepare(scn, controller="pd")
    filt = prepare(override(scn, **{"safety.filter": "mpsc"}), controller="pd")
    rng = np.random.default_rng(0)
    for parts in (bare, filt):
        parts.controller.reset(rng)
    task = bare.task
    view = task.view_index
    t_bare, t_filt, cpu_bare, cpu_filt = [], [], [], []
    clock, cpu = time.perf_counter, time.thread_time
    for t, s, ref in zip(ts, states, refs):
        obs = Observation(float(t), s, s[view], ref, task.names, task.constraints)
        a, a_cpu = clock(), cpu()
        bare.controller.step(obs, 0.001)
        b, b_cpu = clock(), cpu()
        filt.controller.step(obs, 0.001)
        c, c_cpu = clock(), cpu()
        t_bare.append(b - a)
        t_filt.append(c - b)
        cpu_bare.append(b_cpu - a_cpu)
        cpu_filt.append(c_cpu - b_cpu)
    sf = filt.controller.run_metrics()["safety_filter"]
    mb, mf = float(np.median(t_bare)) * 1e3, float(np.median(t_filt)) * 1e3
    # this thread's CPU time too: on the shared machine the wall clock also counts the
    # waits for a core, which no filter can shorten
    cb, cf = float(np.median(cpu_bare)) * 1e3, float(np.median(cpu_filt)) * 1e3
    n = sf["samples"]

    return {"samples": len(ts), "bare_pd_ms_median": mb, "pd_mpsc_ms_median": mf,
            "filter_only_ms_median": sf["qp_ms"]["median"],
            "ratio_filtered_over_bare": mf / mb if mb > 0 else math.inf,
            "bare_pd_cpu_ms_median": cb, "pd_mpsc_cpu_ms_median": cf,
            "cpu_ratio_filtered_over_bare": cf / cb if cb > 0 else math.inf,
            "intervention_share": sf["intervention_share"],
            # which step answered: the fast path (no QP), the bisection on a certified
            # tail (no QP), else the QP ran
            "fast_path_share": sf["fast_path_samples"] / n,
            "bisected_share": sf["bisected_samples"] / n,
            "qp_share": 1.0 - (sf["fast_path_samples"] + sf["bisected_samples"]) / n,
            "load_average_1min": os.getloadavg()[0],
            "closed_loop_pd_mpsc_ms_median": loop_filt, "closed_loop_bare_pd_ms_median": loop_bare,
            "closed_loop_ratio": loop_filt / loop_bare if loop_bare > 0 else math.inf,
            "closed_loop_fast_path_share": loop_sf["fast_path_samples"] / loop_sf["samples"],
            "closed_loop_bisected_share": loop_sf["bisected_samples"] / loop_sf["samples"]}


def bare_replay(scn, history) -> dict:
    """Bare pd's wall time per call (ms: median, max) over a run's recorded observations."""
    from tspend.controllers.base import Observation
    from tspend.loop.simulation import prepare

    parts = prepare(scn, controller="pd")
    parts.controller.reset(np.random.default_rng(0))
    task, times = parts.task, []
    for t, s, ref in zip(history["t"], history["state"], history["ref"]):
        obs = Observation(float(t), s, s[task.view_index], ref, task.names, task.constraints)
        a = time.perf_counter()
        parts.controller.step(obs, 0.001)
        times.append(time.perf_counter() - a)
    return {"median": 1e3 * float(np.median(times)), "max": 1e3 * float(np.max(times))}


def paced_replay(scn, history) -> dict:
    """A fresh pd + mpsc on a run's recorded observations, one per control period on an
    absolute schedule under the rig runner's real-time settings (:mod:`tspend.rig.realtime`:
    SCHED_FIFO, memory locked, the collector paused), as a rig's loop runs it; admission
    (the first observation) before the schedule, as a rig's pre-flight check.  The
    filter's own time per sample, samples over its budget, its shares, what was granted."""
    from tspend import override
    from tspend.controllers.base import Observation
    from tspend.loop.simulation import prepare
    from tspend.rig.realtime import real_time, wait_until

    parts = prepare(override(scn, **{"safety.filter": "mpsc"}), controller="pd")
    filt, task, dt = parts.controller, parts.task, scn.run.dt
    filt.reset(np.random.default_rng(0))
    frames = [Observation(float(t), s, s[task.view_index], ref, task.names, task.constraints)
              for t, s, ref in zip(history["t"], history["state"], history["ref"])]
    filt.step(frames[0], dt)
    period_ns = round(dt * 1e9)
    stolen = steal_ms()
    with real_time() as granted:
        deadline = time.perf_counter_ns() + period_ns
        for obs in frames[1:]:
            wait_until(deadline)
            filt.step(obs, dt)
            deadline += period_ns
    sf = filt.run_metrics()["safety_filter"]
    per = sf["time_per_sample_ms"]
    return {"paced_ms_median": per["median"], "paced_ms_p99": per["p99"],
            "paced_ms_max": per["max"], "paced_over_budget_samples": sf["over_budget_samples"],
            "paced_over_budget_by_cause": sf["over_budget_by_cause"],
            "paced_rollouts_cut_short": sf["rollouts_cut_short"],
            "paced_certified_share": sf["certified_share"],
            "paced_on_certified_plan_share": sf["on_certified_plan_share"],
            "paced_sched_fifo": granted.sched_fifo, "paced_gc_paused": granted.gc_paused,
            "paced_notes": list(granted.notes), "paced_steal_ms": steal_ms() - stolen}


def randomized_timing(machine: str, seeds: int) -> dict:
    """The filter's time per sample in closed loops on the randomised machines (the
    runner's own measurement: median, p99, max per run), and the bare pd's time per
    controller call in the same process on the same seeds, with the load; then the same
    observations paced at the control period as a rig runs them (:func:`paced_replay`)."""
    from safety_filter import MACHINES
    from tspend import load_scenario, override, run

    name, changes = MACHINES[machine]
    base = override(load_scenario(name), **changes)
    runs, kept = [], []
    for seed in range(seeds):
        scn = override(base, **{"run.seed": seed})
        stolen = steal_ms()
        result = run(override(scn, **{"safety.filter": "mpsc"}), controller="pd")
        stolen = steal_ms() - stolen
        filtered = result.metrics
        # bare pd replayed on the filtered loop's observations (a bare run takes the
        # compiled loop, which does not time its controller calls)
        bare = bare_replay(scn, result.history)
        sf = filtered["safety_filter"]
        per = sf["time_per_sample_ms"]
        runs.append({"seed": seed, "status": result.status,
                     "mpsc_ms_median": per["median"], "mpsc_ms_p99": per["p99"],
                     "mpsc_ms_max": per["max"], "budget_ms": sf["budget_ms"],
                     "over_budget_samples": sf["over_budget_samples"],
                     "over_budget_by_cause": sf["over_budget_by_cause"],
                     "certified_share": sf["certified_share"],
                     "on_certified_plan_share": sf.get("on_certified_plan_share"),
                     "bare_pd_ms_median": bare["median"], "bare_pd_ms_max": bare["max"],
                     "ratio_median_over_bare": per["median"] / bare["median"],
                     "budget_skipped_samples": sf["budget_skipped_samples"],
                     "rollouts_cut_short": sf["rollouts_cut_short"],
                     "load_average_1min": os.getloadavg()[0], "steal_ms": stolen})
        kept.append((scn, result.history))
    # the paced replays after every closed loop (one left this process's next closed
    # loop with far fewer rollouts fitting: the collector unfrozen, the memory unlocked)
    for entry, (scn, history) in zip(runs, kept):
        entry.update(paced_replay(scn, history), paced_load_average_1min=os.getloadavg()[0])
        print(json.dumps(entry), flush=True)
    return {"machine": machine, "runs": runs}


def main() -> None:
    import pandas as pd

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=0,
                    help="the seed set's first seed (200: the confirmation set 200..219)")
    ap.add_argument("--kinds", default="pd,second_type")
    ap.add_argument("--machines", default="cartpole_rail,furuta_arm")
    ap.add_argument("--baselines", action="store_true",
                    help="rerun bare and cbf here instead of reading safety_filter.py's CSV")
    ap.add_argument("--resamples", type=int, default=2999)
    ap.add_argument("--timing-only", action="store_true")
    ap.add_argument("--summarize", action="store_true",
                    help="only the summary and the paired tests from the CSVs already written")
    ap.add_argument("--doc-table", action="store_true",
                    help="print docs/safety.md's mpsc table from safety_mpsc.json, run nothing")
    ap.add_argument("--refuse-unadmitted", action="store_true",
                    help="run with safety.refuse_unadmitted = true: a start no plan is "
                         "certified from ends 'refused' before its first input (the rows "
                         "and the summary under <machine>[_seeds<F>]_refuse)")
    ap.add_argument("--samples", type=int, default=5000)
    ap.add_argument("--timing-machine", default="",
                    help="with --timing-only: the closed loops of this machine of "
                         "benchmarks/safety_filter.py (cartpole_rail: the randomised "
                         "cart-pole), seeds 0..--seeds-1, pd behind mpsc and bare, and "
                         "the filter paced as a rig runs it; e.g. --timing-only "
                         "--timing-machine cartpole_rail --seeds 3")
    short_defaults(ap, seeds=2, resamples=200, samples=100)
    args = ap.parse_args()
    if (not 1 <= args.seeds <= 200 or not 100 <= args.samples <= 20000
            or not 0 <= args.first_seed <= 10 ** 6):
        ap.error("--seeds 1..200, --first-seed 0..1000000, --samples 100..20000")
    from safety_filter import MACHINES

    if args.timing_machine and args.timing_machine not in MACHINES:
        ap.error(f"--timing-machine: one of {', '.join(MACHINES)}")
    first, suffix = args.first_seed, tag(args.first_seed, args.refuse_unadmitted)
    warnings.simplefilter("ignore")
    out_path = OUT / "safety_mpsc.json"
    data: dict = {}
    if args.doc_table:
        print(doc_table(json.loads((RESULTS / "safety_mpsc.json").read_text()),
                        args.kinds.split(",")))
        return
    if args.timing_only and args.timing_machine:
        tim = randomized_timing(args.timing_machine, args.seeds)
        path = OUT / "safety_mpsc_timing.json"
        kept = json.loads(path.read_text()) if path.is_file() else {}
        kept["randomized_runs"] = kept.get("randomized_runs", []) + [tim]
        path.write_text(json.dumps(kept, indent=1, default=float) + "\n")
        return
    if args.timing_only:
        # its own file: one entry per run, appended (docs/safety.md quotes three)
        tim = timing(args.samples)
        print(json.dumps(tim, indent=1), flush=True)
        path = OUT / "safety_mpsc_timing.json"
        kept = json.loads(path.read_text()) if path.is_file() else {}
        # the other keys (older runs kept for the record, their notes) stay
        kept["runs"] = kept.get("runs", []) + [tim]
        path.write_text(json.dumps(kept, indent=1, default=float) + "\n")
        return
    else:
        kinds = args.kinds.split(",")
        for machine in args.machines.split(","):
            t0 = time.perf_counter()
            if args.summarize:
                done = OUT / f"safety_mpsc_{machine}{suffix}.csv"
                partial = OUT / f"safety_mpsc_{machine}{suffix}.partial.csv"
                mine = pd.read_csv(done if done.is_file() else partial)
                # only the kinds asked (an interrupted run may hold a few of another)
                mine = mine[mine.controller.isin([k + "+mpsc" for k in kinds])]
            else:
                mine = pd.DataFrame(mpsc_rows(machine, kinds, args.seeds, first,
                                              args.refuse_unadmitted))
                mine.to_csv(OUT / f"safety_mpsc_{machine}{suffix}.csv", index=False)
                (OUT / f"safety_mpsc_{machine}{suffix}.partial.csv").unlink(missing_ok=True)
            # the baselines on the seeds the filter ran (an interrupted run: fewer)
            seeds = int(mine.seed.max()) + 1 - first if len(mine) else args.seeds
            base = pd.DataFrame(baseline_rows(machine, kinds, args.seeds, args.baselines, first))
            ran = {(c.replace("+mpsc", ""), sd) for c, sd in zip(mine.controller, mine.seed)}
            base = base[[(c.replace("+cbf", ""), sd) in ran
                         for c, sd in zip(base.controller, base.seed)]]
            table = pd.concat([base, mine])
            print(markdown_rows(table, machine), flush=True)
            s = summary(table)
            print(f"\n## {machine} ({time.perf_counter() - t0:.0f} s)\n"
                  + json.dumps(s, indent=1), flush=True)
            comp = paired(table, [k for k in kinds if (table.controller == k).any()],
                          args.resamples)
            print(comp["text"], flush=True)
            data[machine + suffix] = {
                "seeds": seeds, "first_seed": first, "summary": s, "paired": comp,
                "baselines": (f"safety_mpsc_{machine}{tag(first)}_baselines.csv" if first else
                              "rerun" if args.baselines else f"safety_filter_{machine}_hocbf.csv")}
    # another process may have written its machine meanwhile: merge only this run's
    # machines into what is there now, then replace
    if out_path.is_file():
        data = {**json.loads(out_path.read_text()), **data}
    out_path.write_text(json.dumps(data, indent=1, default=float) + "\n")


if __name__ == "__main__":
    main()
