"""Test oracle (numpy) of :mod:`tspend.controllers.paper.compensator`. The fuzzy error compensator, eq. (21)-(24), and its adaptive law (27).

Rules (22): IF e_Delta is F_e^i AND ||x|| is F_x^i THEN d_hat^i = q^i; the estimate of
the lumped error d~ is ``d_hat = sum_i tau^i q^i`` (23) and the compensator is
``u_s = sign(e_Delta) d_hat`` (21)/(24).

Law (27): ``dq^i/dt = gamma tau^i |e_Delta|``; its membership part moves the BMF
control points along ``gamma |e_Delta| d d_hat / dc`` (the tau entries for the
membership part of (23) are exactly that derivative).

(27) only ever increases d_hat.  Two standard robust options, off by default so that the
paper's own run stays the paper's: a boundary layer ``sat(e_Delta / eps)`` in place of
sign() (removes chattering at the cost of a residual error of order eps), and leakage
(sigma-modification) ``dq/dt = gamma (tau |e_Delta| - sigma q)`` (bounds q).
"""

from __future__ import annotations

import numpy as np

from tspend.controllers.paper.bspline import BSplineInput

from .numpy_rules import Firing, RuleBase


def switching(e_delta: float, boundary_layer: float) -> float:
    """sign(e_Delta) of (21), or sat(e_Delta / eps) with a boundary layer eps > 0."""
    if boundary_layer > 0.0:
        return float(np.clip(e_delta / boundary_layer, -1.0, 1.0))
    return float(np.sign(e_delta))


class FuzzyCompensator:
    """Rule base on ``(e_Delta, ||x||)`` with consequents ``q`` (h_d,)."""

    def __init__(self, e_input: BSplineInput, x_input: BSplineInput,
                 boundary_layer: float = 0.0, leakage: float = 0.0,
                 leakage_mode: str = "sigma") -> None:
        self.rules = RuleBase((e_input, x_input))
        self.boundary_layer = float(boundary_layer)
        self.leakage = float(leakage)
        self.leakage_mode = leakage_mode
        self.q = np.zeros(self.rules.size)

    def initialise(self, rng: np.random.Generator, lo: float, hi: float) -> None:
        self.q[:] = rng.uniform(lo, hi, size=self.rules.size)

    def evaluate(self, e_delta: float, x_norm: float) -> tuple[Firing, float, float]:
        """Firing strengths tau, the estimate d_hat (23) and u_s (21)."""
        fir = self.rules.evaluate(np.array([e_delta, x_norm]))
        d_hat = float(fir.w @ self.q)
        return fir, d_hat, switching(e_delta, self.boundary_layer) * d_hat

    def q_rate(self, fir: Firing, e_delta: float, gamma: float) -> np.ndarray:
        """(27): ``dq/dt = gamma (tau |e_Delta| - sigma q)``."""
        rate = (gamma * abs(e_delta)) * fir.w
        if self.leakage > 0.0:
            scale = abs(e_delta) if self.leakage_mode == "e" else 1.0
            rate -= (gamma * self.leakage * scale) * self.q
        return rate

    def control_point_rates(self, fir: Firing, e_delta: float, gamma: float,
                            adapt: bool = True) -> list[np.ndarray]:
        """Membership part of (27): ``dc/dt = gamma |e_Delta| d d_hat / dc``."""
        if not adapt:
            return [np.zeros_like(C) for C in self.rules.C]
        grads = self.rules.output_gradient_wrt_control_points(fir, self.q)
        return [(gamma * abs(e_delta)) * g for g in grads]
