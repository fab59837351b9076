"""Every compiled adaptive law against a finite difference of the quantity it differentiates."""

import numpy as np
import pytest

from tspend.controllers.paper import rules
from tspend.controllers.paper.bspline import BSplineInput
from tspend.controllers.paper.compensator import (CompensatorSettings, compensator_law, estimate,
    sets_gradient)
from tspend.controllers.paper.rules import fire
from tspend.controllers.paper.ts_model import (ModelSettings, antecedent_gradient, antecedent_law,
    consequent_law, initial_consequents, model_output)

H = 1e-6


def _perturbed_inputs(n_states=2):
    xs = tuple(BSplineInput(f"x{j}", -6.0, 6.0, 5, 9, 3) for j in range(n_states))
    return xs + (BSplineInput("u", -10.0, 10.0, 3, 9, 3),)


def _jittered_points(inputs, rng):
    """Initial control points moved so that no set saturates near the test inputs."""
    C = rules.initial_control_points(inputs)
    return np.clip(C + rng.uniform(0.02, 0.08, C.shape), 0.01, 0.97)


def _fd(f, C):
    """Central differences of f() w.r.t. every entry of C (changed in place, restored)."""
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


def _model(n_states, rng, eta=0.3, eta_mu=0.05):
    inputs = _perturbed_inputs(n_states)
    s = ModelSettings(grid=rules.grid(inputs), eta=eta, eta_mu=eta_mu, b_min=-1e9, b_sign=1.0, norm_radius=0.0)
    P = initial_consequents(s, rng, n_states, -1.0, 1.0)
    return s, P, _jittered_points(inputs, rng), rules.firing(s.grid)


def _pv(s, P, C, f, z, v):
    f.z[:] = z
    fire(s.grid, C, f)
    p = np.empty(P.shape[1])
    model_output(f.w, P, p)
    return p @ v


@pytest.mark.parametrize("n_states", [2, 3])
def test_antecedent_law_follows_gradient_of_model_output(n_states):
    rng = np.random.default_rng(n_states)
    s, P, C, f = _model(n_states, rng)
    for _ in range(3):
        z = np.append(rng.uniform(-5, 5, n_states), rng.uniform(-9, 9))
        v = rng.normal(size=n_states + 1)
        e_delta, dt = -0.4, 1e-3
        fd = _fd(lambda: _pv(s, P, C, f, z, v), C)
        f.z[:] = z
        varpi = fire(s.grid, C, f)
        antecedent_gradient(s, P, v, f, varpi)
        moved = C.copy()
        antecedent_law(s, moved, f, e_delta, dt)
        np.testing.assert_allclose((moved - C) / (dt * s.eta_mu * e_delta), fd,
                                   atol=1e-7, rtol=1e-5)


def test_consequent_law_is_gradient_of_model_output():
    rng = np.random.default_rng(1)
    s, P, C, f = _model(2, rng)
    z, v = np.array([0.3, -1.2, 2.0]), rng.normal(size=3)
    fd = _fd(lambda: _pv(s, P, C, f, z, v), P)
    _pv(s, P, C, f, z, v)
    e_delta, dt = 0.7, 1e-3
    moved = P.copy()
    consequent_law(s, moved, f.w, v, e_delta, dt)
    np.testing.assert_allclose((moved - P) / dt, s.eta * e_delta * fd, atol=1e-8)


def test_projections_hold_after_the_consequent_law():
    rng = np.random.default_rng(2)
    inputs = _perturbed_inputs(2)
    s = ModelSettings(grid=rules.grid(inputs), eta=50.0, eta_mu=0.0, b_min=0.2, b_sign=1.0, norm_radius=0.5)
    P = initial_consequents(s, rng, 2, -1.0, 1.0)
    f = rules.firing(s.grid)
    f.z[:] = [0.1, 0.2, 0.3]
    fire(s.grid, rules.initial_control_points(inputs), f)
    consequent_law(s, P, f.w, np.array([1.0, -2.0, -5.0]), -3.0, 1.0)
    assert P[:, 2].min() == 0.2                             # Assumption 5
    assert np.linalg.norm(P[:, :2], axis=0).max() <= 0.5 * (1 + 1e-12)   # Assumption 4


@pytest.mark.parametrize("mode", ["sigma", "e"])
def test_compensator_laws(mode):
    rng = np.random.default_rng(3)
    inputs = (BSplineInput("e", -12.0, 12.0, 5, 9, 3), BSplineInput("x", 0.0, 1.05, 5, 9, 3))
    s = CompensatorSettings(grid=rules.grid(inputs), gamma=0.5, boundary_layer=0.0,
                            leakage=0.3, e_modification=mode == "e", adapt_sets=True)
    C = _jittered_points(inputs, rng)
    q = rng.uniform(-0.5, 0.5, 25)
    f = rules.firing(s.grid)
    dt = 1e-3

    def d_hat(z):
        f.z[:] = z
        fire(s.grid, C, f)
        return estimate(f.w, q)

    for e_delta, xn in [(0.7, 0.2), (-5.0, 0.9), (11.0, 0.5)]:
        z = (e_delta, xn)
        fd_q = _fd(lambda: d_hat(z), q)
        fd_c = _fd(lambda: d_hat(z), C)
        d_hat(z)
        varpi = fire(s.grid, C, f)
        sets_gradient(s, q, f, varpi)
        q_new, C_new = q.copy(), C.copy()
        compensator_law(s, q_new, C_new, f, e_delta, dt)
        # (27): gamma (|e_Delta| d d_hat/dq - leakage), leakage sigma q or sigma |e_Delta| q
        scale = abs(e_delta) if mode == "e" else 1.0
        expected = s.gamma * (abs(e_delta) * fd_q - s.leakage * scale * q)
        np.testing.assert_allclose((q_new - q) / dt, expected, atol=1e-8)
        # membership part: gamma |e_Delta| d d_hat / dc
        np.testing.assert_allclose((C_new - C) / dt, s.gamma * abs(e_delta) * fd_c,
                                   atol=1e-7, rtol=1e-5)


def test_firing_normalisation_guard_with_no_rule_firing():
    inputs = (BSplineInput("a", 0.0, 1.0, 3, 5, 3), BSplineInput("b", 0.0, 1.0, 3, 5, 3))
    g, f = rules.grid(inputs), None
    f = rules.firing(g)
    f.z[:] = 0.5
    fire(g, np.zeros((2, 3, 5)), f)                     # nothing fires anywhere
    assert np.all(np.isfinite(f.w)) and f.w.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(f.w, 1.0 / 9.0)


def test_firing_strengths_sum_to_one_far_outside_intervals():
    inputs = (BSplineInput("a", -1.0, 1.0, 5, 9, 3), BSplineInput("b", 0.0, 2.0, 3, 9, 3))
    g = rules.grid(inputs)
    f = rules.firing(g)
    for z in ([1e12, -1e12], [np.inf, -np.inf], [-3.0, 50.0]):
        f.z[:] = z
        fire(g, rules.initial_control_points(inputs), f)
        assert np.all(np.isfinite(f.w)) and f.w.sum() == pytest.approx(1.0)
