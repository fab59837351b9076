"""The CBF safety filter over seeds: violations and tracking with and without it, and its
compute per sample against one bare ``mj_step`` (docs/safety.md).

    python benchmarks/safety_filter.py [--seeds 20] [--kinds pd,second_type] [--out FILE]

Two machines: the randomised cart-pole (``pendulum_mujoco_randomized``: each seed draws the
masses, the pole's length and x0) on a short rail (``effects.rail``), and the Furuta
pendulum (``furuta_mujoco``) with its arm's stop (+/-135 deg, the domain's default task),
each seed drawing x0.  Every kind runs bare and as ``KIND+cbf`` on the same seeds; the
statistics are tspend's (:func:`tspend.studies.stats.compare`: median [Q1, Q3], paired
bootstrap interval, Wilcoxon and Holm over the call; a run the task ended scores +inf).
The compute figure is a ratio against ``mj_step`` measured in the same process.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
from short_mode import out_path, short_defaults

MACHINES = {
    "cartpole_rail": ("pendulum_mujoco_randomized", {
        "effects.rail": 1.0, "run.duration": 3.0,
        # the policy trained on this machine (docs/gym.md); a kind only this machine runs
        "controllers.policy.path": "models/policies/pendulum_mujoco.onnx"}),
    "furuta_arm": ("furuta_mujoco", {"run.duration": 1.5, "randomize.x0": [
        {"dist": "uniform", "low": -0.15, "high": 0.15},
        {"dist": "uniform", "low": -0.5, "high": 0.5}]}),
    # issue 45's double cart-pole with a rail (benchmarks/safety_mpsc.py only): the
    # articulated domain has no effects.rail, so the rail is a hard box on the cart; x0
    # drawn (lower link +/-0.1 rad, its rate +/-0.3 rad/s); lqr made aggressive by an input
    # weight of 1e-4, and the double cart-pole's policy (docs/gym.md)
    "double_rail": ("double_cartpole_mujoco", {
        "run.duration": 3.0, "controllers.lqr.R": 1e-4,
        "task.constraints.box.slider": {"lo": -0.5, "hi": 0.5, "hard": True},
        "randomize.x0": [{"dist": "uniform", "low": -0.1, "high": 0.1},
                         {"dist": "uniform", "low": -0.3, "high": 0.3}],
        "controllers.policy.path": "models/policies/double_cartpole_mujoco.onnx"}),
}
#: what this script runs by default (double_rail is benchmarks/safety_mpsc.py's)
DEFAULT_MACHINES = ("cartpole_rail", "furuta_arm")


def kinds_of(machine: str, kinds: list[str]) -> list[str]:
    """The kinds a machine runs: ``policy`` only where its trained policy applies."""
    return [k for k in kinds if k != "policy" or "controllers.policy.path" in MACHINES[machine][1]]


def rows(machine: str, kinds: list[str], seeds: int, barrier: str = "hocbf",
         first: int = 0) -> list[dict]:
    from tspend import load_scenario, override, run

    name, changes = MACHINES[machine]
    base = override(load_scenario(name), **changes, **{"safety.barrier": barrier})
    out = []
    for kind in kinds_of(machine, kinds):
        for filtered in (False, True):
            k = kind + ("+cbf" if filtered else "")
            for seed in range(first, first + seeds):
                r = run(override(base, **{"run.seed": seed}), controller=k, keep_history=False)
                m = r.metrics
                safety = m.get("safety_filter", {})
                out.append({"scenario": machine, "controller": k, "seed": seed,
                            "status": r.end.status, "rmse": m["rmse"],
                            "violations": m["violations"], "max_violation": m["max_violation"],
                            "safety_filter.intervention_share": safety.get("intervention_share"),
                            "safety_filter.qp_ms": (safety.get("qp_ms") or {}).get("median")})
    return out


def tracking_cost(table, kinds: list[str], resamples: int) -> str:
    """What the filter costs in tracking where it does not change the outcome: rmse of
    KIND against KIND+cbf on the seeds both completed, paired (median difference with a
    bootstrap 95 % interval, Wilcoxon, Holm over the kinds)."""
    from tspend.studies.stats import holm, paired_difference

    lines, results = [], []
    for k in kinds:
        a = table[table.controller == k].set_index("seed")
        b = table[table.controller == k + "+cbf"].set_index("seed")
        both = a.index[(a.status == "completed") & (b.status.reindex(a.index) == "completed")]
        if len(both) < 2:
            lines.append(f"| {k} vs {k}+cbf | {len(both)} | (too few seeds completed both) | | | |")
            continue
        r = paired_difference(a.loc[both, "rmse"], b.loc[both, "rmse"], n_resamples=resamples)
        results.append((k, len(both), r))
    p_holm = holm([r.p_value for _, _, r in results]) if results else []
    for (k, n, r), ph in zip(results, p_holm):
        lines.append(f"| {k} vs {k}+cbf | {n} | {r.median_difference:.4g} "
                     f"[{r.ci_low:.4g}, {r.ci_high:.4g}] | {r.median_ratio:.3f} | "
                     f"{r.p_value:.3g} | {ph:.3g} |")
    head = ("\nTracking cost on the seeds both completed: rmse, d = A - B (negative: the "
            "filter costs), 95 % bootstrap CI, Wilcoxon p, Holm over these rows.\n\n"
            "| A vs B | seeds | median d [95% CI] | median A/B | p | p_holm |\n"
            "|---|---:|---|---:|---:|---:|")
    return "\n".join([head, *lines])


def compute_ratio(samples: int = 2000) -> str:
    """The filter's QP (model evaluation + barrier rows + solve) per sample against one
    bare mj_step of the cart-pole's model, both measured here."""
    import mujoco

    from tspend import load_scenario, override
    from tspend.loop.simulation import prepare

    scn = override(load_scenario("pendulum_mujoco"), **{"effects.rail": 1.0, "safety.filter": "cbf"})
    parts = prepare(scn, controller="pd")
    filt = parts.controller
    from tspend.controllers.base import Observation

    rng = np.random.default_rng(0)
    state = np.array([0.5, 0.05, 0.3, 0.0])
    obs = Observation(0.0, state, state[[1, 3]], np.zeros(3), parts.task.names,
                      parts.task.constraints)
    filt.step(obs, 0.001)  # builds the rows and the solver once
    states = state + rng.normal(scale=[0.3, 0.05, 0.3, 0.1], size=(samples, 4))
    commands = rng.normal(scale=300.0, size=samples)
    t0 = time.perf_counter()
    for s, u in zip(states, commands):
        filt.filter(s, float(u))
    qp = (time.perf_counter() - t0) / samples
    model = mujoco.MjModel.from_xml_path(str(parts.plant.model_path))
    data = mujoco.MjData(model)
    t0 = time.perf_counter()
    for _ in range(samples):
        mujoco.mj_step(model, data)
    step = (time.perf_counter() - t0) / samples
    return (f"filter per sample {1e6 * qp:.1f} us, bare mj_step {1e6 * step:.2f} us, "
            f"ratio {qp / step:.0f}x (measured under load)")


def main() -> None:
    import pandas as pd

    from tspend.studies.stats import compare, markdown

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20, help="how many seeds (1-1000)")
    ap.add_argument("--first-seed", type=int, default=0,
                    help="the first seed (0-10^6); a set other than 0 writes its CSV with a "
                         "_seedsFIRST suffix, e.g. --first-seed 200 for the confirmation set")
    ap.add_argument("--kinds", default="pd,second_type,policy")
    ap.add_argument("--machines", default=",".join(DEFAULT_MACHINES))
    ap.add_argument("--resamples", type=int, default=2999)
    ap.add_argument("--barrier", default="hocbf", choices=("hocbf", "braking", "lyapunov"),
                    help="the filter's barrier for position rows ([safety] barrier)")
    ap.add_argument("--ratio-only", action="store_true",
                    help="only the filter's compute per sample against mj_step")
    short_defaults(ap, seeds=2, resamples=200)
    args = ap.parse_args()
    if not (1 <= args.seeds <= 1000 and 0 <= args.first_seed <= 10**6):
        ap.error(f"--seeds {args.seeds} / --first-seed {args.first_seed}: outside 1-1000 / 0-10^6")
    warnings.simplefilter("ignore")
    kinds = args.kinds.split(",")
    print(compute_ratio(), flush=True)
    if args.ratio_only:
        return
    for machine in args.machines.split(","):
        t0 = time.perf_counter()
        table = pd.DataFrame(rows(machine, kinds, args.seeds, args.barrier, args.first_seed))
        print(f"\n## {machine}, barrier {args.barrier} ({time.perf_counter() - t0:.0f} s)\n")
        summary = table.groupby("controller", sort=False).agg(
            ended=("status", lambda s: int((s != "completed").sum())),
            statuses=("status", lambda s: ",".join(sorted(set(s)))),
            violations_median=("violations", "median"),
            violations_max=("violations", "max"),
            intervention_median=("safety_filter.intervention_share", "median"),
            qp_ms_median=("safety_filter.qp_ms", "median"))
        print(summary.to_string())
        here = kinds_of(machine, kinds)
        names = [k + s for k in here for s in ("", "+cbf")]
        comp = compare(table, names, ("rmse", "violations"), n_resamples=args.resamples,
                       pairs=[(k, k + "+cbf") for k in here])
        seeds = f"{args.first_seed}-{args.first_seed + args.seeds - 1}"
        print(markdown(comp, seeds), flush=True)
        print(tracking_cost(table, here, args.resamples), flush=True)
        suffix = f"_seeds{args.first_seed}" if args.first_seed else ""
        table.to_csv(out_path(f"benchmarks/results/safety_filter_{machine}_{args.barrier}"
                              f"{suffix}.csv"), index=False)


if __name__ == "__main__":
    main()
