"""The T-S fuzzy model of the plant and its second type adaptive laws, eq. (9)-(16), (25)-(26), compiled.

Rule i (13): IF x_o1 is F_1^i AND .. AND u_o is F_{n+1}^i
THEN x_n' = p_1^i x_delta1 + .. + p_n^i x_deltan + p_{n+1}^i u_delta.
The model output (14)/(16) is ``x_n' = p . v + d~`` with ``v = [x_delta; u_delta]`` and
``p_k = sum_i w^i p_k^i`` (9).

Adaptive laws, with ``e_Delta = e^T Gamma b_e``, integrated by forward Euler over the
sample time (as a digital controller does):

* consequents (25)-(26): ``dp_k^i/dt = eta w^i v_k e_Delta``;
* antecedents (second type): the paper adapts the membership values themselves through
  the regressors of (11).  What can be tuned is the BMF control points, which all n+1
  outputs share, so (11) summed over k is carried to the control points by the chain
  rule (docs/paper-notes.md section 4): ``dc/dt = eta_mu e_Delta dy/dc`` with
  ``y^i = p^i . v`` and ``y = sum_i w^i y^i``.  ``eta_mu = 0`` is the first type law
  (consequents only).

Assumption 5 (b_hat bounded away from zero) is enforced by projecting every control-gain
consequent onto ``p_{n+1}^i >= b_min > 0`` after each update: ``b_hat`` is a convex
combination of them, so ``b_hat >= b_min`` at every step.  Assumption 4 (parameters in
a ball) is an optional projection of each consequent column onto ``||p_k|| <= radius``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import tspend.runtime.xp as xp
from tspend.runtime.law import array_law
from tspend.config import ControllerConfig
from tspend.controllers.paper.rules import Firing, Grid, membership_gradient, move_control_points


class ModelSettings(NamedTuple):
    """Constants of the T-S model and its laws."""

    grid: Grid               # rule base over [x_o; u_o]
    eta: float               # rate of (25)-(26)
    eta_mu: float            # rate of the antecedent law (0: first type)
    b_min: float             # Assumption 5
    b_sign: float            # Assumption 5's known sign of df/du: b_sign p_{n+1} >= b_min
    norm_radius: float       # Assumption 4 (0: off)


def model_settings(cfg: ControllerConfig, grid: Grid) -> ModelSettings:
    """The model's constants from the controller's configuration."""
    return ModelSettings(grid=grid, eta=cfg.eta, eta_mu=cfg.antecedent_rate, b_min=cfg.b_min,
                         b_sign=cfg.b_sign, norm_radius=cfg.norm_radius)


@array_law
def model_output(w: np.ndarray, P: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(9): ``p_k = sum_i w^i p_k^i`` into ``p`` (n+1,); returns ``(p,)`` (numba, without
    its runtime, returns an array only inside a tuple)."""
    for k in range(P.shape[1]):
        acc = 0.0
        for i in range(w.size):
            acc += w[i] * P[i, k]
        p = xp.put(p, k, acc)
    return (p,)


@array_law
def rule_outputs(P: np.ndarray, v: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Each rule's consequent (13) at ``v``: ``y^i = p^i . v``; returns ``(y,)``."""
    for i in range(P.shape[0]):
        acc = 0.0
        for k in range(P.shape[1]):
            acc += P[i, k] * v[k]
        y = xp.put(y, i, acc)
    return (y,)


@array_law
def antecedent_gradient(s: ModelSettings, P: np.ndarray, v: np.ndarray, f: Firing,
                        varpi: float) -> Firing:
    """``d(p . v)/dmu`` into ``f.dmu``: the regressors of (11) summed over k (chain rule);
    returns ``f``."""
    y, = rule_outputs(P, v, f.y)
    return membership_gradient(s.grid, Firing(f.z, f.basis, f.span, f.mu, f.dmu, f.w, y),
                               varpi)


@array_law
def antecedent_law(s: ModelSettings, C: np.ndarray, f: Firing, e_delta: float,
                   dt: float) -> np.ndarray:
    """Second type law: ``dc/dt = eta_mu e_Delta d(p . v)/dc`` (gradient from
    :func:`antecedent_gradient`); returns ``(C,)``."""
    return move_control_points(s.grid, C, f, s.eta_mu * e_delta, dt)


@array_law
def consequent_law(s: ModelSettings, P: np.ndarray, w: np.ndarray, v: np.ndarray,
                   e_delta: float, dt: float) -> np.ndarray:
    """(25)-(26): ``dP/dt = eta e_Delta w v^T``, one forward-Euler step, then the
    projections; returns ``(P,)``."""
    c = s.eta * e_delta
    for i in range(P.shape[0]):
        wi = w[i]
        for k in range(P.shape[1]):
            P = xp.add(P, (i, k), dt * (c * (wi * v[k])))
    return project(s, P)


@array_law
def project(s: ModelSettings, P: np.ndarray) -> np.ndarray:
    """Assumption 4 (each column onto ``||p_k|| <= radius``, if set), then Assumption 5:
    ``b_sign p_{n+1}^i >= b_min`` (``b_sign = -1`` on a plant whose gain is negative);
    returns ``(P,)``."""
    n = P.shape[1] - 1
    if s.norm_radius > 0.0:
        for k in range(n + 1):
            sq = 0.0
            for i in range(P.shape[0]):
                sq += P[i, k] * P[i, k]
            nrm = math.sqrt(sq)
            nrm = xp.where(nrm < 1e-300, 1e-300, nrm)
            f = s.norm_radius / nrm
            f = xp.where(f > 1.0, 1.0, f)
            for i in range(P.shape[0]):
                P = xp.put(P, (i, k), P[i, k] * f)
    for i in range(P.shape[0]):
        P = xp.put(P, (i, n), xp.where(s.b_sign * P[i, n] < s.b_min, s.b_sign * s.b_min,
                                       P[i, n]))
    return (P,)


def initial_consequents(s: ModelSettings, rng: np.random.Generator, order: int,
                        lo: float, hi: float) -> np.ndarray:
    """Consequents drawn uniformly from [lo, hi], the gains inside the projection set.

    The paper draws every consequent around zero, so b_hat starts with either sign
    and (19) divides by it: gains are drawn from ``[max(lo, b_min), max(hi, b_min)]``
    instead (a point when the interval lies below b_min), docs/paper-notes.md section 5.
    With a negative gain sign the interval is mirrored: ``-[max(-hi, b_min), max(-lo, b_min)]``.
    """
    h, n = s.grid.term_index.shape[0], order
    P = np.zeros((h, n + 1))
    P[:, :n] = rng.uniform(lo, hi, size=(h, n))
    lo_s, hi_s = sorted((s.b_sign * lo, s.b_sign * hi))
    P[:, n] = s.b_sign * rng.uniform(max(lo_s, s.b_min), max(hi_s, s.b_min), size=h)
    project(s, P)
    return P
