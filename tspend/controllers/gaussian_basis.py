"""Fuzzy basis functions of Gaussian memberships on a fixed grid (Wang and Mendel, 1992).

Each state ``x_i`` has ``T_i`` Gaussian sets with centres evenly spaced on ``[lo_i, hi_i]``
and a common width equal to the spacing,

    mu_ij(x_i) = exp(-((x_i - c_ij) / sigma_i)^2),   c_ij = lo_i + j sigma_i,
    sigma_i = (hi_i - lo_i) / (T_i - 1),

and the rule base is the full grid (one rule per combination of sets, product
inference).  With singleton consequents ``theta`` and centre-average defuzzification the
fuzzy system is ``y(x) = theta^T xi(x)``, where the fuzzy basis functions are

    xi_l(x) = prod_i mu_{i,l_i}(x_i) / sum_l prod_i mu_{i,l_i}(x_i)

(L.-X. Wang and J. M. Mendel, "Fuzzy basis functions, universal approximation, and
orthogonal least-squares learning", IEEE Trans. Neural Networks 3(5), 1992; used as
``f_hat`` and ``g_hat`` in Wang 1993, see :mod:`.wang_indirect`).  The ``xi_l`` are
positive and sum to one, so ``y`` is a convex combination of the ``theta_l``.  Inputs are
clamped to their intervals first, as the paper controller's B-splines are, so the basis
never underflows to 0/0 far outside the grid.
"""

from __future__ import annotations

from functools import reduce
from typing import NamedTuple

import numpy as np


class GaussianGrid(NamedTuple):
    """Centres (one array per input), widths and intervals of a fixed Gaussian grid."""

    centres: tuple[np.ndarray, ...]
    sigma: np.ndarray
    lo: np.ndarray
    hi: np.ndarray

    @property
    def rules(self) -> int:
        return int(np.prod([c.size for c in self.centres]))


def gaussian_grid(sets) -> GaussianGrid:
    """The grid of ``sets``: one ``SetSpec(terms, lo, hi)`` per state (a single term sits
    in the middle with width ``hi - lo``)."""
    centres = tuple(np.linspace(s.lo, s.hi, s.terms) if s.terms > 1
                    else np.array([0.5 * (s.lo + s.hi)]) for s in sets)
    sigma = np.array([(s.hi - s.lo) / max(s.terms - 1, 1) for s in sets])
    return GaussianGrid(centres, sigma, np.array([s.lo for s in sets]),
                        np.array([s.hi for s in sets]))


def memberships(grid: GaussianGrid, x: np.ndarray) -> list[np.ndarray]:
    z = np.clip(x, grid.lo, grid.hi)
    return [np.exp(-(((z[i] - c) / grid.sigma[i]) ** 2)) for i, c in enumerate(grid.centres)]


def basis(grid: GaussianGrid, x: np.ndarray) -> np.ndarray:
    """``xi(x)``: the normalised firing strengths of every rule (row-major grid order)."""
    g = reduce(np.multiply.outer, memberships(grid, x)).ravel()
    return g / g.sum()
