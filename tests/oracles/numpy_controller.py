"""Test oracle: one controller sample step by step in numpy (the pre-numba reference).

The compiled :class:`tspend.controllers.paper.controller.AdaptiveFuzzyController` must match it to rounding
at every step (tests/test_kernels.py).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from tspend.config import ControllerConfig
from tspend.controllers.paper.control_law import lyapunov_gamma
from tspend.controllers.paper.controller import (compensator_inputs, diag_layout, diag_size,
    model_inputs)

from .numpy_compensator import FuzzyCompensator
from .numpy_ts_model import TSModel


def control(p, x_delta, r_n, lam, e, u_s, u_o) -> float:
    """The control law (19)."""
    n = x_delta.size
    return float((-(p[:n] @ x_delta) + r_n - lam @ e - u_s) / p[n] + u_o)


class FiringView(NamedTuple):
    z: np.ndarray
    mu: list
    w: np.ndarray


class NumpyController:
    """The controller of Theorem 1 with the numpy reference implementation of each step.

    A :class:`tspend.controllers.base.Controller`: kind ``second_type`` (or
    ``first_type`` when the antecedents are fixed).
    """

    def __init__(self, cfg: ControllerConfig) -> None:
        self.cfg = cfg
        self.kind = "first_type" if cfg.adaptation == "first" else "second_type"
        self.n = self.order = n = cfg.order
        self.lam = np.asarray(cfg.lam, dtype=float)
        self.Gamma = lyapunov_gamma(self.lam, np.asarray(cfg.Q, dtype=float))
        #: e_Delta = e^T Gamma b_e = Gamma[n-1] . e (Gamma is symmetric)
        self.gamma_row = self.Gamma[n - 1].copy()
        self.model = TSModel(model_inputs(cfg), cfg.b_min, cfg.norm_radius)
        e_in, x_in = compensator_inputs(cfg)
        self.compensator = FuzzyCompensator(e_in, x_in, cfg.boundary_layer, cfg.leakage,
                                           cfg.leakage_mode)
        self.eta = cfg.eta
        self.eta_mu = cfg.antecedent_rate
        self.gamma = cfg.gamma
        self.adapt_compensator_sets = cfg.adaptation != "first"
        self.state_following = cfg.operating_point == "state"
        self.x_o_fixed = np.zeros(n) if not cfg.x_o else np.asarray(cfg.x_o, dtype=float)
        self.u_prev = 0.0
        self.diag = np.zeros(diag_size(n))
        self.layout = diag_layout(n)
        self._last: tuple | None = None        # the last sample's (model, compensator) firing

    # -- set-up -----------------------------------------------------------------------
    def initialise(self, rng: np.random.Generator) -> None:
        """Draw the initial consequents (model, then compensator) from ``rng``."""
        self.model.initialise(rng, *self.cfg.init_consequents)
        self.compensator.initialise(rng, *self.cfg.init_compensator)
        self.u_prev = 0.0

    def reset(self, rng: np.random.Generator) -> None:
        """The protocol's name for :meth:`initialise`."""
        self.initialise(rng)

    # -- one sample ---------------------------------------------------------------------
    def operating_point(self, x: np.ndarray) -> tuple[np.ndarray, float]:
        if self.state_following:
            return x, self.cfg.u_o_fraction * self.u_prev
        return self.x_o_fixed, self.cfg.u_o

    def step(self, x: np.ndarray, ref: np.ndarray, dt: float) -> float:
        """One controller sample at state ``x`` with reference derivatives ``ref`` (n+1,)."""
        n = self.n
        e = x - ref[:n]
        e_delta = float(self.gamma_row @ e)
        x_o, u_o = self.operating_point(x)
        x_delta = x - x_o
        fir, p = self.model.evaluate(np.append(x_o, u_o))
        cfir, d_hat, u_s = self.compensator.evaluate(e_delta, float(np.linalg.norm(x)))
        u = control(p, x_delta, ref[n], self.lam, e, u_s, u_o)
        v = np.append(x_delta, u - u_o)
        self._record(u, u_s, d_hat, e_delta, e, p)
        self._adapt(fir, cfir, v, e_delta, dt)
        self._last = (fir, cfir)
        self.u_prev = u
        return u

    def _adapt(self, fir, cfir, v: np.ndarray, e_delta: float, dt: float) -> None:
        """Forward-Euler step of (25)-(27) and the control-point laws, then projections."""
        model, comp = self.model, self.compensator
        dP = model.consequent_rate(fir, v, e_delta, self.eta)
        dC = model.control_point_rates(fir, v, e_delta, self.eta_mu)
        dq = comp.q_rate(cfir, e_delta, self.gamma)
        dCd = comp.control_point_rates(cfir, e_delta, self.gamma, self.adapt_compensator_sets)
        model.P += dt * dP
        model.project()
        for C, rate in zip(model.rules.C, dC):
            C += dt * rate
        comp.q += dt * dq
        for C, rate in zip(comp.rules.C, dCd):
            C += dt * rate

    def _record(self, u, u_s, d_hat, e_delta, e, p) -> None:
        g, L = self.diag, self.layout
        g[L["u"]], g[L["u_s"]], g[L["d_hat"]], g[L["e_delta"]] = u, u_s, d_hat, e_delta
        g[L["V"]] = 0.5 * e @ self.Gamma @ e
        g[L["norm_P"]] = np.linalg.norm(self.model.P)
        g[L["norm_q"]] = np.linalg.norm(self.compensator.q)
        g[L["min_b"]] = self.model.P[:, self.n].min()
        g[L["e"]] = e
        g[L["p"]] = p

    # -- inspection ---------------------------------------------------------------------
    def parameters(self) -> dict[str, np.ndarray]:
        """Copies of every adapted parameter (for tests and checkpoints)."""
        out = {"P": self.model.P.copy(), "q": self.compensator.q.copy()}
        out.update({f"C_model{j}": C.copy() for j, C in enumerate(self.model.rules.C)})
        out.update({f"C_comp{j}": C.copy() for j, C in enumerate(self.compensator.rules.C)})
        return out

    def last_firing(self, x: np.ndarray | None = None) -> tuple[FiringView, FiringView]:
        """Inputs, memberships and firing strengths that produced the last sample's u.

        Model (z = [x_o; u_o]) then compensator (z = [e_Delta, ||x||]), inputs clamped
        to their intervals as the rule bases see them.
        """
        if self._last is None:
            raise RuntimeError("no controller sample taken yet: call step() first")
        fir, cfir = self._last
        return (FiringView(fir.z, fir.mu, fir.w), FiringView(cfir.z, cfir.mu, cfir.w))

