"""Figures from runs and sweeps: the paper's figures redrawn, membership functions before
and after adaptation, box plots of a comparison across seeds, heat maps of a two-key sweep.

Every figure is written as PNG and PDF with the data it draws beside it as CSV (same
name, ``.csv``), each file atomically, so a reader can check or replot any curve.  One style for all
(:data:`tspend.recorder.plotting.STYLE`, applied with ``matplotlib.rc_context``: no global state), one colour per
controller kind, axis labels with units.  matplotlib is a core dependency; figures are drawn on ``matplotlib.figure.Figure``
objects with the Agg canvas, never through pyplot, so no display is needed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from tspend.runtime.errors import ScenarioError
from tspend.recorder.plotting import (PALETTE, STYLE, kind_colour, kind_dash, kind_label,
    matplotlib_parts, new_figure, state_units)

#: every figure is written in these formats: the picture twice and what it plots
FORMATS = (".png", ".pdf", ".csv")
#: a paper column (inches): the box plots are this wide
COLUMN_WIDTH_IN = 3.5
#: the smallest font a figure uses (points): legible at a paper column
MIN_FONT_PT = 8.0
#: the tracking figures' error panel: |e| below this is drawn at it (a log axis has no 0)
ERROR_FLOOR = 1e-12
#: the paper's figures: scenario, title, which figures
PAPER_CASES = (("ex1_nonaffine_case1", "Example 1, case 1 (nonaffine plant)"),
               ("ex1_nonaffine_case2", "Example 1, case 2 (nonaffine plant)"),
               ("ex2_duffing", "Example 2 (Duffing oscillator)"),
               ("ex3_pendulum_ode", "Example 3 (cart-pole, ODE)"))


@dataclass
class Figures:
    """Where figures go: ``out`` directory, may existing files be replaced.

    Every figure is written as PNG, PDF and the CSV of what it plots, each through a
    partial file renamed when complete (:mod:`tspend.runtime.outputs`): an existing file
    is only ever replaced by a whole new one.  ``pdf`` is kept for old callers (PDF is
    always written).
    """

    out: Path
    pdf: bool = True
    overwrite: bool = False
    written: list[Path] = field(default_factory=list)

    def paths(self, name: str) -> list[Path]:
        return [self.out / f"{name}{e}" for e in FORMATS]

    def check(self, names: Iterable[str]) -> None:
        """Fail before drawing when a file would be replaced (and --overwrite is not given)
        or the directory cannot be written."""
        from tspend.runtime.outputs import OutputRequest, plan_outputs

        for name in names:
            for p in self.paths(name):
                plan_outputs([OutputRequest("--out", "figure", p.suffix, str(p))])
                if p.exists() and not self.overwrite:
                    raise ScenarioError(f"figure {p}: exists; choose another --out or pass "
                                        f"--overwrite")

    def save(self, fig, data, name: str) -> Path:
        """Write ``fig`` as PNG and PDF and ``data`` (a DataFrame) as CSV; the PNG path."""
        import io

        from tspend.runtime.outputs import OutputRequest, claim, plan_outputs

        mpl, _, Canvas = matplotlib_parts()
        self.out.mkdir(parents=True, exist_ok=True)
        paths = self.paths(name)
        Canvas(fig)
        contents = []
        with mpl.rc_context(STYLE):
            for path in paths[:2]:
                buf = io.BytesIO()
                fig.savefig(buf, format=path.suffix[1:])
                contents.append(buf.getvalue())
        contents.append(data.to_csv(index=False).encode())
        outputs = claim(plan_outputs([OutputRequest("--out", "figure", p.suffix, str(p)) for p in paths]))
        try:
            for output, content in zip(outputs, contents):
                output.write(content)
            self.written += [output.commit() for output in outputs]
        except BaseException:
            for output in outputs:
                if not output.committed:
                    output.discard()
            raise
        return self.written[-3]


# -- time series -------------------------------------------------------------------------
def _series_frame(runs: dict, columns: dict, every: int, t_max: float | None = None):
    """One table of t, the reference columns and each run's columns, sampled every
    ``every`` samples (runs that stopped early are padded with empty cells)."""
    import pandas as pd

    longest = max(runs.values(), key=lambda r: r.history["t"].size)
    t = longest.history["t"]
    keep = np.arange(0, t.size, every)
    if t_max is not None:
        keep = keep[t[keep] <= t_max + 1e-12]
    out = {"t": t[keep]}
    ref = longest.history["ref"]
    out["r"] = ref[keep, 0]
    out["r_dot"] = ref[keep, 1]
    for kind, res in runs.items():
        h = res.history
        for col, pick in columns.items():
            v = np.full(keep.size, np.nan)
            k = keep[keep < h["t"].size]
            v[:k.size] = pick(h)[k]
            out[f"{col}_{kind}"] = v
    return pd.DataFrame(out)


def tracking_figure(fig_out: Figures, runs: dict, name: str, title: str, every: int = 1):
    """x1 against r and x2 against r' for each run (the paper's tracking figures), and
    under them |e_1| = |x1 - r| on a log axis: where the lines above lie on top of each
    other, the error tells the kinds apart (down to :data:`ERROR_FLOOR`)."""
    first = next(iter(runs.values()))
    labels, _ = state_units(first.scenario.plant.kind, 2)
    data = _series_frame(runs, {"x1": lambda h: h["x"][:, 0], "x2": lambda h: h["x"][:, 1]},
                         every)
    for kind in runs:
        data[f"abs_e1_{kind}"] = np.abs(data[f"x1_{kind}"] - data["r"])
    fig, axes = new_figure(3, 1, (6.4, 6.2))
    for ax, i, ref_col, ref_label in ((axes[0, 0], 1, "r", "r"), (axes[1, 0], 2, "r_dot", "r'")):
        ax.plot(data["t"], data[ref_col], color="0.35", lw=1.0, ls=":", label=f"reference {ref_label}")
        for kind in runs:
            ax.plot(data["t"], data[f"x{i}_{kind}"], color=kind_colour(kind), ls=kind_dash(kind),
                    label=kind_label(kind, runs[kind]))
        ax.set_ylabel(labels[i - 1])
    err = axes[2, 0]
    unit = labels[0].split(" ", 1)[1] if " " in labels[0] else ""
    for kind in runs:
        err.plot(data["t"], np.maximum(data[f"abs_e1_{kind}"], ERROR_FLOOR), color=kind_colour(kind),
                 ls=kind_dash(kind), lw=1.0, label=kind_label(kind, runs[kind]))
    err.set_yscale("log")
    err.set_ylabel(f"|e₁| = |x₁ − r| {unit}".strip())
    err.set_xlabel("t [s]")
    axes[0, 0].legend(ncols=len(runs) + 1, loc="lower right", bbox_to_anchor=(1.0, 1.0))
    seed = first.scenario.run.seed
    fig.suptitle(f"{title}, seed {seed}")
    return fig_out.save(fig, data, name)


def control_figure(fig_out: Figures, runs: dict, name: str, title: str,
                   t_max: float | None = None):
    """u over time for each run (every sample: u chatters at the sample rate)."""
    first = next(iter(runs.values()))
    _, u_label = state_units(first.scenario.plant.kind, 2)
    data = _series_frame(runs, {"u": lambda h: h["u"]}, 1, t_max)
    data = data.drop(columns=["r", "r_dot"])
    fig, axes = new_figure(len(runs), 1, (6.4, 1.9 * len(runs) + 0.6))
    for ax, kind in zip(axes[:, 0], runs):
        ax.plot(data["t"], data[f"u_{kind}"], color=kind_colour(kind), lw=0.5,
                label=kind_label(kind, runs[kind]))
        ax.set_ylabel(u_label)
        ax.legend(loc="upper right")
    axes[-1, 0].set_xlabel("t [s]")
    fig.suptitle(f"{title}, seed {first.scenario.run.seed}")
    return fig_out.save(fig, data, name)


# -- membership functions -------------------------------------------------------------------
class SetsCapture:
    """A sink that keeps the controller's first and last inner snapshot (membership
    curves with the adapted control points) and the names of the inputs and terms."""

    wants_inner = True

    def __init__(self) -> None:
        self.first = self.last = None
        self.model_inputs = self.compensator_inputs = ()
        self.plant_kind = ""

    def start(self, info) -> None:
        self.model_inputs, self.compensator_inputs = info.model_inputs, info.compensator_inputs
        self.plant_kind = info.plant_kind

    def block(self, block) -> None:
        pass

    def inner(self, snap) -> None:
        if self.first is None:
            self.first = snap
        self.last = snap

    def finish(self, end) -> None:
        pass


def _input_label(name: str, plant_kind: str) -> str:
    """An antecedent input with its unit: x_oj as the state j, u_o as u."""
    states, u = state_units(plant_kind, 9)
    if name.startswith("x_o") and name[3:].isdigit():
        return f"{name} {states[int(name[3:]) - 1].split(' ', 1)[1]}"
    if name == "u_o":
        return f"u_o {u.split(' ', 1)[1]}"
    return name  # e_delta and |x| mix the states' units


def membership_frame(capture: SetsCapture):
    """Long table: base (model/compensator), input, term, z, mu_first, mu_last."""
    import pandas as pd

    parts = []
    for base, infos, attr in (("model", capture.model_inputs, "model_sets"),
                              ("compensator", capture.compensator_inputs, "compensator_sets")):
        for j, info in enumerate(infos):
            grid, before = getattr(capture.first, attr)[j][:2]
            _, after = getattr(capture.last, attr)[j][:2]
            for k, term in enumerate(info.terms):
                parts.append(pd.DataFrame({"base": base, "input": info.name, "term": term,
                                           "z": grid, "mu_first": before[k],
                                           "mu_last": after[k]}))
    return pd.concat(parts, ignore_index=True)


def membership_figure(fig_out: Figures, capture: SetsCapture, name: str, title: str):
    """Every input's membership functions at the first snapshot (dashed) and the last
    (solid), one panel per input, one colour per term."""
    if capture.first is None:
        raise ValueError("no inner snapshot was taken: the controller has no sets, or "
                         "run.snapshot_every is 0")
    data = membership_frame(capture)
    inputs = list(dict.fromkeys(zip(data["base"], data["input"])))
    cols = min(3, len(inputs))
    rows = math.ceil(len(inputs) / cols)
    fig, axes = new_figure(rows, cols, (3.1 * cols, 2.4 * rows + 0.5))
    for ax in axes.flat[len(inputs):]:
        ax.set_visible(False)
    for ax, (base, inp) in zip(axes.flat, inputs):
        part = data[(data["base"] == base) & (data["input"] == inp)]
        for k, (term, sets) in enumerate(part.groupby("term", sort=False)):
            c = PALETTE[k % len(PALETTE)]
            ax.plot(sets["z"], sets["mu_first"], color=c, ls="--", lw=0.9)
            ax.plot(sets["z"], sets["mu_last"], color=c, lw=1.4, label=term)
        ax.set_title(f"{inp} ({base})")
        ax.set_xlabel(_input_label(inp, capture.plant_kind))
        ax.set_ylabel("membership μ [–]")
        ax.set_ylim(-0.03, 1.18)
        ax.legend(ncols=len(part["term"].unique()), fontsize=MIN_FONT_PT, loc="upper center",
                  handlelength=1.2, columnspacing=0.8)
    t0, t1 = capture.first.t, capture.last.t
    fig.suptitle(f"{title}\nmembership functions at t = {t0:g} s (dashed) and "
                 f"t = {t1:g} s (solid)")
    return fig_out.save(fig, data, name)


# -- comparisons across seeds ----------------------------------------------------------------
#: how a run that did not complete is drawn in a box plot: (marker, colour); a run that
#: failed or was interrupted has no marker, it is only counted
OUTCOME_MARKERS = {"diverged": ("x", "#D55E00"), "fell": ("v", "#CC79A7"),
                   "rail_end": ("v", "#CC79A7"), "joint_limit": ("v", "#CC79A7"),
                   "state_bound": ("v", "#CC79A7")}


def box_figure(fig_out: Figures, table, metric: str, name: str,
               controllers: Sequence[str] | None = None, title: str | None = None):
    """One panel per scenario (and grid point), a paper column wide
    (:data:`COLUMN_WIDTH_IN`, fonts >= :data:`MIN_FONT_PT`): the metric across seeds, one
    box per controller, over the runs that completed only.  A run that diverged or ended
    early (fell, rail end, ...) is not data: it is drawn as a marker in a band above the
    boxes, its count written beside it; failed runs are counted."""
    import pandas as pd

    from tspend.studies.stats import _group_columns, _ordered_controllers, outcome_values

    kinds = _ordered_controllers(table, controllers)
    groups = _group_columns(table)
    table = table[table["controller"].isin(kinds)]
    data = table[groups + ["controller", "seed", "status"]].copy()
    data[metric] = outcome_values(table, metric)
    # what a box is drawn from: completed runs' finite values (the CSV says which rows)
    data["plotted"] = (data["status"] == "completed") & np.isfinite(data[metric].to_numpy(dtype=float))
    keys = list(dict.fromkeys(map(tuple, data[groups].astype(str).to_numpy())))
    rows = len(keys)
    fig, axes = new_figure(rows, 1, (COLUMN_WIDTH_IN, 2.5 * rows + 0.35))
    with matplotlib_parts()[0].rc_context(STYLE):
        for ax, key in zip(axes.flat, keys):
            sel = np.all(data[groups].astype(str).to_numpy() == np.array(key), axis=1)
            _box_panel(ax, data[sel], metric, kinds)
            ax.set_title(", ".join(key), fontsize=MIN_FONT_PT + 1, pad=14)
        fig.suptitle(title or f"{metric} across seeds", fontsize=MIN_FONT_PT + 1)
    data = data.rename(columns={metric: "value"}).assign(metric=metric)
    return fig_out.save(fig, pd.DataFrame(data), name)


def _box_panel(ax, part, metric: str, kinds: Sequence[str]) -> None:
    """The boxes of one scenario, and the runs that are not data counted above them."""
    shown = part[part["plotted"]]
    values = shown[metric].to_numpy(dtype=float)
    labels: list[str] = []
    present: set[str] = set()
    for i, kind in enumerate(kinds):
        v = shown.loc[shown["controller"] == kind, metric].to_numpy(dtype=float)
        c = kind_colour(kind)
        if v.size:
            ax.boxplot(v, positions=[i], widths=0.6, patch_artist=True, showfliers=False,
                       medianprops=dict(color="black"),
                       boxprops=dict(facecolor=c, alpha=0.45, edgecolor=c),
                       whiskerprops=dict(color=c), capprops=dict(color=c))
            jitter = np.linspace(-0.15, 0.15, v.size) if v.size > 1 else np.zeros(1)
            ax.scatter(i + jitter, v, s=9, color=c, zorder=3)
        others = part[(part["controller"] == kind) & ~part["plotted"]]
        uncounted = []
        slots = 0
        for status, count in others["status"].value_counts(sort=False).items():
            marker = OUTCOME_MARKERS.get(status)
            if marker is None:  # failed, interrupted: no value at all, counted under the name
                uncounted.append(f"{count} {status}")
                continue
            # in a band above the data area: a marker and the count, never a value
            x = i - 0.18 + 0.36 * slots
            slots += 1
            ax.scatter([x], [1.05], marker=marker[0], s=26, color=marker[1], clip_on=False,
                       transform=ax.get_xaxis_transform(), zorder=4)
            ax.annotate(str(count), (x + 0.08, 1.05), xycoords=("data", "axes fraction"), ha="left",
                        va="center", fontsize=MIN_FONT_PT, color=marker[1], annotation_clip=False)
        labels.append(kind + "".join(f"\n({note})" for note in uncounted))
        present |= {s for s in others["status"] if s in OUTCOME_MARKERS}
    if values.size and values.min() > 0 and values.max() / values.min() > 50:
        ax.set_yscale("log")
    ax.set_xlim(-0.6, len(kinds) - 0.4)
    ax.set_xticks(range(len(kinds)), labels, rotation=30, ha="right", rotation_mode="anchor")
    ax.tick_params(labelsize=MIN_FONT_PT)
    if present:
        from matplotlib.lines import Line2D

        handles = [Line2D([], [], ls="", marker=OUTCOME_MARKERS[s][0], color=OUTCOME_MARKERS[s][1],
                          label=s) for s in sorted(present)]
        ax.legend(handles=handles, loc="lower left", bbox_to_anchor=(1.0, 1.0), ncols=1,
                  fontsize=MIN_FONT_PT, title="runs counted\n(not data)", title_fontsize=MIN_FONT_PT,
                  handletextpad=0.2, borderaxespad=0.0, alignment="left")
    ax.set_ylabel(metric_label(metric, part), fontsize=MIN_FONT_PT + 1)


#: each metric's unit as powers of (the error's unit, u's unit, seconds)
METRIC_DIMENSIONS = {"rmse": (1, 0, 0), "rmse_ss": (1, 0, 0), "max_abs_e": (1, 0, 0),
                     "max_abs_e_ss": (1, 0, 0), "iae": (1, 0, 1), "ise": (2, 0, 1),
                     "itae": (1, 0, 2), "control_energy": (0, 2, 1), "max_abs_u": (0, 1, 0),
                     "tv_u_per_s": (0, 1, -1)}


def _plant_kind(scenario: str) -> str:
    from tspend.scenario import load_scenario

    try:
        return load_scenario(scenario).plant.kind
    except Exception:  # a table from elsewhere: its scenario may not be at hand
        return ""


def metric_label(metric: str, part=None) -> str:
    """``rmse_ss [rad]``, ``control_energy [N²·s]``; ``[–]`` for a dimensionless plant's;
    no unit when the scenarios of ``part`` are unknown or differ in units."""
    kinds = {_plant_kind(s) for s in set(part["scenario"])} if part is not None else {""}
    if len(kinds) != 1 or "" in kinds or metric not in METRIC_DIMENSIONS:
        return metric
    kind = kinds.pop()
    from tspend.recorder.labels import plant_labels

    labels = plant_labels(kind, 1)
    e_unit, u_unit = labels.states[0].unit, labels.control.unit
    power = {1: "", 2: "²", -1: "⁻¹"}
    parts = [f"{unit}{power.get(k, k)}" for unit, k in
             zip((e_unit, u_unit, "s"), METRIC_DIMENSIONS[metric]) if unit and k]
    return f"{metric} [{'·'.join(parts) or '–'}]"


def heatmap_figure(fig_out: Figures, table, x: str, y: str, metric: str, name: str,
                   controllers: Sequence[str] | None = None, title: str | None = None):
    """The median of ``metric`` over seeds at each (x, y) grid point of a sweep, one panel
    per controller; cells where the median run diverged are marked."""
    import pandas as pd
    from matplotlib.colors import LogNorm, Normalize

    from tspend.studies.stats import _ordered_controllers, outcome_values, quartiles

    for key in (x, y):
        if key not in table.columns:
            raise ScenarioError(f"--x/--y {key}: not a column of the table; grid columns: "
                                f"{', '.join(c for c in table.columns if '.' in c) or 'none'}")
    if "scenario" in table.columns and table["scenario"].nunique() > 1:
        raise ScenarioError(f"a heat map shows one scenario; the table has "
                            f"{', '.join(map(str, table['scenario'].unique()))}")
    kinds = _ordered_controllers(table, controllers)
    t = table[table["controller"].isin(kinds)].copy()
    t["_v"] = outcome_values(t, metric)
    recs = []
    for (kind, xv, yv), part in t.groupby(["controller", x, y], sort=True):
        v = part["_v"].to_numpy(dtype=float)
        v = v[~np.isnan(v)]
        q1, med, q3 = quartiles(v) if v.size else (math.nan,) * 3
        recs.append({"controller": kind, x: xv, y: yv, "median": med, "q1": q1, "q3": q3,
                     "runs": len(part), "diverged": int((part["status"] == "diverged").sum())})
    data = pd.DataFrame.from_records(recs)
    finite = data["median"][np.isfinite(data["median"])]
    use_log = finite.size and finite.min() > 0 and finite.max() / finite.min() > 20
    norm = (LogNorm(finite.min(), finite.max()) if use_log else
            Normalize(finite.min(), finite.max()) if finite.size else Normalize(0, 1))
    xs, ys = sorted(data[x].unique()), sorted(data[y].unique())
    fig, axes = new_figure(1, len(kinds), (3.4 * len(kinds) + 0.8, 3.2))
    for ax, kind in zip(axes[0], kinds):
        grid = np.full((len(ys), len(xs)), np.nan)
        part = data[data["controller"] == kind]
        for r in part.to_dict("records"):
            grid[ys.index(r[y]), xs.index(r[x])] = r["median"]
        shown = np.where(np.isfinite(grid), grid, np.nan)
        im = ax.imshow(shown, origin="lower", aspect="auto", cmap="viridis", norm=norm)
        for i in range(len(ys)):
            for j in range(len(xs)):
                v = grid[i, j]
                ax.text(j, i, "div." if np.isposinf(v) else ("" if np.isnan(v) else f"{v:.2g}"),
                        ha="center", va="center", fontsize=MIN_FONT_PT,
                        color="white" if np.isfinite(v) and norm(v) < 0.6 else "black")
        ax.set_xticks(range(len(xs)), [f"{v:g}" if isinstance(v, float) else str(v) for v in xs])
        ax.set_yticks(range(len(ys)), [f"{v:g}" if isinstance(v, float) else str(v) for v in ys])
        ax.set_xlabel(x)
        ax.set_ylabel(y)
        ax.set_title(kind)
        ax.grid(False)
    fig.colorbar(im, ax=axes[0].tolist(), label=f"median {metric_label(metric, table)}")
    fig.suptitle(title or f"median {metric} over seeds")
    return fig_out.save(fig, data, name)


# -- the paper's figures ---------------------------------------------------------------------
def paper_runs(scenario_name: str, kinds: Sequence[str], seed: int | None = None,
               duration: float | None = None, capture_sets: bool = False):
    """Run one paper case with each kind at one seed: ({kind: RunResult}, SetsCapture of
    the first kind or None)."""
    # through the package's facade: RunResult.plot() draws with this module
    from tspend import run
    from tspend.scenario import load_scenario, override

    changes = {}
    if seed is not None:
        changes["run.seed"] = seed
    if duration is not None:
        changes["run.duration"] = duration
    scn = load_scenario(scenario_name)
    scn = override(scn, **changes) if changes else scn
    runs, capture = {}, None
    for i, kind in enumerate(kinds):
        sinks = []
        if capture_sets and i == 0:
            capture = SetsCapture()
            sinks = [capture]
        runs[kind] = run(scn, sinks=sinks, controller=kind)
    return runs, capture


def paper_figures(fig_out: Figures, kinds: Sequence[str] = ("second_type", "first_type"),
                  seed: int | None = None, duration: float | None = None,
                  every: int = 10) -> list[Path]:
    """The paper's figures redrawn: x1, x2 against the reference for Example 1 cases 1-2,
    Example 2 and Example 3; u of Example 2 over 0-15 s; Example 2's membership functions
    before and after adaptation (the first kind's)."""
    names = [f"{s}_tracking" for s, _ in PAPER_CASES] + ["ex2_duffing_u",
                                                         "ex2_duffing_memberships"]
    fig_out.check(names)
    pngs = []
    for scenario, title in PAPER_CASES:
        duffing = scenario == "ex2_duffing"
        runs, capture = paper_runs(scenario, kinds, seed, duration, capture_sets=duffing)
        pngs.append(tracking_figure(fig_out, runs, f"{scenario}_tracking", title, every))
        if duffing:
            pngs.append(control_figure(fig_out, runs, "ex2_duffing_u", title, t_max=15.0))
            pngs.append(membership_figure(fig_out, capture, "ex2_duffing_memberships",
                                          f"{title}, {kinds[0]}, seed "
                                          f"{runs[kinds[0]].scenario.run.seed}"))
    return pngs
