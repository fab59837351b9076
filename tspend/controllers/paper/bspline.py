"""B-spline membership functions (BMFs), eq. (1)-(5) of the paper, compiled.

A fuzzy set F over an input interval [lo, hi] is one B-spline curve clipped to [0, 1]:
``mu_F(z) = S(sum_i c_i N_{i,d}(z))`` (5).  All sets of one input share the interval,
so they share the knot vector and the basis; only their control points differ.  At one
input value only ``d`` basis functions are nonzero (those of the knot span holding z), so
:func:`basis` evaluates just those and :func:`memberships` sums over them.

Knot vector (1), open uniform: d knots at lo, ``r - d`` interior knots, d knots at hi.
**Erratum:** (1) prints the interior step as ``(hi - lo)/(r - d + 2)``; the uniform step
is ``(hi - lo)/(r - d + 1)`` (with the printed value the last span is twice the others).

Cox-de Boor (3)-(4) uses half-open spans ``[t_i, t_{i+1})``; ``z = hi`` is put in the
last non-empty span so that the right end evaluates, and inputs outside [lo, hi] are
clamped to it (a BMF is defined on its interval only).  A NaN input gives all-zero
basis functions (it propagates to the runner's divergence guard, not to an exception).

The compiled functions use numba's ``error_model="numpy"`` (a division by zero gives
inf/nan instead of raising), as do all the controller's compiled functions.

Optional shape projection (issue 15): :func:`project_unimodal` keeps one set's control
polygon unimodal with its peak inside a window of control points.  By the
variation-diminishing property of B-splines a unimodal control polygon gives a unimodal
curve, and disjoint ordered windows keep an input's sets in order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

import tspend.runtime.xp as xp
from tspend.runtime.law import array_law
from tspend.runtime.jit import JIT

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



#: numba options shared by every compiled function of the controller.  The step allocates
#: nothing, so it needs no reference counting (``_nrt=False``): with it, every array view
#: and every structure passed between these small functions would touch atomic counters.


@array_law
def basis_values(z: float, knots: np.ndarray, points: int, order: int,
                 out: np.ndarray) -> tuple:
    """``(s, out)``: the knot span s and the ``d`` basis functions (3)-(4) that can be
    nonzero at ``z`` in ``out[:d]`` (``out[l]`` is ``N_{s-d+1+l, d}(z)``); terms of (4)
    with a zero-length support (0/0) are zero.  Written without a branch on ``z``
    (:mod:`tspend.runtime.law`): the span is the one half-open span holding z."""
    d = order
    lo = knots[0]
    hi = knots[points + d - 1]
    z = xp.where(z < lo, lo, z)
    z = xp.where(z > hi, hi, z)
    number = z >= lo          # False for NaN: every basis function is zero
    s = points - 1            # z == hi: the last non-empty span
    for k in range(d - 1, points):
        s = xp.where((knots[k] <= z) & (z < knots[k + 1]), k, s)
    base = s - d + 1
    for l in range(d):
        out = xp.put(out, l, 0.0)
    out = xp.put(out, d - 1, 1.0)   # order 1 (3): the indicator of span s
    for k in range(2, d + 1):
        # order k (4): N_i = left_i N_i + right_i N_{i+1} for i = s-k+1 .. s; ascending i
        # overwrites N_i only after it was read, and N_{s+1} of order k-1 is zero
        for step in range(k):
            a = d - k + step
            i = base + a
            left_den = knots[i + k - 1] - knots[i]
            right_den = knots[i + k] - knots[i + 1]
            left = xp.where(left_den > 0.0, (z - knots[i]) / left_den, 0.0)
            right = xp.where(right_den > 0.0, (knots[i + k] - z) / right_den, 0.0)
            nxt = out[a + 1] if step < k - 1 else 0.0
            out = xp.put(out, a, left * out[a] + right * nxt)
    for l in range(d):
        out = xp.put(out, l, xp.where(number, out[l], 0.0))
    return xp.where(number, s, d - 1), out


@njit(**JIT)
def basis(z: float, knots: np.ndarray, points: int, order: int, out: np.ndarray) -> int:
    """The knot span of :func:`basis_values`, its basis functions written into ``out``."""
    return basis_values(z, knots, points, order, out)[0]


@array_law
def membership_values(C: np.ndarray, N: np.ndarray, span: int, order: int, terms: int,
                      mu: np.ndarray) -> tuple:
    """``(sum, mu)``: the memberships (5) of the first ``terms`` sets (rows of ``C``) in
    ``mu`` and their sum.  ``N`` and ``span`` are :func:`basis_values` at the input.  S
    clips to [0, 1]; where it clips, ``d mu / d c = 0`` (see :func:`unsaturated`)."""
    base = span - order + 1
    total = 0.0
    for t in range(terms):
        B = 0.0
        for l in range(order):
            B += C[t, base + l] * N[l]
        B = xp.where(B < 0.0, 0.0, B)
        B = xp.where(B > 1.0, 1.0, B)
        mu = xp.put(mu, t, B)
        total += B
    return total, mu


@njit(**JIT)
def memberships(C: np.ndarray, N: np.ndarray, span: int, order: int, terms: int,
                mu: np.ndarray) -> float:
    """The sum of :func:`membership_values`, the memberships written into ``mu``."""
    return membership_values(C, N, span, order, terms, mu)[0]


@array_law
def unsaturated(mu: float) -> bool:
    """Whether S of (5) passes the curve through: ``0 < B < 1``, equivalently ``0 < mu < 1``.

    There ``d mu / d c_l = N_l``; elsewhere S is flat and the gradient is zero
    (docs/paper-notes.md section 1).
    """
    return (0.0 < mu) & (mu < 1.0)


@njit(cache=True, nogil=True, error_model="numpy")
def membership_curves(C: np.ndarray, knots: np.ndarray, points: int, order: int,
                      terms: int, grid: np.ndarray, out: np.ndarray) -> None:
    """The sets' curves (5) at every point of ``grid``: ``out`` has shape (terms, len(grid))."""
    N = np.empty(order)
    mu = np.empty(terms)
    for g in range(grid.size):
        s = basis(grid[g], knots, points, order, N)
        memberships(C, N, s, order, terms, mu)
        for t in range(terms):
            out[t, g] = mu[t]


@array_law
def project_unimodal(c: np.ndarray, first: int, last: int) -> np.ndarray:
    """Make the control polygon ``c`` unimodal with its peak in ``c[first:last + 1]``
    (in place under numba); returns ``(c,)`` (numba, without its runtime, returns an
    array only inside a tuple).

    The peak is the largest point inside the window; moving away from it on either side
    every point is lowered to at most its inner neighbour.  Points already in shape do
    not move, so the map is a projection (applying it twice changes nothing).  The peak's
    place is data, so each side is one pass over every point, masked to that side.
    """
    k = first
    best = c[first]
    for l in range(first + 1, last + 1):
        higher = c[l] > best
        k = xp.where(higher, l, k)
        best = xp.where(higher, c[l], best)
    for l in range(c.size - 2, -1, -1):
        c = xp.put(c, l, xp.where((l < k) & (c[l] > c[l + 1]), c[l + 1], c[l]))
    for l in range(1, c.size):
        c = xp.put(c, l, xp.where((l > k) & (c[l] > c[l - 1]), c[l - 1], c[l]))
    return (c,)


def peak_windows(C: np.ndarray) -> np.ndarray:
    """Disjoint, ordered windows of control points (T, 2) in which each set may peak.

    Set t peaks at ``argmax C[t]`` initially; its window runs from just past the midpoint
    with its left neighbour's peak to the midpoint with its right neighbour's.
    """
    peaks = np.argmax(C, axis=1)
    T, r = C.shape
    windows = np.empty((T, 2), dtype=np.int64)
    for t in range(T):
        windows[t, 0] = 0 if t == 0 else (peaks[t - 1] + peaks[t]) // 2 + 1
        windows[t, 1] = r - 1 if t == T - 1 else (peaks[t] + peaks[t + 1]) // 2
    return windows
