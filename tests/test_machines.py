"""The machines' MJCF models checked with MuJoCo alone (no tspend): independent oracles of
what the articulated domain claims about them.

For each of models/{double_cartpole, triple_cartpole, acrobot, pendubot, reaction_wheel,
rotary_double}.xml: it compiles with the conventions of models/cartpole.xml (RK4, dt <= 1 ms,
contacts off, no frictionloss); q = 0 is an equilibrium (mj_forward's qacc); the central
finite-difference linearisation of mj_forward is controllable (python-control's ctrb has
full rank); and a discrete LQR on that linearisation, run in a plain ``mj_step`` loop,
balances the machine from a tilt of every pole (0.1 rad, alternating signs; 0.05 rad on
the triple cart-pole) within the
actuator's ctrlrange (no clipping needed) and the joints' ranges (rail, cable).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")
control = pytest.importorskip("control")

MODELS = Path(__file__).resolve().parents[1] / "models"

#: machine -> (its poles, LQR input weight rho: R = rho / u_max^2, weight of non-pole
#: angles, the tilt of every pole in rad: the triple cart-pole's 100 N motor catches
#: alternating tilts of 0.05 rad, not 0.1, without clipping)
MACHINES = {
    "double_cartpole": (("hinge1", "hinge2"), 100.0, 10.0, 0.1),
    "triple_cartpole": (("hinge1", "hinge2", "hinge3"), 1000.0, 10.0, 0.05),
    "acrobot": (("shoulder", "elbow"), 200.0, 10.0, 0.1),
    "pendubot": (("shoulder", "elbow"), 100.0, 10.0, 0.1),
    "reaction_wheel": (("pendulum",), 1e5, 1e-4, 0.1),
    "rotary_double": (("link1", "link2"), 100.0, 10.0, 0.1),
}
SECONDS = 6.0


def _model(name):
    return mujoco.MjModel.from_xml_path(str(MODELS / f"{name}.xml"))


def _dynamics(m):
    """x' = f(x, u) for x = (qpos, qvel), through mj_forward."""
    d = mujoco.MjData(m)

    def f(x, u):
        d.qpos[:], d.qvel[:], d.ctrl[:] = x[: m.nv], x[m.nv:], u
        mujoco.mj_forward(m, d)
        return np.concatenate([x[m.nv:], d.qacc])

    return f


def _linearise(m, eps=1e-6):
    f = _dynamics(m)
    n, x0, u0 = 2 * m.nv, np.zeros(2 * m.nv), np.zeros(m.nu)
    A = np.column_stack([(f(x0 + e, u0) - f(x0 - e, u0)) / (2 * eps) for e in np.eye(n) * eps])
    B = np.column_stack([(f(x0, u0 + e) - f(x0, u0 - e)) / (2 * eps) for e in np.eye(m.nu) * eps])
    return A, B


def _lqr(m, poles, rho, other_weight):
    A, B = _linearise(m)
    names = [m.joint(j).name for j in range(m.njnt)]
    q_pos = [10.0 if nm in poles or int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_SLIDE) or nm == "arm"
             else other_weight for j, nm in enumerate(names)]
    Q = np.diag(q_pos + [1.0] * m.nv)
    u_max = float(m.actuator_ctrlrange[0, 1])
    sysd = control.c2d(control.ss(A, B, np.eye(2 * m.nv), 0), m.opt.timestep)
    K, _, _ = control.dlqr(sysd.A, sysd.B, Q, np.eye(1) * rho / u_max**2)
    return K, u_max


@pytest.mark.parametrize("name", sorted(MACHINES))
def test_conventions(name):
    m = _model(name)
    assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
    assert m.opt.timestep <= 1e-3
    assert m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT or not (
        m.geom_contype.any() or m.geom_conaffinity.any())
    assert not m.dof_frictionloss.any()
    assert m.nu == 1 and m.actuator_ctrllimited[0]
    assert all(int(m.jnt_type[j]) in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
               for j in range(m.njnt))
    assert (m.geom_rgba[:, 3] > 0).all()  # drawn from the model: every geom visible


@pytest.mark.parametrize("name", sorted(MACHINES))
def test_upright_is_an_equilibrium_and_unstable(name):
    m = _model(name)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    assert np.abs(d.qacc).max() < 1e-12
    A, _ = _linearise(m)
    assert np.linalg.eigvals(A).real.max() > 1.0  # an inverted pendulum: it falls


@pytest.mark.parametrize("name", sorted(MACHINES))
def test_linearisation_is_controllable(name):
    m = _model(name)
    A, B = _linearise(m)
    assert np.linalg.matrix_rank(control.ctrb(A, B)) == 2 * m.nv


@pytest.mark.parametrize("name", sorted(MACHINES))
def test_lqr_balances_from_a_tilt_of_every_pole(name):
    poles, rho, other, tilt_rad = MACHINES[name]
    m = _model(name)
    K, u_max = _lqr(m, poles, rho, other)
    d = mujoco.MjData(m)
    for i, pole in enumerate(poles):
        d.joint(pole).qpos = tilt_rad * (1 if i % 2 == 0 else -1)
    u_peak, q_peak = 0.0, np.zeros(m.nq)
    for _ in range(int(SECONDS / m.opt.timestep)):
        u = float(-(K @ np.concatenate([d.qpos, d.qvel]))[0])
        u_peak = max(u_peak, abs(u))
        d.ctrl[0] = u
        mujoco.mj_step(m, d)
        q_peak = np.maximum(q_peak, np.abs(d.qpos))
    assert u_peak <= u_max, f"the LQR asked {u_peak:.3g}, the actuator gives {u_max}"
    for j in range(m.njnt):
        if m.jnt_limited[j]:
            assert q_peak[j] < m.jnt_range[j, 1], m.joint(j).name
    for pole in poles:
        assert abs(float(d.joint(pole).qpos[0])) < 1e-3, pole
        assert abs(float(d.joint(pole).qvel[0])) < 1e-2, pole
        # the acrobot's elbow swings furthest (0.97 rad from 0.1 rad): still a catch
        assert q_peak[m.joint(pole).qposadr[0]] < 1.2, pole
    # the cart and the arm come back; a reaction wheel's angle is free (it only spins)
    for j in range(m.njnt):
        if int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_SLIDE) or m.joint(j).name == "arm":
            assert abs(float(d.qpos[m.jnt_qposadr[j]])) < 1e-2, m.joint(j).name


def test_pendubot_reproduces_the_published_lumped_parameters():
    """Spong & Block 1995's theta1..theta5 from the model's bodies (the planar dynamics
    depend on these five only)."""
    m = _model("pendubot")
    m1, m2 = m.body("link1").mass[0], m.body("link2").mass[0]
    lc1, lc2 = m.body("link1").ipos[2], m.body("link2").ipos[2]
    I1, I2 = m.body("link1").inertia[1], m.body("link2").inertia[1]
    l1 = m.body("link2").pos[2]
    theta = [m1 * lc1**2 + m2 * l1**2 + I1, m2 * lc2**2 + I2, m2 * l1 * lc2, m1 * lc1 + m2 * l1, m2 * lc2]
    # the model's masses and lengths are rounded to 6 digits: 1e-3 relative
    np.testing.assert_allclose(theta, [0.0308, 0.0106, 0.0095, 0.2086, 0.0630], rtol=1e-3)
