"""The articulated domain's derivation as the designs use it: f(s, u, p) over CasADi with
the named parameter vector, and lqr's refusal of a machine it cannot stabilise."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from tspend.plants.articulated.machine import Machine, load_machine


@pytest.fixture(autouse=True)
def tmp_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("TSPEND_CACHE_DIR", str(tmp_path / "cache"))


def test_casadi_f_of_state_input_and_parameters():
    """f(s, u, p) over CasADi: at the nominal p it is the compiled rhs; its derivative in
    a mass is the central difference of f itself in that parameter (identification's
    gradient), and a heavier link changes f as MuJoCo's heavier model does."""
    import casadi as ca

    machine = load_machine("models/double_cartpole.xml")
    f = machine.casadi_f()
    rng = np.random.default_rng(2)
    s = np.concatenate([[0.3], rng.uniform(-np.pi, np.pi, 2), rng.uniform(-20, 20, 3)])
    u = np.array([12.0])
    got = np.asarray(f(s, u, machine.p)).ravel()
    want = np.empty(6)
    machine.module.rhs(s, u, np.zeros(3), machine.p, np.zeros(9), np.zeros(3), want)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    i = machine.parameter_names.index("link1.mass")
    S, U, P = ca.SX.sym("s", 6), ca.SX.sym("u", 1), ca.SX.sym("p", machine.p.size)
    J = ca.Function("J", [S, U, P], [ca.jacobian(f(S, U, P), P)])
    dp = np.zeros(machine.p.size)
    dp[i] = 1e-6
    fd = (np.asarray(f(s, u, machine.p + dp)) - np.asarray(f(s, u, machine.p - dp))).ravel() / 2e-6
    np.testing.assert_allclose(np.asarray(J(s, u, machine.p))[:, i], fd, rtol=1e-5, atol=1e-6)
    # MuJoCo's own model with that link heavier: f at the changed p is its qacc
    spec = mujoco.MjSpec.from_file("models/double_cartpole.xml")
    spec.body("link1").mass = machine.p[i] * 1.3
    model = spec.compile()
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:], data.ctrl[:] = s[:3], s[3:], u
    mujoco.mj_forward(model, data)
    p = machine.p.copy()
    p[i] *= 1.3
    np.testing.assert_allclose(np.asarray(f(s, u, p)).ravel()[3:], data.qacc, rtol=1e-10, atol=1e-10)


def test_lqr_refuses_an_uncontrollable_machine():
    """Two equal poles side by side on one cart: their difference cannot be moved by the
    cart, and lqr says so in one line instead of designing a gain that cannot work."""
    from tspend.controllers.lqr import unstabilisable

    twin = mujoco.MjModel.from_xml_string("""
    <mujoco><option><flag contact="disable"/></option><worldbody>
      <body name="cart"><joint name="x" type="slide" axis="1 0 0" range="-2 2"/>
        <inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/>
        <body name="a"><joint name="h1" axis="0 -1 0"/><inertial pos="0 0 0.5" mass="0.5" diaginertia="0.04 0.04 0.001"/></body>
        <body name="b"><joint name="h2" axis="0 -1 0"/><inertial pos="0 0 0.5" mass="0.5" diaginertia="0.04 0.04 0.001"/></body>
      </body></worldbody><actuator><motor name="m" joint="x" ctrlrange="-50 50"/></actuator></mujoco>""")
    m = Machine(twin, "twin")
    why = unstabilisable(*m.linearisation(), m.state_names)
    assert "uncontrollable" in why and "h1" in why and "\n" not in why
    m = load_machine("models/double_cartpole.xml")
    assert unstabilisable(*m.linearisation(), m.state_names) == ""
