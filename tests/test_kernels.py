"""The compiled controller against the numpy oracle (tests/oracles), step by step.

Both controllers start from the same draw (``initialise`` with the same seed) and see the
same random-but-smooth states and references (with a few samples far outside every
input interval); the diagnostics and every adapted parameter must agree to rounding at
every one of 2000 steps.
"""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit
from oracles.numpy_controller import NumpyController

from tspend.config import ControllerConfig, SetSpec
from tspend.controllers.paper.controller import AdaptiveFuzzyController, diag_layout, make_controller

RTOL, ATOL = 1e-10, 1e-12
STEPS = 2000

_N3 = dict(
    lam=(1.0, 3.0, 3.0),
    Q=((10.0, 0.0, 0.0), (0.0, 10.0, 0.0), (0.0, 0.0, 10.0)),
    state_sets=(SetSpec(5, -1.0, 1.0), SetSpec(3, -2.0, 2.0), SetSpec(5, -1.5, 1.5)),
    adaptation="first",
    boundary_layer=0.05,
    leakage=0.1,
    norm_radius=1.0,
)

CONFIGS = {
    "example3": ControllerConfig(),
    "n3_first_fixed": ControllerConfig(**_N3, operating_point="fixed"),
    "n3_first_state": ControllerConfig(**_N3, operating_point="state"),
    # second type at n = 3, a nonzero fixed operating point, cubic B-splines, 7 points
    "n3_second_fixed_offset": ControllerConfig(
        **{**_N3, "adaptation": "second", "norm_radius": 0.0}, operating_point="fixed",
        x_o=(0.1, -0.2, 0.05), u_o=3.0, bspline_order=4, control_points=7),
    # Example 3 with fast laws and every robust option, so that projections act
    "example3_fast_robust": ControllerConfig(
        eta=0.5, eta_mu=2.0, gamma=1.6, boundary_layer=0.1, leakage=0.05, norm_radius=0.3,
        init_consequents=(-0.1, 0.1), init_compensator=(-0.25, 0.25)),
    # Narendra's e-modification in place of the sigma-modification
    "with_e_modification": ControllerConfig(
        eta=0.5, eta_mu=2.0, gamma=1.6, leakage=0.5, leakage_mode="e",
        init_consequents=(-0.1, 0.1), init_compensator=(-0.25, 0.25)),
}


def _signals(cfg: ControllerConfig, seed: int, steps: int = STEPS, dt: float = 1e-3):
    """Smooth random states (n,) and references (n+1,) per step, a few far outside."""
    rng = np.random.default_rng(seed)
    n = cfg.order
    t = np.arange(steps) * dt
    scale = np.array([max(abs(s.lo), abs(s.hi)) for s in cfg.state_sets])

    def smooth(width: int, amp: np.ndarray) -> np.ndarray:
        f = rng.uniform(0.2, 6.0, size=(3, width))
        ph = rng.uniform(0.0, 2 * np.pi, size=(3, width))
        a = rng.uniform(0.1, 0.5, size=(3, width))
        return amp * np.einsum("kw,tkw->tw", a, np.sin(f * t[:, None, None] + ph))

    X = smooth(n, scale)
    # the state roughly tracks the reference, as in closed loop: a large persistent
    # error makes the compensator's set law (27) amplify rounding by orders of magnitude
    # in the reference implementation itself, which no tolerance on rounding survives
    R = smooth(n + 1, np.append(0.05 * scale, 1.0))
    R[:, :n] += X
    far = rng.choice(np.arange(10, steps), size=12, replace=False)
    X[far] = rng.choice([-1.0, 1.0], size=(far.size, n)) * rng.uniform(3, 30, (far.size, 1)) * scale
    R[far[:6]] = rng.uniform(-50.0, 50.0, size=(6, n + 1))
    return X, R


def _compare(a: NumpyController, b: AdaptiveFuzzyController, k: int) -> None:
    layout = diag_layout(a.n)
    for key, where in layout.items():
        np.testing.assert_allclose(b.diag[where], a.diag[where], rtol=RTOL, atol=ATOL,
                                   err_msg=f"diag {key} at step {k}")
    pa, pb = a.parameters(), b.parameters()
    assert pa.keys() == pb.keys()
    for key in pa:
        np.testing.assert_allclose(pb[key], pa[key], rtol=RTOL, atol=ATOL,
                                   err_msg=f"parameter {key} at step {k}")
    assert b.u_prev == pytest.approx(a.u_prev, rel=RTOL, abs=ATOL)


def _pair(cfg: ControllerConfig, seed: int):
    a = NumpyController(cfg)
    b = make_controller(cfg)
    a.initialise(np.random.default_rng(seed))
    b.reset(np.random.default_rng(seed))
    _compare(a, b, -1)
    return a, b


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_kernel_matches_numpy_every_step(name: str) -> None:
    cfg = CONFIGS[name]
    seed = 7 + sorted(CONFIGS).index(name)
    a, b = _pair(cfg, seed)
    X, R = _signals(cfg, seed)
    dt = 1e-3
    n = cfg.order
    b_cols, col_norms = [], []
    for k in range(STEPS):
        ua = a.step(X[k], R[k], dt)
        ub = b.sample(X[k], R[k], dt)
        assert isinstance(ub, float)
        assert ub == pytest.approx(ua, rel=RTOL, abs=ATOL), f"u at step {k}"
        _compare(a, b, k)
        b_cols.append(a.model.P[:, n].min())
        col_norms.append(np.linalg.norm(a.model.P, axis=0).max())
    assert np.all(np.isfinite(a.diag))
    # the runs exercised what they were meant to
    assert np.min(b_cols) == cfg.b_min                    # Assumption 5 projection acted
    if cfg.norm_radius > 0.0:
        # Assumption 4 acted (the b_min projection after it may lift the last column)
        assert np.max(col_norms) >= cfg.norm_radius * (1.0 - 1e-9)
    if cfg.antecedent_rate > 0.0:
        init = NumpyController(cfg)
        assert not np.allclose(init.model.rules.C_all, a.model.rules.C_all)
    if cfg.leakage > 0.0:
        # the leakage term acted: q differs from the same run without it
        c = NumpyController(ControllerConfig(**{**cfg.__dict__, "leakage": 0.0}))
        c.initialise(np.random.default_rng(seed))
        for k in range(STEPS):
            c.step(X[k], R[k], dt)
        assert not np.allclose(c.compensator.q, a.compensator.q, rtol=1e-6)


def test_non_contiguous_inputs_and_snapshot() -> None:
    cfg = CONFIGS["example3"]
    a, b = _pair(cfg, 3)
    X, R = _signals(cfg, 3, steps=50)
    Xf, Rf = np.asfortranarray(X), np.asfortranarray(R)   # rows are strided views
    for k in range(50):
        a.step(X[k], R[k], 1e-3)
        b.sample(Xf[k], Rf[k], 1e-3)
        _compare(a, b, k)
    fa, sb = a.last_firing(X[-1]), b.snapshot(0.05, 50, X[-1])
    np.testing.assert_allclose(sb.firing, fa[0].w, rtol=RTOL, atol=ATOL)
    np.testing.assert_allclose(sb.compensator_firing, fa[1].w, rtol=RTOL, atol=ATOL)
    # reset forgets the previous control (state-following operating point) and the sets
    b.reset(np.random.default_rng(3))
    assert b.u_prev == 0.0
    np.testing.assert_array_equal(b.parameters()["C_model0"], NumpyController(cfg).model.rules.C[0])


def test_last_firing_matches_numpy_reference():
    """Snapshots read the compiled workspace: same memberships and firing as numpy's."""
    cfg = ControllerConfig()
    a, b = NumpyController(cfg), make_controller(cfg)
    a.initialise(np.random.default_rng(5))
    b.reset(np.random.default_rng(5))
    rng = np.random.default_rng(6)
    for _ in range(50):
        x, ref = rng.normal(0, 0.2, 2), rng.normal(0, 0.2, 3)
        a.step(x, ref, 1e-3)
        b.sample(x, ref, 1e-3)
        for fa, fb in zip(a.last_firing(x), b.last_firing(x)):
            np.testing.assert_allclose(fa.z, fb.z, atol=1e-12)
            np.testing.assert_allclose(fa.w, fb.w, atol=1e-12)
            for ma, mb in zip(fa.mu, fb.mu):
                np.testing.assert_allclose(ma, mb, atol=1e-12)
        sb = b.snapshot(0.0, 0, x)
        np.testing.assert_allclose(sb.firing, a.last_firing(x)[0].w, atol=1e-12)
        grid, curves = sb.model_sets[2][:2]
        np.testing.assert_allclose(curves, a.model.rules.curves(2, grid.size)[1], atol=1e-10)


@njit
def _closed_loop_samples(step, settings, state, scratch, X, R, dt, diag, out):
    for k in range(X.shape[0]):
        out[k] = step(settings, state, scratch, 0.0, X[k], X[k], R[k], dt, diag)


def test_compiled_entry_from_a_numba_loop_matches_step():
    """``controller.compiled()`` called from an @njit loop gives Controller.step's u and state."""
    cfg = CONFIGS["example3_fast_robust"]
    a, b = make_controller(cfg), make_controller(cfg)
    a.reset(np.random.default_rng(11))
    b.reset(np.random.default_rng(11))
    X, R = _signals(cfg, 11, steps=300)
    ua = np.array([a.sample(X[k], R[k], 1e-3) for k in range(300)])
    ub = np.empty(300)
    c = b.compiled()
    _closed_loop_samples(c.step, c.settings, c.state, c.scratch, X, R, 1e-3, b.diag, ub)
    np.testing.assert_array_equal(ub, ua)
    np.testing.assert_array_equal(b.diag, a.diag)
    for key, value in a.parameters().items():
        np.testing.assert_array_equal(b.parameters()[key], value, err_msg=key)


def test_configuration_sizes_come_from_the_config():
    b2 = make_controller(ControllerConfig())
    b3 = make_controller(CONFIGS["n3_first_state"])
    assert b2.state.P.shape == (75, 3) and b3.state.P.shape == (5 * 3 * 5 * 3, 4)
    assert b3.settings.model.grid.term_index.shape == (225, 4)
    assert b3.scratch.compensator.w.shape == (25,)
