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
    """Centres (one array per input), widths and intervals of a fixed Gaussian grid.

    ``flat_centres``, ``flat_sigma`` and ``owner`` (the input each flattened centre
    belongs to) let one ``exp`` call evaluate every membership; ``slices`` cut the
    result back into the inputs.
    """

    centres: tuple[np.ndarray, ...]
    sigma: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    flat_centres: np.ndarray
    flat_sigma: np.ndarray
    owner: np.ndarray
    slices: tuple[slice, ...]

    @property
    def rules(self) -> int:
        return int(np.prod([c.size for c in self.centres]))


def gaussian_grid(sets) -> GaussianGrid:
    """The grid of ``sets``: one ``SetSpec(terms, lo, hi)`` per state (a single term sits
    in the middle with width ``hi - lo``)."""
    centres = tuple(np.linspace(s.lo, s.hi, s.terms) if s.terms > 1
                    else np.array([0.5 * (s.lo + s.hi)]) for s in sets)
    sigma = np.array([(s.hi - s.lo) / max(s.terms - 1, 1) for s in sets])
    owner = np.concatenate([np.full(c.size, i) for i, c in enumerate(centres)])
    return GaussianGrid(centres, sigma, np.array([s.lo for s in sets]),
                        np.array([s.hi for s in sets]), np.concatenate(centres),
                        sigma[owner], owner, _slices([c.size for c in centres]))


def _slices(sizes: list[int]) -> tuple[slice, ...]:
    ends = np.cumsum(sizes)
    return tuple(slice(int(e - k), int(e)) for e, k in zip(ends, sizes))


def memberships(grid: GaussianGrid, x: np.ndarray) -> list[np.ndarray]:
    """``mu_ij(x_i)`` of every set, one array per input."""
    z = np.minimum(np.maximum(x, grid.lo), grid.hi)[grid.owner]
    mu = np.exp(-np.square((z - grid.flat_centres) / grid.flat_sigma))
    return [mu[s] for s in grid.slices]


def basis(grid: GaussianGrid, x: np.ndarray) -> np.ndarray:
    """``xi(x)``: the normalised firing strengths of every rule (row-major grid order)."""
    mu = memberships(grid, x)
    g = np.outer(mu[0], mu[1]).ravel() if len(mu) == 2 else reduce(np.multiply.outer, mu).ravel()
    return g / g.sum()
