"""Peer benchmark: tspend's T-S inference against the same model in simpful (2.12).

Run from the project root::

    .venv/bin/python benchmarks/peer_simpful.py

Compared: the model output p = w @ P (9) of the Example 3 T-S model, i.e. the firing
strengths of its 75 grid rules and their weighted average of per-rule consequents, at
one input z = [x_o1, x_o2, u_o].  Neither side adapts anything.

Why it is a like-for-like comparison:

* same sets: every simpful term is a function-defined ``FuzzySet`` whose membership is
  tspend's B-spline set (same knots, order, control points), clipped to [0, 1] by
  simpful's ``MF_object.__call__`` exactly as S of (5) clips it; checked pointwise;
* same rules: the 75 rules of the grid, numbered as ``Grid.term_index``;
* same t-norm: simpful's ``operators=["AND_PRODUCT"]``, tspend's product of memberships;
* same defuzzification: simpful's Sugeno weighted average ``sum g y / sum g`` with
  crisp (zero-order) per-rule outputs ``P[i, k]``, tspend's normalised ``w @ P``.

A simpful rule has one consequent, so p1, p2, p3 take three copies of the rule base
(225 rules); p1 alone (75 rules) is timed too.  The headline simpful figure uses a
scalar pure-Python B-spline membership (the cheapest faithful one); memberships calling
the compiled ``tspend.controllers.paper.bspline`` and a zero-cost membership (simpful's own floor) are timed too.
Figures: median over blocks of the mean cost of one call, inputs cycling through the
test points; simpful with its Python call overhead, tspend evaluated in a compiled loop
over the same inputs (a closed loop in numba calls it so; from Python, passing the
NamedTuple structures costs microseconds per call, which the controller avoids).
"""

from __future__ import annotations

import contextlib
import io
import statistics
import sys
import time
from importlib.metadata import version
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

try:
    import simpful as sf
except ImportError:
    print("simpful is not installed: pip install -e '.[bench]'")
    sys.exit(0)

from tspend.controllers.paper.bspline import basis, memberships  # noqa: E402
from tspend.config import ControllerConfig  # noqa: E402
from tspend.controllers.paper.controller import make_controller  # noqa: E402
from tspend.controllers.paper.rules import VARPI_EPS, fire  # noqa: E402
from tspend.controllers.paper.ts_model import model_output  # noqa: E402
from tspend.runtime.jit import drop_stale_kernels  # noqa: E402
from short_mode import sized  # noqa: E402

# this folder's cached kernels call tspend's: compiled afresh when tspend changed
drop_stale_kernels(Path(__file__).resolve().parent)

OUTPUTS = ("p1", "p2", "p3")


class BSplineMF(sf.MF_object):
    """Term t of a tspend input, B = sum_l c_l N_l(x), in scalar Python (as tspend.controllers.paper.bspline.basis)."""

    def __init__(self, knots: np.ndarray, d: int, c: np.ndarray) -> None:
        self.t, self.d, self.r = [float(k) for k in knots], d, len(c)
        self.c = [float(v) for v in c]

    def _execute(self, x: float) -> float:
        t, d, r = self.t, self.d, self.r
        x = min(max(x, t[0]), t[-1])
        s = r - 1                                   # x == hi: the last non-empty span
        if x < t[-1]:
            s = next(k for k in range(d - 1, r) if t[k] <= x < t[k + 1])
        base = s - d + 1
        N = [0.0] * (d - 1) + [1.0]                 # N[a] = N_{base + a}
        for k in range(2, d + 1):
            for i in range(s - k + 1, s + 1):
                a, ld, rd = i - base, t[i + k - 1] - t[i], t[i + k] - t[i + 1]
                left = (x - t[i]) / ld if ld > 0.0 else 0.0
                right = (t[i + k] - x) / rd if rd > 0.0 else 0.0
                N[a] = left * N[a] + right * (N[a + 1] if i < s else 0.0)
        return sum(self.c[base + l] * N[l] for l in range(d))   # __call__ clips to [0, 1]


class TspendMF(sf.MF_object):
    """The same term through the compiled ``tspend.controllers.paper.bspline`` functions (one point per call)."""

    def __init__(self, knots: np.ndarray, d: int, c: np.ndarray) -> None:
        self.knots, self.d, self.c = knots, d, c[None, :]
        self.N, self.mu = np.empty(d), np.empty(1)

    def _execute(self, x: float) -> float:
        s = basis(float(x), self.knots, self.c.shape[1], self.d, self.N)
        memberships(self.c, self.N, s, self.d, 1, self.mu)
        return float(self.mu[0])


class ConstMF(sf.MF_object):
    """Timing floor only: a membership that costs nothing (the result is not p)."""

    def __init__(self, *_) -> None:
        pass

    def _execute(self, x: float) -> float:
        return 0.5


def build_simpful(ctrl, mf_class) -> sf.FuzzySystem:
    """The 75-rule T-S model (x3 outputs) as a simpful Sugeno system with product AND."""
    inputs, P = ctrl.inputs["model"], ctrl.state.P
    term_index = ctrl.settings.model.grid.term_index
    with contextlib.redirect_stdout(io.StringIO()):   # it prints "Detected Sugeno model type"
        fs = sf.FuzzySystem(operators=["AND_PRODUCT"], show_banner=False, verbose=False)
        for j, inp in enumerate(inputs):
            C = ctrl.state.C_model[j]
            sets = [sf.FuzzySet(function=mf_class(inp.knots, inp.order, C[t].copy()), term=name)
                    for t, name in enumerate(inp.term_names)]
            fs.add_linguistic_variable(inp.name, sf.LinguisticVariable(
                sets, concept=inp.name, universe_of_discourse=[inp.lo, inp.hi]))
        text = []
        for k, out in enumerate(OUTPUTS):
            for i, terms in enumerate(term_index):
                fs.set_crisp_output_value(f"{out}_r{i}", float(P[i, k]))
                ante = " AND ".join(f"({inp.name} IS {inp.term_names[t]})"
                                    for inp, t in zip(inputs, terms))
                text.append(f"IF {ante} THEN {out} IS {out}_r{i}")
        fs.add_rules(text)
    return fs


def simpful_p(fs: sf.FuzzySystem, names, z: np.ndarray, outputs=OUTPUTS) -> np.ndarray:
    for name, v in zip(names, z):
        fs.set_variable(name, v)
    res = fs.Sugeno_inference(list(outputs))
    return np.array([res[o] for o in outputs])


from numba import njit  # noqa: E402

from tspend.runtime.jit import JIT  # noqa: E402


@njit(**JIT)
def compiled_p(z, grid, C, P, scratch, out):
    """p = w @ P (9) at z with tspend's compiled firing (12)."""
    for i in range(z.size):     # (no slice assignment: tspend's options leave out NRT)
        scratch.z[i] = z[i]
    varpi = fire(grid, C, scratch)
    model_output(scratch.w, P, out)
    return varpi


@njit(**JIT)
def compiled_p_each(Z, grid, C, P, scratch, out):
    """compiled_p at every row of Z, in one compiled call (no Python call per evaluation)."""
    for k in range(Z.shape[0]):
        compiled_p(Z[k], grid, C, P, scratch, out)


def per_call(fn, zs, calls: int, blocks: int) -> float:
    """Median over blocks of the mean seconds per call of ``fn(z)``, z cycling through zs."""
    fn(zs[0])
    times = []
    for _ in range(blocks):
        t0 = time.perf_counter()
        for c in range(calls):
            fn(zs[c % len(zs)])
        times.append((time.perf_counter() - t0) / calls)
    return statistics.median(times)


def main() -> int:
    from tspend.controllers.paper import rules

    ctrl = make_controller(ControllerConfig())
    ctrl.reset(np.random.default_rng(0))
    ctrl.state.P[:] = np.random.default_rng(0).uniform(-1.0, 1.0, ctrl.state.P.shape)
    inputs, P, grid = ctrl.inputs["model"], ctrl.state.P, ctrl.settings.model.grid
    scratch = rules.firing(grid)
    names = [inp.name for inp in inputs]
    lo, hi = np.array([i.lo for i in inputs]), np.array([i.hi for i in inputs])
    print(f"T-S model: {' x '.join(str(i.terms) for i in inputs)} = {P.shape[0]} rules, "
          f"P {P.shape}, simpful {version('simpful')}")

    rng = np.random.default_rng(1)
    zs = [rng.uniform(lo, hi) for _ in range(48)] + [lo.copy(), hi.copy()]
    fs = build_simpful(ctrl, BSplineMF)
    fs_np = build_simpful(ctrl, TspendMF)
    out = np.zeros(P.shape[1])

    def p_tspend(z):
        varpi = compiled_p(z, grid, ctrl.state.C_model, P, scratch, out)
        return out.copy(), varpi

    # -- correctness -------------------------------------------------------------------
    mf_err = 0.0
    for z in zs:
        p_tspend(z)
        for j, inp in enumerate(inputs):
            for t in range(inp.terms):
                mf_err = max(mf_err, abs(fs._lvs[inp.name]._FSlist[t].get_value(z[j])
                                         - scratch.mu[j, t]))
    p_ts = np.array([p_tspend(z)[0] for z in zs])
    p_sf = np.array([simpful_p(fs, names, z) for z in zs])
    p_sf_np = np.array([simpful_p(fs_np, names, z) for z in zs[:10]])
    # tspend's guarded weights (g + eps/h)/(varpi + eps) move p by eps (mean(P) - p)/(varpi + eps)
    varpi = np.array([p_tspend(z)[1] - VARPI_EPS for z in zs])
    guard = VARPI_EPS * (P.mean(axis=0) - p_sf) / (varpi + VARPI_EPS)[:, None]
    print(f"max |mu simpful - mu tspend| over {len(zs)} inputs, all sets: {mf_err:.2e}")
    print(f"max |p simpful - p tspend| : {np.abs(p_sf - p_ts).max():.2e}"
          f"  (MFs via tspend.controllers.paper.bspline, 10 inputs: {np.abs(p_sf_np - p_ts[:10]).max():.2e}; "
          f"eps guard predicts {np.abs(guard).max():.2e}, varpi in [{varpi.min():.3f}, {varpi.max():.3f}])")
    print(f"max |p simpful + eps guard - p tspend| : {np.abs(p_sf + guard - p_ts).max():.2e}")
    ok = np.abs(p_sf - p_ts).max() < 1e-9

    # -- timing ------------------------------------------------------------------------
    blocks = sized(15, 2)     # timed blocks per figure (short: a smoke run)
    t_sf = per_call(lambda z: simpful_p(fs, names, z), zs, 10, blocks)
    t_sf1 = per_call(lambda z: simpful_p(fs, names, z, ("p1",)), zs, 20, blocks)
    t_sfn = per_call(lambda z: simpful_p(fs_np, names, z), zs, 2, sized(5, 1))
    fs_c = build_simpful(ctrl, ConstMF)
    t_sfc = per_call(lambda z: simpful_p(fs_c, names, z), zs, 10, blocks)
    C = ctrl.state.C_model
    Z = np.array(zs * sized(400, 10))
    t_nb = per_call(lambda _: compiled_p_each(Z, grid, C, P, scratch, out), [None], 5,
                    sized(21, 2)) / len(Z)
    us = 1e6
    print("\nper evaluation of p at one input (median over blocks):")
    print(f"simpful 75-rule inference (p1..p3, 225 rules): {t_sf * us:10.1f} us/eval")
    for label, t in (("simpful p1 only (75 rules)", t_sf1),
                     ("simpful p1..p3, MFs via tspend.controllers.paper.bspline", t_sfn),
                     ("simpful p1..p3, zero-cost MFs (floor)", t_sfc)):
        print(f"  ({label + '):':<43} {t * us:10.1f} us/eval")
    print(f"tspend compiled (rules.fire + model_output, in a compiled loop): {t_nb * us:8.3f} us/eval"
          f"  (simpful is {t_sf / t_nb:.0f}x slower)")
    if not ok:
        print("WARNING: simpful and tspend disagree beyond 1e-9")
    return 0


if __name__ == "__main__":
    sys.exit(main())
