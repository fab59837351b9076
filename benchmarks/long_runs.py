"""Long runs: how the paper's law (27) lets q grow without bound, across seeds, and which
robust option keeps tracking accuracy and stays bounded over 600 s.

    python benchmarks/long_runs.py                       # seeds 0:4, 600 s, 2 workers
    python benchmarks/long_runs.py --seeds 0:8 --duration 600 --jobs 2 --out long_runs

Each option runs ``pendulum_mujoco`` for ``--duration`` seconds at every seed:

* ``paper``: law (27) as printed (q only ever grows);
* ``boundary_layer``: sat(e_Delta / 0.01) in place of sign();
* ``sigma``: sigma-modification, leakage 0.1;
* ``e_mod``: e-modification, leakage 0.1 (when the controller has ``leakage_mode``).

The runs go through ``tspend.run`` with a small sink that keeps, per 10 s window, the
largest |q| (the ``norm_q`` diagnostic), the RMS tracking error and the largest |u|: a
sweep row holds the run's totals only, and boundedness is a statement about the path.
Runs execute in a process pool (``--jobs``).  Written to ``--out``: ``runs.csv`` (one
row per run), ``windows.csv`` (one row per run and window), ``norm_q.png`` (+ CSV) and a
Markdown summary on stdout: per option, how many runs diverged and when (time to
divergence: median, min, max), |q| at 120 s, 300 s and the end, the RMS error over the
last 300 s, and paired comparisons of every option against ``paper`` (tspend.studies.stats).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import fields
from pathlib import Path

import numpy as np

WINDOW_S = 10.0
#: tracking counts as lost once a window's RMS error exceeds this (the paper's runs sit
#: near 1e-4 rad in steady state)
LOST_RAD = 1e-2


class WindowTrack:
    """Per WINDOW_S of simulated time: max norm_q, RMS e1, max |u| (flat memory)."""

    def __init__(self, dt: float) -> None:
        self.per = int(round(WINDOW_S / dt))
        self.rows: list[tuple[float, float, float, float]] = []
        self._q = self._e2 = self._u = 0.0
        self._n = 0
        self._t = 0.0

    def start(self, info) -> None:
        pass

    def inner(self, snap) -> None:
        pass

    def block(self, block) -> None:
        t, e, u = block.data["t"], block.data["e"][:, 0], block.data["u"]
        q = block.data.get("norm_q", np.zeros_like(t))
        i = 0
        while i < t.size:
            k = min(t.size - i, self.per - self._n)
            self._q = max(self._q, float(np.max(np.abs(q[i:i + k]))))
            self._e2 += float(e[i:i + k] @ e[i:i + k])
            self._u = max(self._u, float(np.max(np.abs(u[i:i + k]))))
            self._n += k
            self._t = float(t[i + k - 1])
            i += k
            if self._n == self.per:
                self._close()

    def _close(self) -> None:
        if self._n:
            self.rows.append((self._t, self._q, math.sqrt(self._e2 / self._n), self._u))
        self._q = self._e2 = self._u = 0.0
        self._n = 0

    def finish(self, end) -> None:
        self._close()


def options(has_e_mod: bool) -> dict[str, dict]:
    opts = {"paper": {}, "boundary_layer": {"controller.boundary_layer": 0.01},
            "sigma": {"controller.leakage": 0.1}}
    if has_e_mod:
        opts["e_mod"] = {"controller.leakage": 0.1, "controller.leakage_mode": "e"}
    return opts


def one_run(option: str, changes: dict, seed: int, duration: float) -> dict:
    from tspend import load_scenario, override, run

    scn = override(load_scenario("pendulum_mujoco"),
                   **{**changes, "run.seed": seed, "run.duration": duration})
    track = WindowTrack(scn.run.dt)
    started = time.perf_counter()
    res = run(scn, sinks=[track], keep_history=False)
    m = res.metrics
    return {"option": option, "seed": seed, "status": res.status, "message": res.end.message,
            "t_end": m["sim_s"], "wall_s": time.perf_counter() - started,
            **{k: m[k] for k in ("rmse", "rmse_ss", "max_abs_e_ss", "control_energy",
                                 "max_abs_u", "tv_u_per_s")},
            "windows": track.rows}


def q_at(windows, t: float) -> float:
    """Largest |q| in the window ending at or after t (nan if the run ended before)."""
    for end, q, _, _ in windows:
        if end >= t - 1e-9:
            return q
    return math.nan


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="0:4")
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default="long_runs")
    ap.add_argument("--options", help="comma-separated subset of the options")
    ap.add_argument("--summarize", action="store_true",
                    help="run nothing: write OUT/summary.json from the runs.csv already in OUT")
    args = ap.parse_args(argv)
    if args.summarize:
        import pandas as pd

        out = Path(args.out)
        if not (out / "runs.csv").is_file():
            ap.error(f"--summarize: no {out / 'runs.csv'}")
        write_summary(pd.read_csv(out / "runs.csv"), out)
        print(f"{out / 'summary.json'}")
        return 0

    import pandas as pd

    from tspend.config import ControllerConfig
    from tspend.studies.stats import compare, markdown
    from tspend.sweep.plan import parse_seeds

    seeds = parse_seeds(args.seeds)
    has_e = any(f.name == "leakage_mode" for f in fields(ControllerConfig))
    opts = options(has_e)
    if args.options:
        opts = {k: v for k, v in opts.items() if k in args.options.split(",")}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    results = []
    with ProcessPoolExecutor(args.jobs) as pool:
        futures = [pool.submit(one_run, o, c, s, args.duration) for o, c in opts.items()
                   for s in seeds]
        for f in as_completed(futures):
            r = f.result()
            results.append(r)
            print(f"{r['option']:>15} seed {r['seed']}: {r['status']} at {r['t_end']:.1f} s "
                  f"({r['wall_s']:.0f} s wall)", file=sys.stderr, flush=True)
    results.sort(key=lambda r: (list(opts).index(r["option"]), r["seed"]))
    windows = pd.DataFrame([{"option": r["option"], "seed": r["seed"], "t_end": w[0],
                             "max_norm_q": w[1], "rms_e": w[2], "max_abs_u": w[3]}
                            for r in results for w in r["windows"]])
    windows.to_csv(out / "windows.csv", index=False)
    runs = pd.DataFrame([{k: v for k, v in r.items() if k != "windows"} for r in results])
    for label, t in (("q_120s", 120.0), ("q_300s", 300.0)):
        runs[label] = [q_at(r["windows"], t) for r in results]
    runs["q_end"] = [r["windows"][-1][1] if r["windows"] else math.nan for r in results]
    # the first 10 s are the transient; after it, the first window off the reference
    runs["t_lost"] = [next((w[0] for w in r["windows"] if w[0] > 15.0 and w[2] > LOST_RAD),
                           math.nan) for r in results]
    runs.to_csv(out / "runs.csv", index=False)

    print(f"\n## pendulum_mujoco, {args.duration:g} s, seeds {args.seeds}\n")
    print("| option | runs | diverged | time to divergence [s]: median (min-max) | "
          f"tracking lost (RMS e > {LOST_RAD:g} rad) at [s] | "
          "‖q‖ at 120 s | at 300 s | at the end | rmse_ss (last half, completed runs) [rad] |")
    print("|---|---:|---:|---|---|---|---|---|---|")
    for o in opts:
        part = runs[runs.option == o]
        div = part[part.status == "diverged"]
        ttd = (f"{np.median(div.t_end):.0f} ({div.t_end.min():.0f}-{div.t_end.max():.0f})"
               if len(div) else "none")

        def med(col, rows=part):  # median [min, max]
            v = rows[col].to_numpy(float)
            v = v[np.isfinite(v)]
            return f"{np.median(v):.3g} [{v.min():.3g}, {v.max():.3g}]" if v.size else "n/a"
        done = part[part.status == "completed"]
        lost = part.t_lost.dropna()
        lost_text = (f"{np.median(lost):.0f} ({lost.min():.0f}-{lost.max():.0f}), "
                     f"{len(lost)} of {len(part)} runs" if len(lost) else "never")
        print(f"| {o} | {len(part)} | {len(div)} | {ttd} | {lost_text} | {med('q_120s')} | "
              f"{med('q_300s')} "
              f"| {med('q_end')} | {med('rmse_ss', done)} |")
    table = runs.rename(columns={"option": "controller"}).assign(
        scenario=f"pendulum_mujoco, {args.duration:g} s")[
        ["scenario", "controller", "seed", "status", "rmse_ss", "max_abs_e_ss", "tv_u_per_s"]]
    comp = compare(table, list(opts), ["rmse_ss", "max_abs_e_ss", "tv_u_per_s"],
                   pairs=[(o, "paper") for o in opts if o != "paper"], n_resamples=2000)
    print()
    print(markdown(comp, args.seeds))
    _figure(windows, runs, out, args.duration)
    write_summary(runs, out)
    print(f"wall: {time.perf_counter() - started:.0f} s; files in {out}/", file=sys.stderr)
    return 0


def _spread(values) -> dict | None:
    """median, min, max, q25, q75 of the finite values (None when there are none)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if not v.size:
        return None
    q25, q50, q75 = np.percentile(v, [25, 50, 75])
    return {"median": float(q50), "min": float(v.min()), "max": float(v.max()),
            "q25": float(q25), "q75": float(q75), "n": int(v.size)}


def write_summary(runs, out: Path) -> None:
    """``out/summary.json``: per option the figures docs/long-runs.md quotes (runs,
    divergences and when, when tracking was lost, ‖q‖ at 120 s, 300 s and the end, and
    rmse_ss and tv_u_per_s over the completed runs), each as median, min, max, q25, q75."""
    import json

    summary = {}
    for o in dict.fromkeys(runs.option):
        part = runs[runs.option == o]
        div, done = part[part.status == "diverged"], part[part.status == "completed"]
        summary[o] = {"runs": int(len(part)), "diverged": int(len(div)),
                      "seeds": sorted(int(x) for x in part.seed),
                      "t_diverged_s": _spread(div.t_end), "t_lost_s": _spread(part.t_lost),
                      "lost_runs": int(part.t_lost.notna().sum()),
                      "q_120s": _spread(part.q_120s), "q_300s": _spread(part.q_300s),
                      "q_end": _spread(part.q_end), "rmse_ss": _spread(done.rmse_ss),
                      "tv_u_per_s": _spread(done.tv_u_per_s)}
    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")


def _figure(windows, runs, out: Path, duration: float) -> None:
    try:
        from tspend.studies.figures import PALETTE, Figures, new_figure
    except Exception:
        return
    opts = list(dict.fromkeys(runs.option))
    fig, axes = new_figure(1, 2, (10.0, 3.6))
    for i, o in enumerate(opts):
        part = windows[windows.option == o]
        for j, (seed, w) in enumerate(part.groupby("seed")):
            axes[0, 0].semilogy(w.t_end, w.max_norm_q, color=PALETTE[i], lw=1.0,
                                label=o if j == 0 else None)
            axes[0, 1].semilogy(w.t_end, w.rms_e, color=PALETTE[i], lw=1.0,
                                label=o if j == 0 else None)
    axes[0, 0].set_ylabel("max ‖q‖ per 10 s [N]")
    axes[0, 1].set_ylabel("RMS θ error per 10 s [rad]")
    for ax in axes[0]:
        ax.set_xlabel("t [s]")
        ax.set_xlim(0, duration)
    axes[0, 0].legend()
    fig.suptitle(f"pendulum_mujoco over {duration:g} s, every seed one line")
    Figures(out, overwrite=True).save(fig, windows, "norm_q")


if __name__ == "__main__":
    sys.exit(main())
