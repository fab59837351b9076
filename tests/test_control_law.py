"""Lemma 1's Gamma against scipy, Hurwitz checks, the control law (19)."""

import numpy as np
import pytest
from scipy.linalg import solve_continuous_lyapunov

from tspend.controllers.paper.control_law import (companion, control, control_law_settings,
    is_hurwitz, lyapunov_gamma, lyapunov_tracking, tracking_error)


@pytest.mark.parametrize("lam,Q", [
    ((1.0, 2.0), np.diag([10.0, 10.0])),
    ((1.0, 3.0, 3.0), np.diag([10.0, 10.0, 10.0])),
    ((2.0, 5.0, 4.0, 3.0), np.eye(4) + 0.3 * np.ones((4, 4))),
])
def test_gamma_solves_lemma_1_and_equals_scipy(lam, Q):
    G = lyapunov_gamma(np.array(lam), Q)
    A = companion(np.array(lam))
    np.testing.assert_allclose(A.T @ G + G @ A, -Q, atol=1e-10)
    np.testing.assert_allclose(G, solve_continuous_lyapunov(A.T, -Q), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(G, G.T)
    assert np.linalg.eigvalsh(G).min() > 0


def test_paper_gamma_value():
    G = lyapunov_gamma(np.array([1.0, 2.0]), np.diag([10.0, 10.0]))
    np.testing.assert_allclose(G, [[15.0, 5.0], [5.0, 5.0]], atol=1e-12)


def test_hurwitz():
    assert is_hurwitz(np.array([1.0, 2.0]))
    assert not is_hurwitz(np.array([-1.0, 2.0]))
    assert not is_hurwitz(np.array([1.0, 0.0]))       # marginal: roots on the axis
    assert is_hurwitz(np.array([1.0, 3.0, 3.0]))


def test_control_law_gives_designed_error_dynamics():
    """On a plant that IS the model, (19) makes e'' = -lambda . e - u_s exactly."""
    rng = np.random.default_rng(0)
    lam = np.array([1.0, 2.0])
    p = np.array([0.3, -0.7, 1.9])
    x_o, u_o = np.array([0.1, -0.2]), 0.4
    x = rng.normal(size=2)
    ref = rng.normal(size=3)
    e = x - ref[:2]
    u_s = 0.05
    u = control(p, x - x_o, ref[2], lam, e, u_s, u_o)
    xdot_n = p[:2] @ (x - x_o) + p[2] * (u - u_o)
    assert xdot_n - ref[2] == pytest.approx(-lam @ e - u_s)


def test_tracking_error_and_lyapunov_function_against_scipy_gamma():
    """e_Delta = e^T Gamma b_e and V = 1/2 e^T Gamma e with Gamma from scipy's solver."""
    lam, Q = np.array([1.0, 3.0, 3.0]), np.diag([10.0, 4.0, 1.0])
    s = control_law_settings(lam, Q)
    G = solve_continuous_lyapunov(companion(lam).T, -Q)
    rng = np.random.default_rng(1)
    e = np.empty(3)
    for _ in range(10):
        x, ref = rng.normal(size=3), rng.normal(size=4)
        e_delta = tracking_error(s, x, ref, e)
        np.testing.assert_allclose(e, x - ref[:3])
        assert e_delta == pytest.approx(e @ G @ np.array([0.0, 0.0, 1.0]), rel=1e-10)
        assert lyapunov_tracking(s, e) == pytest.approx(0.5 * e @ G @ e, rel=1e-10)
