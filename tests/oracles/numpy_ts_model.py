"""Test oracle (numpy) of :mod:`tspend.controllers.paper.ts_model`. The T-S fuzzy model of the plant and its second type adaptive laws, eq. (9)-(16), (25)-(26).

Rule i (13): IF x_o1 is F_1^i AND .. AND u_o is F_{n+1}^i
THEN x_n' = p_1^i x_delta1 + .. + p_n^i x_deltan + p_{n+1}^i u_delta.
The model output (14)/(16) is ``x_n' = p . v + d~`` with ``v = [x_delta; u_delta]`` and
``p_k = sum_i w^i p_k^i`` (9).

Adaptive laws, with ``e_Delta = e^T Gamma b_e``:

* consequents (25)-(26): ``dp_k^i/dt = eta w^i v_k e_Delta``;
* antecedents (second type): the paper adapts the membership values themselves through
  the regressors of (11).  What can be tuned is the BMF control points, which all n+1
  outputs share, so (11) summed over k is carried to the control points by the chain
  rule (docs/paper-notes.md section 4): ``dc/dt = eta_mu e_Delta dy/dc`` with ``y^i = p^i . v`` and
  ``y = sum_i w^i y^i``.  ``eta_mu = 0`` is the first type law (consequents only).

Assumption 5 (b_hat bounded away from zero) is enforced by projecting every control-gain
consequent onto ``p_{n+1}^i >= b_min > 0`` after each update: ``b_hat`` is a convex
combination of them, so ``b_hat >= b_min`` at every step.  Assumption 4 (parameters in
a ball) is an optional projection of each consequent column onto ``||p_k|| <= radius``.
"""

from __future__ import annotations

import numpy as np

from tspend.controllers.paper.bspline import BSplineInput

from .numpy_rules import Firing, RuleBase


class TSModel:
    """Grid T-S model with consequents ``P`` (h, n+1) over the inputs ``[x_o; u_o]``."""

    def __init__(self, inputs: tuple[BSplineInput, ...], b_min: float,
                 norm_radius: float = 0.0) -> None:
        self.rules = RuleBase(inputs)
        self.order = len(inputs) - 1
        self.b_min = float(b_min)
        self.norm_radius = float(norm_radius)
        self.P = np.zeros((self.rules.size, self.order + 1))

    def initialise(self, rng: np.random.Generator, lo: float, hi: float) -> None:
        """Consequents drawn uniformly from [lo, hi], the gains inside the projection set.

        The paper draws every consequent around zero, so b_hat starts with either sign
        and (19) divides by it: gains are drawn from ``[max(lo, b_min), max(hi, b_min)]``
        instead (a point when the interval lies below b_min), docs/paper-notes.md section 5.
        """
        h, n = self.rules.size, self.order
        self.P[:, :n] = rng.uniform(lo, hi, size=(h, n))
        self.P[:, n] = rng.uniform(max(lo, self.b_min), max(hi, self.b_min), size=h)
        self.project()

    def evaluate(self, z: np.ndarray) -> tuple[Firing, np.ndarray]:
        """Firing strengths at the operating point ``z`` and the model's p (9)."""
        fir = self.rules.evaluate(z)
        return fir, fir.w @ self.P

    def consequent_rate(self, fir: Firing, v: np.ndarray, e_delta: float, eta: float) -> np.ndarray:
        """(25)-(26): ``dP/dt = eta e_Delta w v^T``, shape (h, n+1)."""
        return (eta * e_delta) * np.multiply.outer(fir.w, v)

    def output_gradient_wrt_control_points(self, fir: Firing, v: np.ndarray) -> list[np.ndarray]:
        """``d(p . v)/dc`` for every input's control points (the chain rule of (11))."""
        return self.rules.output_gradient_wrt_control_points(fir, self.P @ v)

    def control_point_rates(self, fir: Firing, v: np.ndarray, e_delta: float,
                            eta_mu: float) -> list[np.ndarray]:
        """Second type antecedent law: ``dc/dt = eta_mu e_Delta d(p . v)/dc``."""
        if eta_mu == 0.0:
            return [np.zeros_like(C) for C in self.rules.C]
        grads = self.output_gradient_wrt_control_points(fir, v)
        return [(eta_mu * e_delta) * g for g in grads]

    def project(self) -> None:
        """Assumption 5: gains onto ``p_{n+1}^i >= b_min``; Assumption 4 if a radius is set."""
        if self.norm_radius > 0.0:
            norms = np.linalg.norm(self.P, axis=0)
            self.P *= np.minimum(1.0, self.norm_radius / np.maximum(norms, 1e-300))
        np.maximum(self.P[:, self.order], self.b_min, out=self.P[:, self.order])
