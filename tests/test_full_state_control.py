"""Issue 20: controlling the whole machine, against independent checks.

* full-state LQR: the gain is R^-1 B^T P with P from scipy's Riccati solver (the kind uses
  python-control's ``control.lqr``), on A, B from the cart-pole's equations derived by
  hand; on the paper's MuJoCo case it holds the cart within 3 m over 20 s;
* MPC: the rail and the actuator's range hold in every predicted trajectory and in the
  simulated one;
* swing-up: the energy rate the model gives for the applied force is never negative
  before the catch, the sampled energy never falls by more than the hold's rounding,
  and the pole ends up upright;
* sampled control: the zero-order hold and the delay against a hand-computed sequence;
* machine metrics: joints, plant parameters, saturation, compute time, flattening;
* bad settings: one line, exit 2.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import solve_continuous_are

from tspend import load_scenario, override, run
from tspend.cli.main import main
from tspend.loop.simulation import build_controller
from tspend.controllers.base import Controller, Observation
from tspend.controllers.full_model import full_model, wrap_angle
from tspend.loop.simulation import nominal_machine
from mpc_plans import run_keeping_plans
from tspend.loop.metrics import flatten
from loop_harness import ZOH_CASES, sampled_run


def build(scenario, kind):
    """The kind as the runner builds it: designed on the nominal machine."""
    return build_controller(scenario, kind=kind)


def _hand_AB(M=10.0, m=1.0, l=3.0, g=9.8):
    """The cart-pole linearised at the upright, from (C1)-(C2) by hand (J = 4/3 m l^2):
    det = (M+m) J - (m l)^2; theta'' = ((M+m) m g l theta + m l u) / det,
    x'' = (J u + (m l)^2 g theta) / det."""
    J = 4.0 / 3.0 * m * l * l
    det = (M + m) * J - (m * l) ** 2
    A = np.zeros((4, 4))
    A[0, 2] = A[1, 3] = 1.0
    A[2, 1] = (m * l) ** 2 * g / det
    A[3, 1] = (M + m) * m * g * l / det
    B = np.array([[0.0], [0.0], [J / det], [m * l / det]])
    return A, B


@pytest.mark.parametrize("name", ["ex3_pendulum_ode", "pendulum_mujoco"])
def test_full_lqr_gain_is_scipys_riccati_gain(name):
    ctrl = build(load_scenario(name), "lqr")
    A, B = _hand_AB()
    np.testing.assert_allclose(ctrl.A, A, atol=1e-7)
    np.testing.assert_allclose(ctrl.B, B, rtol=1e-7, atol=1e-12)
    P = solve_continuous_are(A, B, ctrl.Q, np.array([[ctrl.R]]))
    np.testing.assert_allclose(ctrl.K, (B.T @ P / ctrl.R)[0], rtol=1e-6)
    np.testing.assert_allclose(ctrl.P, P, rtol=1e-6)
    assert np.linalg.eigvals(ctrl.closed_loop()).real.max() < 0.0


def test_full_lqr_feedforward_makes_the_sine_exact_on_the_linear_model():
    # for r = a sin(w t) the reference state s_r and u_r solve s_r' = A s_r + B u_r
    ctrl = build(load_scenario("ex3_pendulum_ode"), "lqr")
    a, w = 0.1, ctrl.omega
    for t in (0.0, 0.7, 2.0):
        row = lambda t: np.array([a * np.sin(w * t), a * w * np.cos(w * t), -a * w * w * np.sin(w * t)])
        s_r, u_r = ctrl.reference_state(row(t))
        h = 1e-6
        ds = (ctrl.reference_state(row(t + h))[0] - ctrl.reference_state(row(t - h))[0]) / (2 * h)
        np.testing.assert_allclose(ds, ctrl.A @ s_r + ctrl.B[:, 0] * u_r, atol=1e-7)


def test_full_lqr_holds_the_cart_on_the_paper_case():
    r = run(load_scenario("pendulum_mujoco"), controller="lqr")
    assert r.status == "completed", r.end.message
    assert r.metrics["joints"]["slider"]["max_abs"] <= 3.0
    assert r.metrics["rmse_ss"] < 1e-3


def test_mpc_constraints_hold_predicted_and_simulated(monkeypatch):
    s = override(load_scenario("ex3_pendulum_ode"),
                 **{"run.duration": 1.0, "effects.rail": 1.2, "effects.saturation": 150.0,
                    "controllers.mpc.horizon": 15})
    r, plans = run_keeping_plans(monkeypatch, s)
    assert r.status == "completed", r.end.message
    assert len(plans) == 50       # one solve per 20 ms
    tol = 1e-6
    for S, U, lo, hi in plans:
        assert np.all(S[0] >= lo[0] - tol) and np.all(S[0] <= hi[0] + tol)
        assert np.all(np.abs(U) <= 150.0 + tol)
    h = r.history
    assert np.abs(h["state"][:, 0]).max() < 1.2
    assert np.abs(h["u"]).max() <= 150.0 + tol
    # the bound was active: without it the cart would go further (the constraint did work)
    assert max(S[0].max() for S, *_ in plans) > 1.15 - 1e-3 or np.abs(h["u"]).max() > 149.0
    # the input is held over each 20 ms period
    assert np.all(np.diff(h["u"].reshape(50, 20), axis=1) == 0.0)


def test_swingup_energy_rises_until_the_catch_and_the_pole_is_held():
    s = override(load_scenario("swingup_mujoco"), **{"effects.rail": 0.0, "run.duration": 8.0})
    r = run(s)
    assert r.controller.kind == "swingup" and r.status == "completed", r.end.message
    h = r.history
    caught = int(np.argmax(h["mode"] > 0.5))
    assert caught > 0 and h["t"][caught] < 6.0
    model = full_model(s, nominal_machine(s))
    state, u = h["state"][:caught], h["u"][:caught]
    # E' = dE/ds . s'(s, u) from the model, at the applied force
    rate = np.array([energy_rate(model, st, uk) for st, uk in zip(state, u)])
    assert rate.min() >= -1e-9 * np.abs(rate).max()
    E = h["energy"][:caught]
    assert np.diff(E).min() > -1e-4          # the hold over a sign change, O(dt^2)
    mgl = 1.0 * 9.8 * 3.0                    # the paper's pole: E hanging = -2 m g l
    assert E[0] == pytest.approx(-2 * mgl) and E[-1] > -0.1 * mgl
    assert abs(wrap_angle(h["state"][-1, 1])) < 0.1       # settling 4 s after the catch
    # the recorded error is wrapped: the pole caught at 2 pi k shows e near 0
    assert np.abs(h["e"][:, 0]).max() <= math.pi + 1e-12


def energy_rate(model, s, u, h=1e-6):
    """``dE/dt = grad E . s'``: the domain's energy along the model's flow (central
    difference along the vector field)."""
    f = model.rhs(s, u)
    return (model.energy(s + h * f) - model.energy(s - h * f)) / (2 * h)


def test_swingup_scenario_meets_the_issue():
    r = run(load_scenario("swingup_mujoco"))
    assert r.status == "completed", r.end.message
    assert r.metrics["rmse_ss"] <= 0.05
    assert r.metrics["joints"]["slider"]["max_abs"] < 8.0


class _Counter(Controller):
    """u = how many times step was called."""

    kind = "counter"

    def __init__(self) -> None:
        self.order = 2
        self.diag = np.zeros(0)
        self.calls = 0

    def reset(self, rng) -> None:
        self.calls = 0

    def step(self, obs: Observation, dt: float) -> float:
        self.calls += 1
        return float(self.calls)


@pytest.mark.parametrize("every, delay, expected", ZOH_CASES)
def test_zero_order_hold_and_delay_by_hand(every, delay, expected):
    ctrl = _Counter()
    loop, hist, end = sampled_run("ex2_duffing", ctrl, every, delay)
    assert end.status == "completed"
    np.testing.assert_array_equal(hist.arrays()["u"], expected)
    assert ctrl.calls == len(range(0, 10, every))


def test_mpc_runs_at_its_own_period_and_control_period_overrides():
    s = override(load_scenario("ex3_pendulum_ode"), **{"run.duration": 0.2,
                                                       "controllers.mpc.horizon": 10})
    r = run(s, controller="mpc")
    assert np.count_nonzero(np.diff(r.history["u"])) <= 9
    r = run(override(s, **{"run.control_period": 0.05}), controller="lqr")
    assert np.count_nonzero(np.diff(r.history["u"])) <= 3


def test_machine_metrics_and_saturation_are_reported():
    s = override(load_scenario("pendulum_mujoco"), **{"run.duration": 0.05, "plant.x0": [3.0, 0.0],
                                                      "task.fall_angle": 0.0})
    r = run(s)     # the paper's controller from 3 rad asks far beyond the 2000 N motor
    m = r.metrics
    # what the motor applied, and what the controller asked
    assert m["saturated_fraction"] > 0.0 and m["max_abs_u"] == 2000.0
    assert m["max_abs_u_command"] > 2000.0
    assert m["plant"]["M"] == 10.0 and m["plant"]["l"] == 3.0
    assert set(m["joints"]) == {"slider", "hinge"}
    assert m["joints"]["hinge"]["final"] == pytest.approx(r.history["state"][-1, 1])
    # the motor clipped: the cart's acceleration is what 2000 N can give at most
    v = r.history["state"][:, 2]
    assert np.abs(np.diff(v)).max() / s.run.dt < 2000.0 / 10.0 * 1.5
    assert m["controller_ms"]["max"] is None or m["controller_ms"]["max"] > 0.0
    flat = flatten(m)
    assert "joints.slider.max_abs" in flat and "plant.M" in flat


@pytest.mark.parametrize("args, expect", [
    (["run", "ex3_pendulum_ode", "--set", "run.control_period=0.0015"], "whole multiple of run.dt"),
    (["run", "ex2_duffing", "--controller", "lqr", "--set", "controllers.lqr.design=\"full\""],
     "'full' needs a plant with a full state"),
    (["run", "ex2_duffing", "--controller", "mpc"],
     "controller 'mpc' cannot run on plant 'duffing' (domain duffing): it needs the full state"),
    (["run", "ex2_duffing", "--controller", "swingup"],
     "controller 'swingup' cannot run on plant 'duffing' (domain duffing): it needs the full "
     "state"),
    (["run", "furuta_mujoco", "--set", "effects.change.at=1.0", "--set", "effects.change.m=0.1"],
     "effects.change: the furuta domain does not support it"),
    (["run", "furuta_mujoco", "--set", "effects.outer_loop.k_x=0.1"],
     "effects.outer_loop: the furuta domain does not support it"),
    (["run", "ex2_duffing", "--set", "effects.rail=1.0"],
     "effects.rail: the duffing domain has no rail"),
    (["run", "ex3_pendulum_ode", "--controller", "lqr", "--set",
      "controllers.lqr.state_weights=[1.0, 2.0]"], "needs 4 entries"),
    (["run", "swingup_mujoco", "--set", "controllers.swingup.release_angle=0.1"],
     "must exceed catch_angle"),
    (["run", "ex3_pendulum_ode", "--controller", "mpc", "--set", "controllers.mpc.period=0.0125"],
     "whole multiple of run.dt"),
    (["run", "ex3_pendulum_ode", "--set", "run.controller=\"nope\""], "run.controller"),
])
def test_bad_settings_are_one_line_exit_2(args, expect, capsys):
    assert main(args + ["--no-record", "--duration", "0.01"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expect in err[0], err


@pytest.mark.parametrize("name", ["ex3_pendulum_ode", "pendulum_mujoco"])
def test_full_lqr_compiled_equals_generic_bit_for_bit(name):
    s = override(load_scenario(name), **{"run.duration": 1.0})
    a = run(s, controller="lqr", compiled=True)
    b = run(s, controller="lqr", compiled=False)
    assert a.status == b.status == "completed"
    for key in ("u", "x", "state", "V", "u_ff"):
        np.testing.assert_array_equal(a.history[key], b.history[key])


def test_full_lqr_on_the_furuta_pendulum_holds_the_arm():
    # the hand-written Furuta equations' linearisation is the oracle for A, B
    import mujoco

    from tests.oracles.furuta_equations import linearize, params_from_model

    s = load_scenario("furuta_ode")
    ctrl = build(s, "lqr")
    A, B = linearize(params_from_model(mujoco.MjModel.from_xml_path("models/furuta.xml")))[:2]
    np.testing.assert_allclose(ctrl.A, A, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(ctrl.B.ravel(), np.ravel(B), rtol=1e-6)
    P = solve_continuous_are(ctrl.A, ctrl.B, ctrl.Q, np.array([[ctrl.R]]))
    np.testing.assert_allclose(ctrl.K, (ctrl.B.T @ P / ctrl.R)[0], rtol=1e-6)
    r = run(s, controller="lqr")
    assert r.status == "completed" and r.metrics["joints"]["arm"]["max_abs"] < 0.5
    assert r.metrics["rmse_ss"] < 1e-3
