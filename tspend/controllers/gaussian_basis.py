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

import math
from typing import NamedTuple

import numpy as np

import tspend.runtime.xp as xp
from tspend.runtime.law import array_law

__all__ = ["GaussianGrid", "GaussianTable", "basis", "basis_into", "gaussian_grid",
           "memberships"]


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

    def table(self) -> "GaussianTable":
        """The grid as compiled code reads it (:func:`basis_into`)."""
        return GaussianTable(self.flat_centres.copy(), self.flat_sigma.copy(),
                             self.owner.astype(np.intp), self.lo.copy(), self.hi.copy(),
                             np.array([c.size for c in self.centres], dtype=np.intp))


class GaussianTable(NamedTuple):
    """A :class:`GaussianGrid` flattened for compiled code: every set's centre and width,
    the input it belongs to, the inputs' intervals and their number of sets."""

    centres: np.ndarray   # (total sets,)
    sigma: np.ndarray     # (total sets,)
    owner: np.ndarray     # (total sets,) intp
    lo: np.ndarray        # (inputs,)
    hi: np.ndarray        # (inputs,)
    terms: np.ndarray     # (inputs,) intp


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


@array_law
def memberships_into(table: GaussianTable, x: np.ndarray, mu: np.ndarray) -> tuple:
    """``mu_ij(x_i)`` of every set into ``mu`` (the sets of input 0 first), with ``x_i``
    clamped to its interval; returns ``(mu,)``."""
    for k in range(mu.size):
        i = table.owner[k]
        z = xp.where(table.lo[i] > x[i], table.lo[i], x[i])
        z = xp.where(table.hi[i] < z, table.hi[i], z)
        w = (z - table.centres[k]) / table.sigma[k]
        mu = xp.put(mu, k, math.exp(-(w * w)))
    return (mu,)


@array_law
def basis_into(table: GaussianTable, x: np.ndarray, mu: np.ndarray, xi: np.ndarray) -> tuple:
    """``xi(x)`` into ``xi``: every rule's product of memberships (row-major grid order: the
    last input's set varies fastest), normalised to sum 1; ``mu`` is scratch of one entry
    per set; returns ``(xi,)``.  The one implementation, for numba and JAX
    (:mod:`tspend.runtime.law`)."""
    mu, = memberships_into(table, x, mu)
    inputs = table.terms.size
    total = 0.0
    for rule in range(xi.size):
        # the rule's set of each input: rule's digits in the mixed radix of terms,
        # the first input's the most significant; product in input order
        g = 1.0
        stride = xi.size
        offset = 0
        rest = rule
        for i in range(inputs):
            stride //= table.terms[i]
            j = rest // stride
            rest -= j * stride
            g *= mu[offset + j]
            offset += table.terms[i]
        xi = xp.put(xi, rule, g)
        total += g
    for rule in range(xi.size):
        xi = xp.put(xi, rule, xi[rule] / total)
    return (xi,)


def memberships(grid: GaussianGrid, x: np.ndarray) -> list[np.ndarray]:
    """``mu_ij(x_i)`` of every set, one array per input."""
    mu = np.empty(grid.flat_centres.size)
    memberships_into(grid.table(), np.asarray(x, dtype=float), mu)
    return [mu[s] for s in grid.slices]


def basis(grid: GaussianGrid, x: np.ndarray) -> np.ndarray:
    """``xi(x)``: the normalised firing strengths of every rule (row-major grid order)."""
    mu, xi = np.empty(grid.flat_centres.size), np.empty(grid.rules)
    basis_into(grid.table(), np.asarray(x, dtype=float), mu, xi)
    return xi
