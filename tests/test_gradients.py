"""Every adaptive-law gradient against a finite difference of the quantity it differentiates."""

import numpy as np
import pytest

from tspend.bspline import BSplineInput
from tspend.compensator import FuzzyCompensator
from tspend.rules import RuleBase
from tspend.ts_model import TSModel

H = 1e-6


def _perturbed_inputs(rng, n_states=2):
    """Example-sized inputs with control points perturbed so no set saturates near z."""
    xs = tuple(BSplineInput(f"x{j}", -6.0, 6.0, 5, 9, 3) for j in range(n_states))
    return xs + (BSplineInput("u", -10.0, 10.0, 3, 7, 3),)


def _jitter(rules: RuleBase, rng):
    for C in rules.C:
        C[:] = np.clip(C + rng.uniform(0.02, 0.08, C.shape), 0.01, 0.97)


def _fd_control_points(rules: RuleBase, f, j):
    """Central differences of f() w.r.t. every control point of input j."""
    C = rules.C[j]
    out = np.zeros_like(C)
    for idx in np.ndindex(C.shape):
        old = C[idx]
        C[idx] = old + H
        fp = f()
        C[idx] = old - H
        fm = f()
        C[idx] = old
        out[idx] = (fp - fm) / (2 * H)
    return out


@pytest.mark.parametrize("n_states", [2, 3])
def test_model_control_point_gradient(n_states):
    rng = np.random.default_rng(n_states)
    model = TSModel(_perturbed_inputs(rng, n_states), b_min=0.01)
    model.initialise(rng, -1.0, 1.0)
    _jitter(model.rules, rng)
    for _ in range(3):
        z = np.append(rng.uniform(-5, 5, n_states), rng.uniform(-9, 9))
        v = rng.normal(size=n_states + 1)

        def y():
            fir, p = model.evaluate(z)
            return p @ v

        fir, _ = model.evaluate(z)
        grads = model.output_gradient_wrt_control_points(fir, v)
        for j in range(n_states + 1):
            np.testing.assert_allclose(grads[j], _fd_control_points(model.rules, y, j),
                                       atol=1e-8, rtol=1e-6)


def test_consequent_rate_is_gradient_of_model_output():
    rng = np.random.default_rng(1)
    model = TSModel(_perturbed_inputs(rng), b_min=0.01)
    model.initialise(rng, -1.0, 1.0)
    z, v = np.array([0.3, -1.2, 2.0]), rng.normal(size=3)
    fir, p = model.evaluate(z)
    e_delta, eta = 0.7, 0.3
    rate = model.consequent_rate(fir, v, e_delta, eta)
    fd = np.zeros_like(model.P)
    for idx in np.ndindex(model.P.shape):
        old = model.P[idx]
        model.P[idx] = old + H
        fp = model.evaluate(z)[1] @ v
        model.P[idx] = old - H
        fm = model.evaluate(z)[1] @ v
        model.P[idx] = old
        fd[idx] = (fp - fm) / (2 * H)
    np.testing.assert_allclose(rate, eta * e_delta * fd, atol=1e-9)


def test_control_point_rate_scales_gradient_and_first_type_is_zero():
    rng = np.random.default_rng(2)
    model = TSModel(_perturbed_inputs(rng), b_min=0.01)
    model.initialise(rng, -1.0, 1.0)
    z, v = np.array([1.0, 0.5, -3.0]), rng.normal(size=3)
    fir, _ = model.evaluate(z)
    g = model.output_gradient_wrt_control_points(fir, v)
    r = model.control_point_rates(fir, v, -0.4, 0.05)
    for gj, rj in zip(g, r):
        np.testing.assert_allclose(rj, -0.4 * 0.05 * gj)
    assert all(np.all(rj == 0) for rj in model.control_point_rates(fir, v, -0.4, 0.0))


def test_compensator_gradients():
    rng = np.random.default_rng(3)
    comp = FuzzyCompensator(BSplineInput("e", -12.0, 12.0, 5, 9, 3),
                            BSplineInput("x", 0.0, 1.05, 5, 9, 3))
    comp.initialise(rng, -0.5, 0.5)
    _jitter(comp.rules, rng)
    for e_delta, xn in [(0.7, 0.2), (-5.0, 0.9), (11.0, 0.5)]:
        def d_hat():
            return comp.evaluate(e_delta, xn)[1]

        fir, _, _ = comp.evaluate(e_delta, xn)
        # q part of (27): d d_hat / dq = tau
        fd_q = np.zeros_like(comp.q)
        for i in range(comp.q.size):
            old = comp.q[i]
            comp.q[i] = old + H
            fp = d_hat()
            comp.q[i] = old - H
            fm = d_hat()
            comp.q[i] = old
            fd_q[i] = (fp - fm) / (2 * H)
        np.testing.assert_allclose(comp.q_rate(fir, e_delta, 1.0), abs(e_delta) * fd_q, atol=1e-9)
        # membership part of (27): gamma |e_Delta| d d_hat / dc
        rates = comp.control_point_rates(fir, e_delta, 0.5)
        for j in range(2):
            fd = _fd_control_points(comp.rules, d_hat, j)
            np.testing.assert_allclose(rates[j], 0.5 * abs(e_delta) * fd, atol=1e-8, rtol=1e-6)


def test_firing_normalisation_guard_with_no_rule_firing():
    rules = RuleBase((BSplineInput("a", 0.0, 1.0, 3, 5, 3), BSplineInput("b", 0.0, 1.0, 3, 5, 3)))
    for C in rules.C:
        C[:] = 0.0          # nothing fires anywhere
    fir = rules.evaluate(np.array([0.5, 0.5]))
    assert np.all(np.isfinite(fir.w)) and fir.w.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(fir.w, 1.0 / 9.0)


def test_firing_strengths_sum_to_one_far_outside_intervals():
    rules = RuleBase((BSplineInput("a", -1.0, 1.0, 5, 9, 3), BSplineInput("b", 0.0, 2.0, 3, 7, 3)))
    for z in ([1e12, -1e12], [np.inf, -np.inf], [-3.0, 50.0]):
        fir = rules.evaluate(np.array(z, dtype=float))
        assert np.all(np.isfinite(fir.w)) and fir.w.sum() == pytest.approx(1.0)
