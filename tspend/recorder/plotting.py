"""One run drawn the paper's way (``RunResult.plot()``), and the style every figure shares.

The figures of studies (:mod:`tspend.studies.figures`: the paper's, box plots, heat maps)
draw with the same :data:`STYLE`, colours and labels, from here.  matplotlib is drawn on
``matplotlib.figure.Figure`` objects with the Agg canvas, never through pyplot.
"""

from __future__ import annotations

from typing import Sequence

from tspend.runtime.errors import ScenarioError

STYLE = {
    "figure.dpi": 100, "savefig.dpi": 150, "font.size": 9, "axes.titlesize": 10,
    "axes.labelsize": 9, "legend.fontsize": 8, "figure.titlesize": 10, "xtick.labelsize": 8, "ytick.labelsize": 8,
    "axes.grid": True, "grid.alpha": 0.3, "grid.linewidth": 0.6, "lines.linewidth": 1.2,
    "axes.spines.top": False, "axes.spines.right": False, "legend.frameon": False,
    "savefig.bbox": "tight",
}
#: one colour per controller kind, the same in every figure (Okabe-Ito, colour-blind safe)
PALETTE = ("#0072B2", "#E69F00", "#009E73", "#CC79A7", "#56B4E9", "#D55E00", "#F0E442",
           "#000000")
#: line styles that tell kinds apart in grey print too
DASHES = ("-", "--", "-.", ":")


def state_units(plant_kind: str, order: int) -> tuple[tuple[str, ...], str]:
    """(symbol [unit] of each state, of u) for a plant kind's axis labels."""
    from tspend.recorder.labels import plant_labels

    labels = plant_labels(plant_kind, order)
    greek = {"theta": "θ", "theta'": "θ'", "alpha": "α", "alpha'": "α'"}

    def axis(q) -> str:
        return f"{greek.get(q.symbol, q.symbol)} [{q.unit or '–'}]"

    return tuple(axis(q) for q in labels.states), axis(labels.control)


def matplotlib_parts():
    """matplotlib, its Figure and the Agg canvas (ScenarioError when it is missing)."""
    from tspend.runtime.extras import missing_extra

    problem = missing_extra("matplotlib", "figures")
    if problem:
        raise ScenarioError(problem)
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    return matplotlib, Figure, FigureCanvasAgg


def kind_colour(kind: str, kinds: Sequence[str] | None = None) -> str:
    """The colour of a controller kind: its place in the registry, so it never changes
    between figures."""
    from tspend.controllers import KINDS

    order = list(KINDS) + [k for k in (kinds or ()) if k not in KINDS]
    i = order.index(kind) if kind in order else len(order)
    return PALETTE[i % len(PALETTE)]


def kind_dash(kind: str) -> str:
    from tspend.controllers import KINDS

    order = list(KINDS)
    return DASHES[(order.index(kind) if kind in order else 0) % len(DASHES)]


def new_figure(rows: int, cols: int, size: tuple[float, float]):
    """A Figure with a grid of axes in the common style (no pyplot)."""
    mpl, Figure, _ = matplotlib_parts()
    with mpl.rc_context(STYLE):
        fig = Figure(figsize=size, layout="constrained")
        axes = fig.subplots(rows, cols, squeeze=False)
    return fig, axes


def run_figure(result, every: int = 1):
    """One run in the paper's panels: each state of the task's view against its
    reference (x1 and r, x2 and r', ...), then the control u; a matplotlib Figure
    (``RunResult.plot()``)."""
    h = result.history
    if not h:
        raise ValueError("the run kept no history (run it with keep_history=True)")
    n = h["x"].shape[1]
    labels, u_label = state_units(result.scenario.plant.kind, n)
    kind = getattr(result.controller, "kind", "")
    keep = slice(None, None, max(1, int(every)))
    t = h["t"][keep]
    fig, axes = new_figure(n + 1, 1, (6.4, 1.6 * (n + 1) + 0.6))
    colour = kind_colour(kind) if kind else PALETTE[0]
    for i in range(n):
        ax = axes[i, 0]
        ref = "r" + "'" * i
        ax.plot(t, h["ref"][keep, i], color="0.35", lw=1.0, ls=":", label=f"reference {ref}")
        ax.plot(t, h["x"][keep, i], color=colour, label=kind_label(kind or "x", result))
        ax.set_ylabel(labels[i] if i < len(labels) else f"x{i + 1}")
    axes[0, 0].legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), ncols=2, fontsize=7)
    axes[n, 0].plot(t, h["u"][keep], color=colour, lw=0.5)
    axes[n, 0].set_ylabel(u_label)
    axes[n, 0].set_xlabel("t [s]")
    fig.suptitle(f"{result.scenario.name}, {kind}, seed {result.scenario.run.seed}")
    return fig


def kind_label(kind: str, res) -> str:
    """A run's legend entry: its kind, and how it ended when it did not complete."""
    return kind if res.status == "completed" else f"{kind} ({res.status})"
