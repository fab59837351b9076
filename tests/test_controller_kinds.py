"""The baseline controller kinds against independent checks (issue 11).

* LQR: the gain equals R^-1 B^T P with P from scipy's Riccati solver on a linearisation
  derived by hand, and A - B K is Hurwitz;
* the oracle (feedback linearisation) without disturbance beats every adaptive kind on
  each analytic plant, and on the cart-pole ODE at 1 ms its rmse_ss is below 1e-4 rad;
  its Newton solution equals scipy's brentq root;
* sliding mode reaches its boundary layer and stays in it;
* wang_indirect's laws equal finite-difference gradients of its Lyapunov terms;
* [controllers.KIND] tables: validated with one-line errors, exit 2.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import solve_continuous_are, solve_continuous_lyapunov
from scipy.optimize import brentq

from tspend import load_scenario, override, run
from tspend.cli.main import main
from tspend.controllers import KINDS
from tspend.loop.simulation import build_controller
from tspend.controllers.base import Controller, check_diagnostics
from tspend.controllers.feedback_linearization import solve_for_u
from tspend.controllers.gaussian_basis import basis, gaussian_grid
from tspend.controllers.plant_model import plant_model
from tspend.loop.simulation import nominal_machine
from tspend.runtime.errors import ScenarioError
from tspend.loop.metrics import METRIC_KEYS


def build(scenario, kind):
    """The kind as the runner builds it: designed on the nominal machine."""
    return build_controller(scenario, kind=kind)


BASELINES = ("pd", "lqr", "feedback_linearization", "sliding_mode", "wang_indirect",
             "swingup", "mpc", "policy", "excited", "tvlqr")
ADAPTIVE = ("second_type", "first_type", "wang_indirect")


def _hand_linearisation(scenario):
    """(a, b) of each plant at the origin / upright, differentiated by hand."""
    kind = scenario.plant.kind
    if kind == "nonaffine":   # 0.2 (1 + e^0)(2 + sin 0)(1 + e^0) at the origin; f_x = 0 there
        return np.zeros(2), 0.2 * 2 * 2 * 2
    if kind == "duffing":
        return np.array([0.0, -0.1]), 1.0
    if kind == "third_order":
        return np.array([-1.0, -2.0, -1.5]), (1.5 + 1.0) * 1.2
    p = scenario.plant        # cart-pole: theta'' ~ ((M+m) g theta + u) / (4/3 l (M+m) - m l)
    # a MuJoCo scenario's 0 keeps models/cartpole.xml's own M = 10, m = 1, l = 3, g = 9.8
    M, m, l, g = (p.M or 10.0), (p.m or 1.0), (p.l or 3.0), (p.g or 9.8)
    den = 4.0 / 3.0 * l * (M + m) - m * l
    return np.array([(M + m) * g / den, 0.0]), 1.0 / den


@pytest.mark.parametrize("name", ["ex1_nonaffine_case1", "ex2_duffing", "ex3_pendulum_ode",
                                  "pendulum_mujoco", "third_order"])
def test_lqr_gain_is_the_riccati_gain_and_closed_loop_is_hurwitz(name):
    s = load_scenario(name)
    if name in ("ex3_pendulum_ode", "pendulum_mujoco"):   # the paper's 2-state view
        s = override(s, **{"controllers.lqr.design": "view"})
    ctrl = build(s, "lqr")
    a, b = _hand_linearisation(s)
    n = a.size
    A = np.eye(n, k=1)
    A[-1] = a
    B = np.zeros((n, 1))
    B[-1, 0] = b
    np.testing.assert_allclose(ctrl.A, A, atol=1e-7)
    np.testing.assert_allclose(ctrl.B, B, rtol=1e-8)
    Q, R = ctrl.Q, ctrl.R
    P = solve_continuous_are(A, B, Q, np.array([[R]]))
    np.testing.assert_allclose(ctrl.K, (B.T @ P / R)[0], rtol=1e-6)
    assert np.linalg.eigvals(A - B @ ctrl.K[None, :]).real.max() < 0.0
    # P is also the Lyapunov matrix of the closed loop: (A-BK)^T P + P (A-BK) = -(Q + K^T R K)
    Acl = ctrl.closed_loop()
    Pl = solve_continuous_lyapunov(Acl.T, -(Q + R * np.outer(ctrl.K, ctrl.K)))
    np.testing.assert_allclose(ctrl.P, Pl, rtol=1e-6)


def test_lqr_weights_come_from_the_table():
    s = load_scenario("ex2_duffing")
    assert build(s, "lqr").Q[0, 0] == 1e4             # the shipped [controllers.lqr] table
    s2 = override(s, **{"controllers.lqr.R": 0.5})
    assert build(s2, "lqr").R == 0.5
    ex3_view = override(load_scenario("ex3_pendulum_ode"), **{"controllers.lqr.design": "view"})
    assert build(ex3_view, "lqr").R == pytest.approx(
        1.0 / _hand_linearisation(load_scenario("ex3_pendulum_ode"))[1] ** 2)


def _on_reference(name, duration):
    """The scenario without disturbance, starting on the reference (e(0) = 0), so that what
    remains is model error and the sample-and-hold, not the transient lambda sets."""
    s = load_scenario(name)
    n = len(s.plant.x0)
    x0 = s.reference.derivatives(np.zeros(1), n - 1)[0]
    return override(s, **{"disturbance.amplitude": 0.0, "plant.x0": [float(v) for v in x0],
                           "run.duration": duration})


@pytest.mark.parametrize("name", ["ex1_nonaffine_case1", "ex1_nonaffine_case2", "ex2_duffing",
                                  "ex3_pendulum_ode", "third_order"])
def test_oracle_beats_every_adaptive_kind_without_disturbance(name):
    s = _on_reference(name, 4.0)
    oracle = run(s, controller="feedback_linearization", keep_history=False).metrics
    for kind in ADAPTIVE:
        m = run(s, controller=kind, keep_history=False).metrics
        assert oracle["rmse_ss"] < m["rmse_ss"], (kind, oracle["rmse_ss"], m["rmse_ss"])
        assert oracle["max_abs_e"] < m["max_abs_e"], kind


def test_oracle_on_the_cartpole_ode_at_1ms():
    s = override(load_scenario("ex3_pendulum_ode"), **{"disturbance.amplitude": 0.0})
    assert s.run.dt == 0.001 and s.run.duration == 20.0
    r = run(s, controller="feedback_linearization")
    assert r.status == "completed"
    assert r.metrics["rmse_ss"] < 1e-4, r.metrics
    assert np.abs(r.history["residual"]).max() < 1e-9     # closed form: exact up to rounding


def test_oracle_newton_equals_a_bracketing_root_finder():
    s = load_scenario("ex1_nonaffine_case2")
    model = plant_model(s, nominal_machine(s))
    rng = np.random.default_rng(3)
    for _ in range(20):
        x, v = rng.uniform(-1.5, 1.5, 2), rng.uniform(-5, 5)
        u, its, res = solve_for_u(model, 0.0, x, v, rng.uniform(-2, 2), 1e-13, 50)
        ref = brentq(lambda w: model.f(0.0, x, w) - v, -50.0, 10.0, xtol=1e-14)
        assert u == pytest.approx(ref, abs=1e-10) and its >= 1 and abs(res) < 1e-11


@pytest.mark.parametrize("name", ["ex3_pendulum_ode", "ex2_duffing", "ex1_nonaffine_case1"])
def test_sliding_mode_reaches_its_boundary_layer_and_stays(name):
    s = override(load_scenario(name), **{"run.duration": 6.0})
    r = run(s, controller="sliding_mode")
    assert r.status == "completed"
    ctrl, h = r.controller, r.history
    # s recomputed from the runner's own e, independently of the controller's diag
    s_e = h["e"] @ ctrl.c
    np.testing.assert_allclose(h["s"], s_e, atol=1e-12)
    inside = np.abs(s_e) <= ctrl.phi
    assert not inside[0]                       # starts outside: there is a reaching phase
    first = int(np.argmax(inside))
    assert inside[first:].all(), "left the boundary layer"
    assert first * s.run.dt < 2.0


def test_wang_laws_are_gradients_of_the_lyapunov_cross_term():
    s = load_scenario("ex3_pendulum_ode")
    ctrl = build(s, "wang_indirect")
    ctrl.reset(np.random.default_rng(0))
    rng = np.random.default_rng(5)
    ctrl.theta_f[:] = rng.normal(size=ctrl.theta_f.size)
    ctrl.theta_g[:] = rng.uniform(0.01, 0.05, ctrl.theta_g.size)
    e = rng.normal(scale=0.1, size=2)
    x = rng.uniform(-0.5, 0.5, 2)
    xi = basis(ctrl.grid, x)
    P = solve_continuous_lyapunov(ctrl_companion(ctrl.lam).T, -ctrl.Q)
    e_delta = float(e @ P[:, -1])
    u_c = 3.7
    dtf, dtg = ctrl.rates(e_delta, xi, u_c)

    # C(theta) = e^T P b [f_hat(theta_f) + g_hat(theta_g) u_c]: the part of V' that the
    # parameter terms must cancel; the law is theta' = gamma dC/dtheta
    def C(tf, tg):
        return e_delta * (tf @ basis(ctrl.grid, x) + (tg @ basis(ctrl.grid, x)) * u_c)

    h = 1e-3  # C is linear in theta: no truncation error, and rounding stays small
    for theta, rate, gamma, which in ((ctrl.theta_f, dtf, ctrl.gamma_f, 0),
                                      (ctrl.theta_g, dtg, ctrl.gamma_g, 1)):
        fd = np.zeros_like(theta)
        for i in range(theta.size):
            tp, tm = theta.copy(), theta.copy()
            tp[i] += h
            tm[i] -= h
            args_p = (tp, ctrl.theta_g) if which == 0 else (ctrl.theta_f, tp)
            args_m = (tm, ctrl.theta_g) if which == 0 else (ctrl.theta_f, tm)
            fd[i] = (C(*args_p) - C(*args_m)) / (2 * h)
        np.testing.assert_allclose(rate, gamma * fd, rtol=1e-6, atol=1e-10)


def ctrl_companion(lam):
    A = np.eye(lam.size, k=1)
    A[-1] = -lam
    return A


def test_wang_lyapunov_derivative_is_minus_half_eQe_on_a_representable_plant():
    """With f = theta_f*^T xi, g = theta_g*^T xi, no disturbance and no supervisor, the
    laws make V' = -1/2 e^T Q e exactly; V' by finite differences along the flow."""
    s = load_scenario("ex3_pendulum_ode")
    ctrl = build(s, "wang_indirect")
    rng = np.random.default_rng(11)
    h_rules = ctrl.theta_f.size
    tf_star, tg_star = rng.normal(size=h_rules), rng.uniform(0.02, 0.04, h_rules)
    tf, tg = rng.normal(size=h_rules), rng.uniform(0.02, 0.04, h_rules)
    P, Q, lam = ctrl.P, ctrl.Q, ctrl.lam
    A = ctrl_companion(lam)
    for _ in range(5):
        x, e = rng.uniform(-0.5, 0.5, 2), rng.normal(scale=0.1, size=2)
        r_n = rng.normal()
        xi = basis(ctrl.grid, x)
        u_c = (-(tf @ xi) + r_n - lam @ e) / (tg @ xi)
        e_dot = A @ e + np.array([0.0, (tf_star - tf) @ xi + ((tg_star - tg) @ xi) * u_c])
        e_delta = float(e @ P[:, -1])
        tf_dot, tg_dot = ctrl.rates(e_delta, xi, u_c)

        def V(e_, tf_, tg_):
            return (0.5 * e_ @ P @ e_ + (tf_star - tf_) @ (tf_star - tf_) / (2 * ctrl.gamma_f)
                    + (tg_star - tg_) @ (tg_star - tg_) / (2 * ctrl.gamma_g))

        eps = 1e-7
        V_dot = (V(e + eps * e_dot, tf + eps * tf_dot, tg + eps * tg_dot)
                 - V(e - eps * e_dot, tf - eps * tf_dot, tg - eps * tg_dot)) / (2 * eps)
        assert V_dot == pytest.approx(-0.5 * e @ Q @ e, rel=1e-5, abs=1e-10)


def test_gaussian_basis_is_a_partition_of_unity_on_the_grid():
    s = load_scenario("ex3_pendulum_ode")
    grid = gaussian_grid(s.controller.state_sets)
    xi = basis(grid, np.array([0.1, -0.3]))
    assert xi.size == 25 and xi.min() > 0 and xi.sum() == pytest.approx(1.0)
    # at a grid node the rule centred there fires most; product of Gaussians by hand
    c0, c1 = grid.centres[0][1], grid.centres[1][3]
    xi = basis(grid, np.array([c0, c1]))
    assert int(np.argmax(xi)) == 1 * 5 + 3
    mu = [np.exp(-((c0 - grid.centres[0]) / grid.sigma[0]) ** 2),
          np.exp(-((c1 - grid.centres[1]) / grid.sigma[1]) ** 2)]
    g = np.outer(*mu).ravel()
    np.testing.assert_allclose(xi, g / g.sum(), rtol=1e-12)


def test_wang_projection_keeps_g_hat_away_from_zero():
    s = override(load_scenario("ex3_pendulum_ode"), **{"run.duration": 3.0})
    r = run(s, controller="wang_indirect")
    assert r.status == "completed"
    g_min = r.scenario.controller.b_min
    assert r.history["min_theta_g"].min() >= g_min
    assert r.history["g_hat"].min() >= g_min * (1 - 1e-12)


def test_wang_supervisor_acts_only_above_V_bar():
    # bounds that hold for the cart-pole on |theta| <= 0.3: |f| <= 1, 0.02 <= g <= 0.03
    s = override(load_scenario("ex3_pendulum_ode"), **{
        "run.duration": 2.0, "controllers.wang_indirect.supervisory": True,
        "controllers.wang_indirect.f_upper": 1.0, "controllers.wang_indirect.g_upper": 0.03,
        "controllers.wang_indirect.g_lower": 0.02, "controllers.wang_indirect.V_bar": 0.01})
    r = run(s, controller="wang_indirect")
    assert r.status == "completed", r.end.message
    h = r.history
    on = h["u_s"] != 0.0
    assert on.any() and (~on).any()
    assert (h["V"][on] > 0.01).all() and ((h["V"][~on] <= 0.01) | (h["e_delta"][~on] == 0)).all()
    # u_s opposes e_Delta
    assert (np.sign(r.history["u_s"][on]) == -np.sign(r.history["e_delta"][on])).all()


@pytest.mark.parametrize("kind", BASELINES)
def test_every_kind_runs_with_named_diagnostics_and_the_same_metrics(kind):
    s = override(load_scenario("pendulum_mujoco"), **{"run.duration": 0.3})
    r = run(s, controller=kind)
    assert isinstance(r.controller, Controller) and r.controller.kind == kind
    check_diagnostics(r.controller.diagnostics, r.controller.diag)
    assert r.status == "completed" and set(METRIC_KEYS) <= set(r.metrics)
    for d in r.controller.diagnostics:
        assert r.history[d.name].shape[0] == 300, d.name
        assert np.all(np.isfinite(r.history[d.name])), d.name


def test_pd_is_the_error_feedback_law():
    s = override(load_scenario("ex2_duffing"), **{"run.duration": 0.2,
                                                   "controllers.pd.gains": [30.0, 11.0],
                                                   "controllers.pd.b0": 2.0})
    h = run(s, controller="pd").history
    u = (h["ref"][:, 2] - h["e"] @ np.array([30.0, 11.0])) / 2.0
    np.testing.assert_allclose(h["u"], u, rtol=1e-12, atol=1e-12)


def test_mujoco_model_uses_the_scenarios_machine():
    s = override(load_scenario("pendulum_mujoco"), **{"plant.M": 5.0, "plant.l": 1.0})
    a, b = plant_model(s, nominal_machine(s)).linearisation()
    a_ref, b_ref = _hand_linearisation(s)
    np.testing.assert_allclose(a, a_ref, rtol=1e-7)
    assert b == pytest.approx(b_ref, rel=1e-8)


@pytest.mark.parametrize("key, value, expect", [
    ("controllers.lqr.RR", 1.0, "controllers.lqr.RR: unknown key (did you mean 'R'?); allowed for kind 'lqr': Q, R, design"),
    ("controllers.nope.k", 1.0, "controllers.nope: unknown controller kind; allowed: pd, lqr"),
    ("controllers.pd.gains", [1.0], "controllers.pd.gains: must have 2 entries"),
    ("controllers.lqr.Q", [[1.0, 2.0], [2.0, 1.0]], "controllers.lqr.Q: must be positive definite"),
    ("controllers.lqr.R", -1.0, "controllers.lqr.R: must be > 0"),
    ("controllers.sliding_mode.nominal", "exact", "'exact' is not allowed"),
    ("controllers.feedback_linearization.lambda", [-1.0, 2.0], "must be Hurwitz"),
    ("controllers.wang_indirect.supervisory", 1, "must be true or false"),
    ("controllers.wang_indirect.sets", [{"terms": 3, "lo": 1.0, "hi": 0.0}] * 2, "sets[0].lo"),
    ("controllers.first_type.eta", 1.0, "settings live in [controller]"),
])
def test_bad_tables_are_one_line_errors(key, value, expect):
    with pytest.raises(ScenarioError) as exc:
        override(load_scenario("ex3_pendulum_ode"), **{key: value})
    msg = str(exc.value)
    assert "\n" not in msg and "ex3_pendulum_ode.toml" in msg and expect in msg, msg


def test_cli_unknown_kind_and_key_exit_2(capsys):
    assert main(["run", "ex2_duffing", "--controller", "nope", "--no-record"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and all(k in err[0] for k in KINDS)
    assert main(["run", "ex2_duffing", "--controller", "lqr", "--no-record",
                 "--set", "controllers.lqr.S=1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "allowed for kind 'lqr': Q, R, design" in err[0]


def test_every_baseline_has_settings_and_defaults_documented():
    settings = {k: c.Settings for k, c in KINDS.items() if k not in ("second_type", "first_type")}
    assert set(settings) == set(BASELINES) and set(BASELINES) < set(KINDS)
    for kind, cls in settings.items():
        assert cls.__doc__ and f"[controllers.{kind}]" in cls.__doc__
        for f in cls.__dataclass_fields__.values():
            assert f.metadata.get("doc"), (kind, f.name)


def test_a_baselines_diagnostics_are_recorded_by_name(tmp_path):
    from tspend.recorder import (RerunSink, close_recording, open_recording,
                                 read_scalar_series, series_location)

    s = override(load_scenario("ex2_duffing"), **{"run.duration": 0.5})
    rrd = tmp_path / "smc.rrd"
    rec = open_recording("tspend_test_kinds", path=rrd)
    r = run(s, controller="sliding_mode", sinks=[RerunSink(rec)])
    close_recording(rec)
    diags = r.controller.diagnostics
    for name in ("s", "u_sw", "u_eq"):
        entity, instance = series_location(name, 2, (), diagnostics=diags)
        t, values = read_scalar_series(rrd, entity, instance)
        np.testing.assert_array_equal(values, r.history[name])
        np.testing.assert_allclose(t, r.history["t"], atol=1e-12)


@pytest.mark.parametrize("kind", ["lqr", "sliding_mode"])
def test_model_based_kinds_assume_the_compiled_machine(kind: str) -> None:
    """On an MJCF whose hinge axis is reversed, the nominal model is read back from the
    compiled model (its gain sign included), so the baselines still balance the pole."""
    scenario = override(load_scenario("pendulum_mujoco"), **{
        "run.duration": 6.0, "plant.model": "tests/models/cartpole_reversed.xml"})
    with pytest.warns(Warning, match="reversed gain sign"):
        result = run(scenario, controller=kind, keep_history=False)
    assert result.status == "completed"
    if kind == "lqr":
        # the full-state design's slow cart mode is still settling at 6 s: the reversed
        # machine must behave exactly as the normal one
        normal = run(override(scenario, **{"plant.model": "models/cartpole.xml"}),
                     controller=kind, keep_history=False)
        assert result.metrics["rmse_ss"] == pytest.approx(normal.metrics["rmse_ss"], rel=1e-9)
        assert result.metrics["rmse_ss"] < 0.02
    else:
        assert result.metrics["rmse_ss"] < 1e-3
