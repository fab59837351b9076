"""Test oracle (numpy) of :mod:`tspend.controllers.paper.rules`. The grid rule base: every combination of the inputs' terms is a rule, eq. (8)-(12).

Rule i fires with ``prod_j mu_{F_j^i}(z_j)``; normalised by ``varpi``, the sum over
rules, it is ``w^i`` (12).  On a grid the unnormalised strengths are the outer product
of the inputs' membership vectors and ``varpi`` is the product of their sums, so no
loop over rules is needed.  Rules are numbered in C order of the grid (the last input
varies fastest).

The weighted output of any per-rule quantity ``y^i`` is ``y = sum_i w^i y^i``; its
gradient with respect to one membership value (the chain rule behind eq. (11),
docs/paper-notes.md section 4) is ``dy/dmu_{F_j^s} = sum_{i uses F_j^s} (y^i - y) w^i / mu_{F_j^s}``, where
``w^i / mu_{F_j^s}`` is the product of the rule's *other* memberships over ``varpi``:
a tensor contraction over every input but j, never a division by a membership.

Guard against ``varpi -> 0`` (every set of some input at zero, possible once control
points adapt): the weights are ``(g_i + eps/h) / (varpi + eps)``, which is the plain
(12) to within ``eps = 1e-12`` when any rule fires and uniform when none does.  The
gradient below is the exact gradient of this guarded form.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tspend.controllers.paper.bspline import BSplineInput

from .numpy_bspline import BasisEvaluator, memberships

#: regularisation of the normalisation (12); see the module docstring
VARPI_EPS = 1e-12

_LETTERS = "abcdefghijklmnopqrstuvwxyz"


@dataclass
class Firing:
    """One evaluation of the rule base at an input vector z."""

    z: np.ndarray                  # (m,) inputs clamped to their intervals
    N: list[np.ndarray]            # per input: basis (r_j,)
    mu: list[np.ndarray]           # per input: memberships (T_j,)
    unsaturated: list[np.ndarray]  # per input: 0 < B < 1 mask (T_j,)
    w: np.ndarray                  # (h,) normalised firing strengths (12)
    varpi: float                   # sum of unnormalised strengths (plus eps)


class RuleBase:
    """The grid of rules over ``inputs``; holds each input's BMF control points.

    ``C[j]`` is the (T_j, r_j) control-point array of input j: the antecedent
    parameters adapted by the second type laws.
    """

    def __init__(self, inputs: tuple[BSplineInput, ...]) -> None:
        if not inputs:
            raise ValueError("a rule base needs at least one input")
        self.inputs = tuple(inputs)
        self.shape = tuple(inp.terms for inp in self.inputs)
        self.size = int(np.prod(self.shape))
        self.knots = [inp.knots for inp in self.inputs]
        self.bases = [BasisEvaluator(kn, inp.order) for kn, inp in zip(self.knots, self.inputs)]
        self.orders = [inp.order for inp in self.inputs]
        self.lo = np.array([inp.lo for inp in self.inputs])
        self.hi = np.array([inp.hi for inp in self.inputs])
        # all inputs' control points in one padded array (m, T_max, r_max), so that a
        # compiled kernel can update them in place; C[j] is input j's (T_j, r_j) view
        self.C_all = np.zeros((len(self.inputs), max(self.shape),
                               max(inp.control_points for inp in self.inputs)))
        self.C = [self.C_all[j, : inp.terms, : inp.control_points]
                  for j, inp in enumerate(self.inputs)]
        for C, inp in zip(self.C, self.inputs):
            C[:] = inp.initial_control_points()
        self._leave_one_out = self._contraction_subscripts()
        self._grid_basis: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    def _contraction_subscripts(self) -> list[str]:
        """einsum subscripts contracting a rule tensor with every input's vector but one."""
        m = len(self.inputs)
        axes = _LETTERS[:m]
        subs = []
        for j in range(m):
            others = [axes[k] for k in range(m) if k != j]
            subs.append(",".join([axes] + others) + "->" + axes[j])
        return subs

    @property
    def term_index(self) -> np.ndarray:
        """(h, m): the term of each input used by each rule."""
        return np.indices(self.shape).reshape(len(self.shape), -1).T

    def evaluate(self, z: np.ndarray) -> Firing:
        """Memberships of every input and normalised firing strengths (12) at ``z``."""
        z = np.clip(np.asarray(z, dtype=float), self.lo, self.hi)
        N = [basis(zj)[0] for zj, basis in zip(z, self.bases)]
        mu, unsat = zip(*(memberships(Cj, Nj) for Cj, Nj in zip(self.C, N)))
        g = mu[0]
        for mu_j in mu[1:]:
            g = np.multiply.outer(g, mu_j)
        g = g.reshape(-1)
        varpi = float(np.prod([m_j.sum() for m_j in mu])) + VARPI_EPS
        w = (g + VARPI_EPS / self.size) / varpi
        return Firing(z, list(N), list(mu), list(unsat), w, varpi)

    def output_gradient_wrt_memberships(self, fir: Firing, y_rules: np.ndarray) -> list[np.ndarray]:
        """``d y / d mu_{F_j^s}`` for ``y = sum_i w^i y^i``: per input, shape (T_j,)."""
        y = fir.w @ y_rules
        D = ((y_rules - y) / fir.varpi).reshape(self.shape)
        grads = []
        for j, subs in enumerate(self._leave_one_out):
            others = [fir.mu[k] for k in range(len(self.inputs)) if k != j]
            grads.append(np.einsum(subs, D, *others) if others else D.copy())
        return grads

    def output_gradient_wrt_control_points(self, fir: Firing, y_rules: np.ndarray) -> list[np.ndarray]:
        """``d y / d c`` for every input's control points: per input, shape (T_j, r_j).

        Chain rule: ``dy/dc_{s,l} = dy/dmu_s * N_l`` where the set is unsaturated.
        """
        dmu = self.output_gradient_wrt_memberships(fir, y_rules)
        return [(g * u)[:, None] * N[None, :] for g, u, N in zip(dmu, fir.unsaturated, fir.N)]

    def curves(self, j: int, points: int = 101) -> tuple[np.ndarray, np.ndarray]:
        """Membership curves of input j on a grid: (grid (G,), curves (T_j, G))."""
        key = (j, points)
        if key not in self._grid_basis:  # the basis on the grid never changes: once
            grid = np.linspace(self.lo[j], self.hi[j], points)
            self._grid_basis[key] = (grid, self.bases[j](grid).T)
        grid, NT = self._grid_basis[key]
        return grid, np.clip(self.C[j] @ NT, 0.0, 1.0)
