"""The second type adaptive fuzzy controller: T-S model + compensator + control law (19).

One call of :meth:`AdaptiveFuzzyController.step` is one controller sample:

1. ``e = x - r``, ``e_Delta = e^T Gamma b_e``;
2. the operating point: fixed ``(x_o, u_o)``, or state-following ``x_o = x`` and
   ``u_o = fraction * u(previous sample)`` (Example 3's ``u_o = u(t)/2`` is an algebraic
   loop; the previous sample breaks it, docs/paper-notes.md section 6);
3. the T-S model's p (9) at ``z = [x_o; u_o]``, the compensator's d_hat and u_s (21)-(23);
4. u from (19);
5. the adaptive laws (25)-(27) integrated by forward Euler over the sample time, as a
   digital controller does, then the projections (Assumptions 4-5).

The diagnostics of the sample are written into ``self.diag`` (layout :data:`DIAG_KEYS`),
which the runner copies into its block: no allocation of result objects per step.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .bspline import BSplineInput
from .compensator import FuzzyCompensator
from .config import ControllerConfig, SetSpec
from .control_law import control, lyapunov_gamma
from .controllers.base import Diagnostic
from .sinks import FuzzyInputInfo, InnerSnapshot
from .ts_model import TSModel

#: scalar diagnostics in ``diag``, in order; then e (n entries) and p (n + 1 entries)
DIAG_SCALARS = ("u", "u_s", "d_hat", "e_delta", "V", "norm_P", "norm_q", "min_b")


def diag_layout(n: int) -> dict[str, slice | int]:
    """Where each diagnostic sits in the ``diag`` vector of an order-n controller."""
    layout: dict[str, slice | int] = {k: i for i, k in enumerate(DIAG_SCALARS)}
    s = len(DIAG_SCALARS)
    layout["e"] = slice(s, s + n)
    layout["p"] = slice(s + n, s + 2 * n + 1)
    return layout


def diag_size(n: int) -> int:
    return len(DIAG_SCALARS) + 2 * n + 1


def paper_diagnostics(n: int) -> tuple[Diagnostic, ...]:
    """The per-sample diagnostics of the paper controller, as the runner sees them.

    ``u`` and ``e`` are in ``diag`` too (the kernel writes them) but the runner records
    those itself, so they are not declared.
    """
    L = diag_layout(n)
    p = L["p"]
    return (
        Diagnostic("u_s", L["u_s"], panel="compensator", unit="N",
                   description="compensator part of u (21)", chattering=True),
        Diagnostic("d_hat", L["d_hat"], panel="disturbance", unit="",
                   description="compensator estimate of the lumped uncertainty (23)", chattering=True),
        Diagnostic("e_delta", L["e_delta"], panel="error", description="e^T Gamma b_e"),
        Diagnostic("V", L["V"], panel="lyapunov", log=True,
                   description="tracking part of the Lyapunov function (28), 1/2 e^T Gamma e"),
        Diagnostic("norm_P", L["norm_P"], panel="norms", log=True,
                   description="Frobenius norm of the consequents P"),
        Diagnostic("norm_q", L["norm_q"], panel="norms", log=True,
                   description="norm of the compensator consequents q"),
        Diagnostic("min_b", L["min_b"], panel="norms",
                   description="min over rules of p_{n+1}^i (>= b_min under projection)"),
        Diagnostic("p", p.start, p.stop - p.start,
                   labels=tuple(f"p_{i + 1}" for i in range(n)) + ("b_hat",), panel="params",
                   description="model output p_1 .. p_{n+1} of (9); b_hat = p_{n+1}"),
    )


def _input(name: str, spec: SetSpec, cfg: ControllerConfig) -> BSplineInput:
    return BSplineInput(name, spec.lo, spec.hi, spec.terms, cfg.control_points, cfg.bspline_order)


def model_inputs(cfg: ControllerConfig) -> tuple[BSplineInput, ...]:
    """Antecedent inputs of the T-S model: x_o1 .. x_on, u_o."""
    xs = tuple(_input(f"x_o{j + 1}", s, cfg) for j, s in enumerate(cfg.state_sets))
    return xs + (_input("u_o", cfg.u_sets, cfg),)


def compensator_inputs(cfg: ControllerConfig) -> tuple[BSplineInput, BSplineInput]:
    return _input("e_delta", cfg.e_delta_sets, cfg), _input("|x|", cfg.x_norm_sets, cfg)


def input_info(inputs: tuple[BSplineInput, ...]) -> tuple[FuzzyInputInfo, ...]:
    return tuple(FuzzyInputInfo(i.name, i.lo, i.hi, i.term_names) for i in inputs)


class FiringView(NamedTuple):
    """One rule base's inputs (m,), memberships (per input, (T_j,)) and firing (h,)."""

    z: np.ndarray
    mu: list
    w: np.ndarray


class AdaptiveFuzzyController:
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
        self.model = TSModel(model_inputs(cfg), cfg.b_min, cfg.norm_radius, cfg.b_sign)
        e_in, x_in = compensator_inputs(cfg)
        self.compensator = FuzzyCompensator(e_in, x_in, cfg.boundary_layer, cfg.leakage)
        self.eta = cfg.eta
        self.eta_mu = cfg.antecedent_rate
        self.gamma = cfg.gamma
        self.adapt_compensator_sets = cfg.adaptation != "first"
        self.state_following = cfg.operating_point == "state"
        self.x_o_fixed = np.zeros(n) if not cfg.x_o else np.asarray(cfg.x_o, dtype=float)
        self.u_prev = 0.0
        self.diag = np.zeros(diag_size(n))
        self.layout = diag_layout(n)
        self.diagnostics = paper_diagnostics(n)
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

    def fuzzy_inputs(self) -> dict[str, tuple[FuzzyInputInfo, ...]]:
        """The antecedent inputs of the model's and the compensator's rule bases."""
        return {"model": input_info(model_inputs(self.cfg)),
                "compensator": input_info(compensator_inputs(self.cfg))}

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

    def snapshot(self, t: float, step: int, x: np.ndarray) -> InnerSnapshot:
        """The controller's inner state after the sample at ``t``: membership curves (with
        the adapted control points), where the sample's inputs sat on them, and the
        firing strengths and consequents it used."""
        fir, cfir = self.last_firing(x)
        return InnerSnapshot(
            t=t, step=step,
            model_sets=_sets(self.model.rules, fir),
            compensator_sets=_sets(self.compensator.rules, cfir),
            firing=np.array(fir.w), compensator_firing=np.array(cfir.w),
            consequents=self.model.P.copy(), q=self.compensator.q.copy())


def _sets(rules, fir: FiringView) -> tuple:
    out = []
    for j in range(len(rules.inputs)):
        grid, curves = rules.curves(j)
        out.append((grid, curves, float(fir.z[j]), np.array(fir.mu[j])))
    return tuple(out)
