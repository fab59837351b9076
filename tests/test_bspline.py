"""B-spline membership functions against scipy's BSpline, the knot erratum, clipping."""

import numpy as np
import pytest
from scipy.interpolate import BSpline

from tspend.bspline import (BSplineInput, basis_matrix, greville_abscissae, memberships,
                            membership_gradient, open_uniform_knots, triangle_control_points)


@pytest.mark.parametrize("r,d", [(7, 3), (9, 3), (9, 4), (5, 2), (12, 5), (3, 3)])
@pytest.mark.parametrize("lo,hi", [(-6.0, 6.0), (0.0, 1.0471975511965976), (-1400.0, 1400.0)])
def test_basis_equals_scipy_bspline(r, d, lo, hi):
    knots = open_uniform_knots(lo, hi, r, d)
    z = np.concatenate([np.linspace(lo, hi, 997), knots])
    N = basis_matrix(z, knots, d)
    for i in range(r):
        c = np.zeros(r)
        c[i] = 1.0
        # scipy's degree is our order minus one; extrapolate=False gives nan past hi,
        # so evaluate hi just inside, where the spline is continuous
        ref = BSpline(knots, c, d - 1, extrapolate=True)(np.clip(z, lo, hi))
        np.testing.assert_allclose(N[:, i], ref, rtol=0, atol=1e-12)


def test_knot_step_erratum_gives_uniform_spans():
    knots = open_uniform_knots(-6.0, 6.0, 9, 3)
    assert knots.size == 12
    spans = np.diff(np.unique(knots))
    np.testing.assert_allclose(spans, spans[0])           # all spans equal
    assert spans[0] == pytest.approx(12.0 / (9 - 3 + 1))  # not 12 / (r - d + 2)


def test_partition_of_unity_and_right_end():
    knots = open_uniform_knots(-1.0, 2.0, 8, 3)
    z = np.array([-1.0, -0.3, 0.0, 1.999999, 2.0])
    np.testing.assert_allclose(basis_matrix(z, knots, 3).sum(axis=1), 1.0, atol=1e-14)
    assert basis_matrix(np.array([2.0]), knots, 3)[0, -1] == pytest.approx(1.0)


def test_inputs_outside_interval_are_clamped():
    knots = open_uniform_knots(-1.0, 1.0, 7, 3)
    far = basis_matrix(np.array([-1e9, 1e9, np.inf, -np.inf]), knots, 3)
    ends = basis_matrix(np.array([-1.0, 1.0, 1.0, -1.0]), knots, 3)
    np.testing.assert_array_equal(far, ends)


def test_initial_sets_cover_interval_and_sum_to_one():
    inp = BSplineInput("x", -6.0, 6.0, 5, 9, 3)
    C = inp.initial_control_points()
    z = np.linspace(-6, 6, 501)
    mu = np.clip(C @ basis_matrix(z, inp.knots, 3).T, 0, 1)
    np.testing.assert_allclose(mu.sum(axis=0), 1.0, atol=1e-12)
    assert (mu.max(axis=0) > 0.3).all()                   # every point fires some set
    peaks = z[np.argmax(mu, axis=1)]
    np.testing.assert_allclose(peaks, np.linspace(-6, 6, 5), atol=0.2)  # NB .. PB in order


def test_greville_points_lie_in_interval_and_increase():
    knots = open_uniform_knots(0.0, 1.0, 9, 3)
    g = greville_abscissae(knots, 3)
    assert g.size == 9 and g[0] == 0.0 and g[-1] == 1.0 and np.all(np.diff(g) > 0)


def test_clipping_and_gradient_mask():
    knots = open_uniform_knots(0.0, 1.0, 5, 3)
    N = basis_matrix(np.array([0.4]), knots, 3)[0]
    C = np.array([[2.0] * 5, [-1.0] * 5, [0.5] * 5])
    mu, unsat = memberships(C, N)
    np.testing.assert_allclose(mu, [1.0, 0.0, 0.5])
    np.testing.assert_array_equal(unsat, [False, False, True])
    G = membership_gradient(N, unsat)
    np.testing.assert_array_equal(G[:2], 0.0)
    np.testing.assert_allclose(G[2], N)


def test_membership_gradient_matches_finite_differences():
    rng = np.random.default_rng(0)
    inp = BSplineInput("x", -2.0, 3.0, 3, 8, 3)
    C = inp.initial_control_points() * 0.8 + 0.05
    for z in rng.uniform(-2, 3, 20):
        N = basis_matrix(np.array([z]), inp.knots, 3)[0]
        mu, unsat = memberships(C, N)
        G = membership_gradient(N, unsat)
        h = 1e-7
        for s in range(3):
            for l in range(8):
                Cp, Cm = C.copy(), C.copy()
                Cp[s, l] += h
                Cm[s, l] -= h
                fd = (memberships(Cp, N)[0][s] - memberships(Cm, N)[0][s]) / (2 * h)
                if 1e-6 < C[s] @ N < 1 - 1e-6:
                    assert G[s, l] == pytest.approx(fd, abs=1e-7)
