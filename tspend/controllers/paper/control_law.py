"""The control law (19), the error dynamics (18) and the Lyapunov matrix of Lemma 1.

Gamma is solved once when the controller is built (numpy); the per-sample functions
are compiled.

``e = x - r`` with ``r = [r, r', .., r^(n-1)]``; ``lambda = [lambda_1 .. lambda_n]`` makes
the companion matrix Lambda (last row ``-lambda``) Hurwitz, and Gamma solves
``Lambda^T Gamma + Gamma Lambda = -Q`` (Lemma 1).  ``e_Delta = e^T Gamma b_e``.

Control (19): ``u = (-p_{1..n} . x_delta + r^(n) - lambda^T e - u_s) / p_{n+1} + u_o``.
(17) is garbled by the OCR; (19) is the law implemented.  With it the model's error
dynamics are (18): ``e' = Lambda e + b_e (d~ - u_s)``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

# Lambda of (18) and its Hurwitz test live with the settings they validate (tspend.config)
from tspend.config import companion, is_hurwitz  # noqa: F401 - re-exported
import tspend.runtime.xp as xp
from tspend.runtime.law import array_law
from tspend.runtime.jit import JIT


def lyapunov_gamma(lam: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """Gamma of Lemma 1: the solution of ``Lambda^T Gamma + Gamma Lambda = -Q``.

    Solved as the Kronecker-product linear system (n^2 unknowns, n is small), which is
    independent of scipy's Bartels-Stewart solver that the tests compare against.
    """
    A = companion(lam)
    Q = np.asarray(Q, dtype=float)
    n = A.shape[0]
    eye = np.eye(n)
    # vec(A^T G + G A) = (I kron A^T + A^T kron I) vec(G), with row-major vec
    K = np.kron(A.T, eye) + np.kron(eye, A.T)
    G = np.linalg.solve(K, -Q.reshape(-1)).reshape(n, n)
    return 0.5 * (G + G.T)


class ControlLawSettings(NamedTuple):
    """Constants of (18)-(19): the error gains and Gamma of Lemma 1."""

    lam: np.ndarray          # (n,) lambda_1 .. lambda_n
    Gamma: np.ndarray        # (n, n) solves Lambda^T Gamma + Gamma Lambda = -Q


def control_law_settings(lam, Q) -> ControlLawSettings:
    lam = np.asarray(lam, dtype=float)
    return ControlLawSettings(lam=lam, Gamma=lyapunov_gamma(lam, np.asarray(Q, dtype=float)))


@array_law
def tracking_errors(s: ControlLawSettings, x: np.ndarray, ref: np.ndarray,
                    e: np.ndarray) -> tuple:
    """``(e_Delta, e)``: ``e = x - r`` in ``e`` and ``e_Delta = e^T Gamma b_e`` (Gamma's
    last row . e)."""
    G = s.Gamma
    n = e.size
    e_delta = 0.0
    for k in range(n):
        ek = x[k] - ref[k]
        e = xp.put(e, k, ek)
        e_delta += G[n - 1, k] * ek
    return e_delta, e


@njit(**JIT)
def tracking_error(s: ControlLawSettings, x: np.ndarray, ref: np.ndarray, e: np.ndarray) -> float:
    """The ``e_Delta`` of :func:`tracking_errors`, ``e`` written into ``e``."""
    return tracking_errors(s, x, ref, e)[0]


@array_law
def lyapunov_tracking(s: ControlLawSettings, e: np.ndarray) -> float:
    """The tracking part of the Lyapunov function (28): ``V = 1/2 e^T Gamma e``."""
    G = s.Gamma
    n = e.size
    V = 0.0
    for k in range(n):
        acc = 0.0
        for i in range(n):
            acc += (0.5 * e[i]) * G[i, k]
        V += acc * e[k]
    return V


@array_law
def control(p: np.ndarray, x_delta: np.ndarray, r_n: float, lam: np.ndarray,
            e: np.ndarray, u_s: float, u_o: float) -> float:
    """The control law (19): ``u = (-p_{1..n} . x_delta + r^(n) - lambda^T e - u_s) / p_{n+1} + u_o``."""
    n = lam.size
    px = 0.0
    le = 0.0
    for k in range(n):
        px += p[k] * x_delta[k]
        le += lam[k] * e[k]
    return (-px + r_n - le - u_s) / p[n] + u_o


def compensator_share(u_s: np.ndarray, b_hat: np.ndarray) -> np.ndarray:
    """The compensator's part of ``u`` in (19): ``-u_s / p_{n+1}``, in ``u``'s unit.

    ``u_s`` itself is in the unit of ``x^(n)`` (it cancels the uncertainty of (14)); what
    it does to the plant's input is this share, drawn by the recorder beside ``u``.
    """
    return -np.asarray(u_s, dtype=np.float64) / np.asarray(b_hat, dtype=np.float64)
