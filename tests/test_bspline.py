"""The compiled B-spline basis and memberships against scipy's BSpline, the knot erratum, clipping."""

import numpy as np
import pytest
from oracles.numpy_bspline import basis_matrix as numpy_basis_matrix
from scipy.interpolate import BSpline

from tspend.controllers.paper.bspline import BSplineInput, basis, greville_abscissae, membership_curves, memberships, open_uniform_knots, peak_windows, project_unimodal, triangle_control_points, unsaturated


def basis_matrix(z: np.ndarray, knots: np.ndarray, d: int) -> np.ndarray:
    """All r basis functions at every z, from the compiled nonzero ones: (len(z), r)."""
    r = len(knots) - d
    out = np.zeros((len(z), r))
    N = np.empty(d)
    for row, zk in enumerate(np.atleast_1d(z)):
        s = basis(float(zk), knots, r, d, N)
        out[row, s - d + 1: s + 1] = N
    return out


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
    # and the vectorised numpy oracle agrees with the compiled span-local recursion
    np.testing.assert_allclose(N, numpy_basis_matrix(z, knots, d), rtol=0, atol=1e-13)


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


def test_inputs_outside_interval_are_clamped_and_nan_gives_zero():
    knots = open_uniform_knots(-1.0, 1.0, 7, 3)
    far = basis_matrix(np.array([-1e9, 1e9, np.inf, -np.inf]), knots, 3)
    ends = basis_matrix(np.array([-1.0, 1.0, 1.0, -1.0]), knots, 3)
    np.testing.assert_array_equal(far, ends)
    assert not basis_matrix(np.array([np.nan]), knots, 3).any()


def test_initial_sets_cover_interval_and_sum_to_one():
    inp = BSplineInput("x", -6.0, 6.0, 5, 9, 3)
    C = inp.initial_control_points()
    z = np.linspace(-6, 6, 501)
    mu = np.empty((5, z.size))
    membership_curves(C, inp.knots, 9, 3, 5, z, mu)
    np.testing.assert_allclose(mu, np.clip(C @ basis_matrix(z, inp.knots, 3).T, 0, 1), atol=1e-15)
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
    N = np.empty(3)
    s = basis(0.4, knots, 5, 3, N)
    C = np.array([[2.0] * 5, [-1.0] * 5, [0.5] * 5])
    mu = np.empty(3)
    total = memberships(C, N, s, 3, 3, mu)
    np.testing.assert_allclose(mu, [1.0, 0.0, 0.5])
    assert total == pytest.approx(1.5)
    assert [unsaturated(m) for m in mu] == [False, False, True]


def test_membership_gradient_matches_finite_differences():
    """d mu / d c_l = N_l where unsaturated (the rules' chain rule relies on it)."""
    rng = np.random.default_rng(0)
    inp = BSplineInput("x", -2.0, 3.0, 3, 8, 3)
    C = inp.initial_control_points() * 0.8 + 0.05
    N, mu, mp, mm = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    for z in rng.uniform(-2, 3, 20):
        s = basis(z, inp.knots, 8, 3, N)
        memberships(C, N, s, 3, 3, mu)
        full = basis_matrix(np.array([z]), inp.knots, 3)[0]
        h = 1e-7
        for t in range(3):
            for l in range(8):
                Cp, Cm = C.copy(), C.copy()
                Cp[t, l] += h
                Cm[t, l] -= h
                memberships(Cp, N, s, 3, 3, mp)
                memberships(Cm, N, s, 3, 3, mm)
                fd = (mp[t] - mm[t]) / (2 * h)
                if 1e-6 < mu[t] < 1 - 1e-6:
                    assert unsaturated(mu[t])
                    assert full[l] == pytest.approx(fd, abs=1e-7)


def test_unimodal_projection_is_a_projection_with_peak_in_window():
    rng = np.random.default_rng(4)
    for _ in range(200):
        c = rng.uniform(-0.2, 1.2, 9)
        first, last = sorted(rng.integers(0, 9, 2))
        p = c.copy()
        project_unimodal(p, first, last)
        k = int(np.argmax(p))
        assert first <= k <= last or p[k] == p[first: last + 1].max()
        assert np.all(np.diff(p[: k + 1]) >= 0) and np.all(np.diff(p[k:]) <= 0)
        assert np.all(p <= c)                              # only lowers points
        again = p.copy()
        project_unimodal(again, first, last)
        np.testing.assert_array_equal(again, p)           # idempotent


def test_peak_windows_of_initial_sets_are_disjoint_and_ordered():
    knots = open_uniform_knots(-1.0, 1.0, 9, 3)
    w = peak_windows(triangle_control_points(knots, 3, 5))
    assert w[0, 0] == 0 and w[-1, 1] == 8
    assert np.all(w[1:, 0] == w[:-1, 1] + 1) and np.all(w[:, 0] <= w[:, 1])
