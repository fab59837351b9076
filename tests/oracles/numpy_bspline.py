"""Test oracle: the B-spline basis (3)-(4) and memberships (5) vectorised in numpy.

The step-by-step reference the compiled :mod:`tspend.controllers.paper.bspline` is checked against (and
itself checked against scipy's BSpline).
"""

from __future__ import annotations

import numpy as np


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
