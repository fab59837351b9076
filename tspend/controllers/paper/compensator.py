"""The fuzzy error compensator, eq. (21)-(24), and its adaptive law (27), compiled.

Rules (22): IF e_Delta is F_e^i AND ||x|| is F_x^i THEN d_hat^i = q^i; the estimate of
the lumped error d~ is ``d_hat = sum_i tau^i q^i`` (23) and the compensator is
``u_s = sign(e_Delta) d_hat`` (21)/(24).

Law (27): ``dq^i/dt = gamma tau^i |e_Delta|``; its membership part moves the BMF
control points along ``gamma |e_Delta| d d_hat / dc`` (the tau entries for the
membership part of (23) are exactly that derivative).

(27) only ever increases d_hat.  Robust options, off by default so that the paper's own
run stays the paper's:

* a boundary layer ``sat(e_Delta / eps)`` in place of sign() (removes chattering at the
  cost of a residual error of order eps);
* leakage ``sigma > 0`` (``leakage``), in one of two forms (``leakage_mode``):

  - ``"sigma"``, the sigma-modification (Ioannou & Kokotovic):
    ``dq/dt = gamma (tau |e_Delta| - sigma q)``; bounds q, at the price of a bias
    towards q = 0 even when the error is zero;
  - ``"e"``, Narendra's e-modification (K. S. Narendra and A. M. Annaswamy, "A new
    adaptive law for robust adaptation without persistent excitation", IEEE Trans.
    Automatic Control 32(2):134-145, 1987):
    ``dq/dt = gamma (tau |e_Delta| - sigma |e_Delta| q)``; the leakage is scaled by the
    error, so it vanishes as tracking becomes exact and q is not pulled away from the
    value that achieves it.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import tspend.runtime.xp as xp
from tspend.runtime.law import array_law
from tspend.config import ControllerConfig
from tspend.controllers.paper.rules import (Firing, Grid, membership_gradient, move_control_points,
    weighted_output)


class CompensatorSettings(NamedTuple):
    """Constants of the compensator and its law (27)."""

    grid: Grid               # rule base over (e_Delta, ||x||)
    gamma: float             # rate of (27)
    boundary_layer: float    # 0: sign() of (21)
    leakage: float           # sigma (0: the paper's (27))
    e_modification: bool     # leakage scaled by |e_Delta| (Narendra) instead of constant
    adapt_sets: bool         # the membership part of (27) (second type)


def compensator_settings(cfg: ControllerConfig, grid: Grid) -> CompensatorSettings:
    """The compensator's constants from the controller's configuration."""
    return CompensatorSettings(grid=grid, gamma=cfg.gamma, boundary_layer=cfg.boundary_layer,
                               leakage=cfg.leakage, e_modification=cfg.leakage_mode == "e",
                               adapt_sets=cfg.adaptation != "first")


@array_law
def switching(e_delta: float, boundary_layer: float) -> float:
    """sign(e_Delta) of (21), or sat(e_Delta / eps) with a boundary layer eps > 0."""
    if boundary_layer > 0.0:
        sw = e_delta / boundary_layer
        sw = xp.where(sw < -1.0, -1.0, sw)
        return xp.where(sw > 1.0, 1.0, sw)
    # sign(0) = 0 (and NaN stays NaN)
    return xp.where(e_delta > 0.0, 1.0, xp.where(e_delta < 0.0, -1.0, e_delta))


@array_law
def estimate(tau: np.ndarray, q: np.ndarray) -> float:
    """(23): ``d_hat = sum_i tau^i q^i``, the compensator rule base's weighted output."""
    return weighted_output(tau, q)


@array_law
def sets_gradient(s: CompensatorSettings, q: np.ndarray, f: Firing, varpi: float) -> Firing:
    """``d d_hat / dmu`` into ``f.dmu`` (per-rule outputs ``q^i``); returns ``f``."""
    y = f.y
    for i in range(q.size):
        y = xp.put(y, i, q[i])
    return membership_gradient(s.grid, Firing(f.z, f.basis, f.span, f.mu, f.dmu, f.w, y),
                               varpi)


@array_law
def compensator_law(s: CompensatorSettings, q: np.ndarray, C: np.ndarray, f: Firing,
                    e_delta: float, dt: float) -> tuple:
    """(27) with the optional leakage, one forward-Euler step; then its membership part
    ``dc/dt = gamma |e_Delta| d d_hat / dc`` (gradient from :func:`sets_gradient`);
    returns ``(q, C)``."""
    tau = f.w
    ae = s.gamma * abs(e_delta)
    if s.leakage > 0.0:
        gs = s.gamma * s.leakage * (abs(e_delta) if s.e_modification else 1.0)
        for i in range(q.size):
            q = xp.add(q, i, dt * (ae * tau[i] - gs * q[i]))
    else:
        for i in range(q.size):
            q = xp.add(q, i, dt * (ae * tau[i]))
    if s.adapt_sets:
        C, = move_control_points(s.grid, C, f, ae, dt)
    return q, C
