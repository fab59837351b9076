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
* same rules: the 75 rules of the grid, numbered as ``RuleBase.term_index``;
* same t-norm: simpful's ``operators=["AND_PRODUCT"]``, tspend's product of memberships;
* same defuzzification: simpful's Sugeno weighted average ``sum g y / sum g`` with
  crisp (zero-order) per-rule outputs ``P[i, k]``, tspend's normalised ``w @ P``.

A simpful rule has one consequent, so p1, p2, p3 take three copies of the rule base
(225 rules); p1 alone (75 rules) is timed too.  The headline simpful figure uses a
scalar pure-Python B-spline membership (the cheapest faithful one); memberships calling
``tspend.bspline`` and a zero-cost membership (simpful's own floor) are timed too.
Figures: median over blocks of the mean cost of one call, inputs cycling through the
test points, Python call overhead included on every side.
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

from tspend.bspline import basis_matrix  # noqa: E402
from tspend.config import ControllerConfig  # noqa: E402
from tspend.controller import AdaptiveFuzzyController  # noqa: E402
from tspend.kernels import HAVE_NUMBA, CompiledController, _fire  # noqa: E402
from tspend.rules import VARPI_EPS  # noqa: E402

OUTPUTS = ("p1", "p2", "p3")


class BSplineMF(sf.MF_object):
    """Term t of a tspend input, B = sum_l c_l N_l(x), in scalar Python (kernels._basis)."""

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
    """The same term through ``tspend.bspline.basis_matrix`` (numpy, one point per call)."""

    def __init__(self, knots: np.ndarray, d: int, c: np.ndarray) -> None:
        self.knots, self.d, self.c = knots, d, c

    def _execute(self, x: float) -> float:
        return float(self.c @ basis_matrix(x, self.knots, self.d)[0])


class ConstMF(sf.MF_object):
    """Timing floor only: a membership that costs nothing (the result is not p)."""

    def __init__(self, *_) -> None:
        pass

    def _execute(self, x: float) -> float:
        return 0.5


def build_simpful(model, mf_class) -> sf.FuzzySystem:
    """The 75-rule T-S model (x3 outputs) as a simpful Sugeno system with product AND."""
    rules = model.rules
    with contextlib.redirect_stdout(io.StringIO()):   # it prints "Detected Sugeno model type"
        fs = sf.FuzzySystem(operators=["AND_PRODUCT"], show_banner=False, verbose=False)
        for inp, kn, C in zip(rules.inputs, rules.knots, rules.C):
            sets = [sf.FuzzySet(function=mf_class(kn, inp.order, C[t].copy()), term=name)
                    for t, name in enumerate(inp.term_names)]
            fs.add_linguistic_variable(inp.name, sf.LinguisticVariable(
                sets, concept=inp.name, universe_of_discourse=[inp.lo, inp.hi]))
        text = []
        for k, out in enumerate(OUTPUTS):
            for i, terms in enumerate(rules.term_index):
                fs.set_crisp_output_value(f"{out}_r{i}", float(model.P[i, k]))
                ante = " AND ".join(f"({inp.name} IS {inp.term_names[t]})"
                                    for inp, t in zip(rules.inputs, terms))
                text.append(f"IF {ante} THEN {out} IS {out}_r{i}")
        fs.add_rules(text)
    return fs


def simpful_p(fs: sf.FuzzySystem, names, z: np.ndarray, outputs=OUTPUTS) -> np.ndarray:
    for name, v in zip(names, z):
        fs.set_variable(name, v)
    res = fs.Sugeno_inference(list(outputs))
    return np.array([res[o] for o in outputs])


if HAVE_NUMBA:
    from numba import njit

    @njit(cache=True, nogil=True)
    def numba_p(z, P, Cm, knots, ic, tidx, ws, M, out):
        """p = w @ P at z with the kernel's own _basis/_fire (workspace rows as in the kernel)."""
        h, m = P.shape[0], Cm.shape[0]
        W, Z = 4 * M, 4 * M + 6
        for j in range(m):
            ws[Z, j] = z[j]
        _fire(0.0, 0.0, Z, 0, m, h, 0, Cm, knots, ic, tidx, ws, M, W, VARPI_EPS)
        for k in range(P.shape[1]):
            acc = 0.0
            for i in range(h):
                acc += ws[W, i] * P[i, k]
            out[k] = acc
        return out


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
    cfg = ControllerConfig()
    ctrl = CompiledController(cfg) if HAVE_NUMBA else AdaptiveFuzzyController(cfg)
    model = ctrl.model
    model.initialise(np.random.default_rng(0), -1.0, 1.0)
    rules = model.rules
    names = [inp.name for inp in rules.inputs]
    print(f"T-S model: {' x '.join(str(t) for t in rules.shape)} = {rules.size} rules, "
          f"P {model.P.shape}, simpful {version('simpful')}")

    rng = np.random.default_rng(1)
    zs = [rng.uniform(rules.lo, rules.hi) for _ in range(48)] + [rules.lo.copy(), rules.hi.copy()]
    fs = build_simpful(model, BSplineMF)
    fs_np = build_simpful(model, TspendMF)

    # -- correctness -------------------------------------------------------------------
    mf_err = max(abs(fs._lvs[inp.name]._FSlist[t].get_value(z[j]) - rules.evaluate(z).mu[j][t])
                 for z in zs for j, inp in enumerate(rules.inputs) for t in range(inp.terms))
    p_ts = np.array([model.evaluate(z)[1] for z in zs])
    p_sf = np.array([simpful_p(fs, names, z) for z in zs])
    p_sf_np = np.array([simpful_p(fs_np, names, z) for z in zs[:10]])
    # tspend's guarded weights (g + eps/h)/(varpi + eps) move p by eps (mean(P) - p)/(varpi + eps)
    varpi = np.array([rules.evaluate(z).varpi - VARPI_EPS for z in zs])
    guard = VARPI_EPS * (model.P.mean(axis=0) - p_sf) / (varpi + VARPI_EPS)[:, None]
    print(f"max |mu simpful - mu tspend| over {len(zs)} inputs, all sets: {mf_err:.2e}")
    print(f"max |p simpful - p tspend numpy| : {np.abs(p_sf - p_ts).max():.2e}"
          f"  (MFs via tspend.bspline, 10 inputs: {np.abs(p_sf_np - p_ts[:10]).max():.2e}; "
          f"eps guard predicts {np.abs(guard).max():.2e}, varpi in [{varpi.min():.3f}, {varpi.max():.3f}])")
    print(f"max |p simpful + eps guard - p tspend numpy| : {np.abs(p_sf + guard - p_ts).max():.2e}")
    ok = np.abs(p_sf - p_ts).max() < 1e-9
    if HAVE_NUMBA:
        args = (model.P, ctrl._Cm, ctrl._knots, ctrl._ic, ctrl._tidx, np.zeros_like(ctrl._ws),
                len(ctrl._ic), np.zeros(model.P.shape[1]))
        p_nb = np.array([numba_p(z, *args).copy() for z in zs])
        print(f"max |p tspend numba - p tspend numpy| : {np.abs(p_nb - p_ts).max():.2e}")
        ok &= np.abs(p_nb - p_ts).max() < 1e-12

    # -- timing ------------------------------------------------------------------------
    t_sf = per_call(lambda z: simpful_p(fs, names, z), zs, 10, 15)
    t_sf1 = per_call(lambda z: simpful_p(fs, names, z, ("p1",)), zs, 20, 15)
    t_sfn = per_call(lambda z: simpful_p(fs_np, names, z), zs, 2, 5)
    fs_c = build_simpful(model, ConstMF)
    t_sfc = per_call(lambda z: simpful_p(fs_c, names, z), zs, 10, 15)
    t_np = per_call(model.evaluate, zs, 500, 21)
    us = 1e6
    print("\nper evaluation of p at one input (median over blocks):")
    print(f"simpful 75-rule inference (p1..p3, 225 rules): {t_sf * us:10.1f} us/eval")
    for label, t in (("simpful p1 only (75 rules)", t_sf1),
                     ("simpful p1..p3, MFs via tspend.bspline", t_sfn),
                     ("simpful p1..p3, zero-cost MFs (floor)", t_sfc)):
        print(f"  ({label + '):':<43} {t * us:10.1f} us/eval")
    print(f"tspend numpy (TSModel.evaluate):               {t_np * us:10.1f} us/eval"
          f"  (simpful is {t_sf / t_np:.1f}x slower)")
    if HAVE_NUMBA:
        t_nb = per_call(lambda z: numba_p(z, *args), zs, 20000, 21)
        print(f"tspend numba (kernel _basis/_fire + w @ P):   {t_nb * us:10.3f} us/eval"
              f"  (simpful is {t_sf / t_nb:.0f}x slower)")
    else:
        print("tspend numba: skipped (numba not installed)")
    if not ok:
        print("WARNING: simpful and tspend disagree beyond 1e-9")
    return 0


if __name__ == "__main__":
    sys.exit(main())
