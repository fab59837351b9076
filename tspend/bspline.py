"""B-spline membership functions (BMFs), eq. (1)-(5) of the paper.

A fuzzy set F over an input interval [lo, hi] is one B-spline curve clipped to [0, 1]:
``mu_F(z) = S(sum_i c_i N_{i,d}(z))`` (5).  All sets of one input share the interval,
so they share the knot vector and the basis; only their control points differ.  The
basis is evaluated once per input and all that input's sets follow by one
matrix-vector product.

Knot vector (1), open uniform: d knots at lo, ``r - d`` interior knots, d knots at hi.
**Erratum:** (1) prints the interior step as ``(hi - lo)/(r - d + 2)``; the uniform step
is ``(hi - lo)/(r - d + 1)`` (with the printed value the last span is twice the others).

Cox-de Boor (3)-(4) uses half-open spans ``[t_i, t_{i+1})``; ``z = hi`` is put in the
last non-empty span so that the right end evaluates, and inputs outside [lo, hi] are
clamped to it (a BMF is defined on its interval only).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: linguistic term names by number of sets
TERM_NAMES = {
    2: ("N", "P"),
    3: ("N", "Z", "P"),
    5: ("NB", "NS", "Z", "PS", "PB"),
    7: ("NB", "NM", "NS", "Z", "PS", "PM", "PB"),
}


def term_names(count: int) -> tuple[str, ...]:
    """Conventional names of ``count`` evenly spaced terms (NB .. PB), else T0 .. Tk."""
    return TERM_NAMES.get(count, tuple(f"T{i}" for i in range(count)))


def open_uniform_knots(lo: float, hi: float, r: int, d: int) -> np.ndarray:
    """Knot vector (1) for ``r`` control points of order ``d`` on [lo, hi], erratum fixed.

    Returns ``r + d`` knots: ``d`` copies of lo, ``r - d`` interior knots at the
    uniform step ``(hi - lo)/(r - d + 1)``, ``d`` copies of hi.
    """
    if d < 1 or r < d:
        raise ValueError(f"need order d >= 1 and r >= d control points, got r={r}, d={d}")
    interior = lo + (hi - lo) * np.arange(1, r - d + 1) / (r - d + 1)
    return np.concatenate([np.full(d, float(lo)), interior, np.full(d, float(hi))])


def greville_abscissae(knots: np.ndarray, d: int) -> np.ndarray:
    """Greville points ``g_i = mean(t_{i+1} .. t_{i+d-1})``: where control point i 'sits'."""
    r = len(knots) - d
    if d == 1:
        return 0.5 * (knots[:r] + knots[1: r + 1])
    window = np.lib.stride_tricks.sliding_window_view(knots[1:-1], d - 1)
    return window.mean(axis=1)[:r]


class BasisEvaluator:
    """All basis functions ``N_{i,d}`` (3)-(4) of one knot vector, at any points.

    The denominators of (4) depend on the knots only, so they are computed once; each
    call is then a few vectorised operations per order (no loop over basis functions).
    Terms with a zero-length support (0/0) are zero.  ``z`` is clamped to the knot
    range, and the right end goes to the last non-empty span.
    """

    def __init__(self, knots: np.ndarray, d: int) -> None:
        self.t = t = np.asarray(knots, dtype=float)
        self.d = d
        self.r = len(t) - d
        self.lo, self.hi = t[0], t[-1]
        self.n_spans = len(t) - 1
        self.levels = []
        for k in range(2, d + 1):
            m = self.n_spans - k + 1                     # number of order-k functions
            left_den = t[k - 1: k - 1 + m] - t[:m]
            right_den = t[k: k + m] - t[1: 1 + m]
            self.levels.append((m, t[:m], t[k: k + m],
                                np.where(left_den > 0, left_den, 1.0), left_den > 0,
                                np.where(right_den > 0, right_den, 1.0), right_den > 0))

    def __call__(self, z: np.ndarray) -> np.ndarray:
        """Shape (len(z), r)."""
        t = self.t
        z = np.clip(np.atleast_1d(np.asarray(z, dtype=float)), self.lo, self.hi)[:, None]
        # order 1 (3): half-open spans, with z == hi assigned to the last non-empty span
        N = ((t[:-1] <= z) & (z < t[1:])).astype(float)
        at_hi = z[:, 0] >= self.hi
        if at_hi.any():
            N[at_hi] = 0.0
            N[at_hi, self.r - 1] = 1.0
        for m, t_lo, t_hi, lden, lok, rden, rok in self.levels:
            left = np.where(lok, (z - t_lo) / lden, 0.0)
            right = np.where(rok, (t_hi - z) / rden, 0.0)
            N = left * N[:, :m] + right * N[:, 1: m + 1]
        return N


def basis_matrix(z: np.ndarray, knots: np.ndarray, d: int) -> np.ndarray:
    """All basis functions ``N_{i,d}(z)`` at the points ``z``: shape (len(z), r).

    Convenience form of :class:`BasisEvaluator` for a one-off evaluation.
    """
    return BasisEvaluator(knots, d)(z)


def clip_unit(b: np.ndarray) -> np.ndarray:
    """S of (5): clip the B-spline curve to [0, 1]."""
    return np.clip(b, 0.0, 1.0)


def triangle_control_points(knots: np.ndarray, d: int, terms: int) -> np.ndarray:
    """Initial control points of ``terms`` bump-shaped sets, shape (terms, r).

    Each set is a triangle centred on one of ``terms`` evenly spaced points of the
    interval (half-width one spacing), sampled at the Greville abscissae.  Triangles
    sum to one, and the basis is a partition of unity, so the initial sets sum to one
    everywhere: neighbours overlap and every point of the interval fires some rule.
    """
    lo, hi = knots[0], knots[-1]
    g = greville_abscissae(knots, d)
    if terms == 1:
        return np.ones((1, g.size))
    centres = np.linspace(lo, hi, terms)
    width = (hi - lo) / (terms - 1)
    return np.clip(1.0 - np.abs(g[None, :] - centres[:, None]) / width, 0.0, 1.0)


@dataclass(frozen=True)
class BSplineInput:
    """The geometry of one antecedent input: interval, order, number of control points."""

    name: str
    lo: float
    hi: float
    terms: int
    control_points: int = 9
    order: int = 3

    @property
    def knots(self) -> np.ndarray:
        return open_uniform_knots(self.lo, self.hi, self.control_points, self.order)

    @property
    def term_names(self) -> tuple[str, ...]:
        return term_names(self.terms)

    def initial_control_points(self) -> np.ndarray:
        return triangle_control_points(self.knots, self.order, self.terms)


def memberships(C: np.ndarray, N: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Membership values (5) of all sets of one input, and where they are unsaturated.

    ``C``: control points (T, r); ``N``: basis at the input (r,).  Returns ``mu`` (T,)
    and the mask ``0 < B < 1`` where ``d mu / d c_l = N_l`` (elsewhere S is flat and
    the gradient is zero, docs/paper-notes.md section 1).
    """
    B = C @ N
    return clip_unit(B), (B > 0.0) & (B < 1.0)


def membership_gradient(N: np.ndarray, unsaturated: np.ndarray) -> np.ndarray:
    """``d mu_s / d c_{s,l}`` for every set s and control point l: shape (T, r)."""
    return unsaturated[:, None] * N[None, :]
