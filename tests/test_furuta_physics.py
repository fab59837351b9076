"""The hand-written Furuta ODE (tests/oracles/furuta_equations.py, the oracle of the derived
equations tspend steps) against independent oracles.

* MuJoCo's ``mj_forward`` (recursive Newton-Euler, composite rigid bodies) on
  models/furuta.xml and on a deliberately awkward variant of it: the accelerations;
* MuJoCo's RK4 ``mj_step``: a 2 s open-loop run, step for step;
* ``solve_ivp`` (DOP853, rtol 1e-12) on the textbook equations of the QUBE's uniform rods
  (Cazzolato & Prime 2011 in Quanser's convention), written here from the published
  numbers alone: a third opinion on both the equations and the integration;
* central differences of ``mj_forward`` for the linearisation, and an LQR designed on it
  that must balance the MuJoCo model.
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
from numba import njit
from scipy.integrate import solve_ivp
from scipy.linalg import solve_continuous_are

from tests.oracles import furuta_equations as fp
from tspend.plants.analytic import rk4_step, rk4_work

MODEL = Path(__file__).resolve().parents[1] / "models" / "furuta.xml"
DURATION_S = 2.0
ALPHA0_RAD = 0.1


def _model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(MODEL))


def _qacc(m: mujoco.MjModel, d: mujoco.MjData, s: np.ndarray, u: float, tau_p: float) -> np.ndarray:
    """MuJoCo's accelerations at state ``s`` with ctrl ``u`` and pendulum torque ``tau_p``."""
    d.qpos[:] = s[:2]
    d.qvel[:] = s[2:]
    d.ctrl[0] = u
    d.qfrc_applied[:] = (0.0, tau_p)
    mujoco.mj_forward(m, d)
    return d.qacc.copy()


def _random_states(rng: np.random.Generator, n: int) -> list[tuple[np.ndarray, float, float]]:
    """States anywhere on the circle at up to 30 rad/s, volts beyond the +/-10 V clip."""
    return [(rng.uniform([-4.0, -4.0, -30.0, -30.0], [4.0, 4.0, 30.0, 30.0]),
             float(rng.uniform(-14.0, 14.0)), float(rng.uniform(-0.02, 0.02)))
            for _ in range(n)]


# -- the parameters ------------------------------------------------------------------------
def test_model_holds_the_published_numbers():
    """models/furuta.xml, read back from the compiled model, is the QUBE of FurutaParams()."""
    got, want = fp.params_from_model(_model()), fp.FurutaParams()
    for name in want.__dataclass_fields__:
        np.testing.assert_allclose(np.asarray(getattr(got, name), dtype=float),
                                   np.asarray(getattr(want, name), dtype=float),
                                   rtol=1e-12, atol=1e-15, err_msg=name)
    # by hand, from the manual's numbers: the rod about its end, the rotor and hub, the motor
    assert got.arm_inertia == pytest.approx(0.095 * 0.085 ** 2 / 3, rel=1e-12)
    assert got.arm_armature == pytest.approx(4.6e-6, rel=1e-12)
    assert got.motor_gain == pytest.approx(0.042 / 8.4, rel=1e-12)
    assert got.motor_bias_velocity == pytest.approx(-0.042 * 0.042 / 8.4, rel=1e-12)
    assert got.ctrl_range == (-10.0, 10.0)


def test_motor_is_the_dc_motor_and_clips_at_the_amplifier_limit():
    m = _model()
    d = mujoco.MjData(m)
    machine = fp.FurutaParams().machine()
    for volts, w in ((3.0, 0.0), (-7.5, 12.0), (25.0, -4.0), (-40.0, 30.0)):
        _qacc(m, d, np.array([0.2, 0.0, w, 0.0]), volts, 0.0)
        clipped = min(max(volts, -10.0), 10.0)
        expected = 0.042 * (clipped - 0.042 * w) / 8.4
        assert d.qfrc_actuator[0] == pytest.approx(expected, rel=1e-13)
        assert fp.motor_torque(machine, 0.2, w, volts) == pytest.approx(expected, rel=1e-13)


# -- accelerations -------------------------------------------------------------------------
def test_accelerations_match_mj_forward():
    m = _model()
    d = mujoco.MjData(m)
    machine = fp.params_from_model(m).machine()
    worst = 0.0
    for s, u, tau in _random_states(np.random.default_rng(1), 50):
        ref = _qacc(m, d, s, u, tau)
        got = np.array(fp.machine_accelerations(machine, s, u, tau))
        np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-12)
        worst = max(worst, float(np.max(np.abs(got - ref) / np.abs(ref))))
    print(f"max relative |accel diff| over 50 states: {worst:.2e}")


AWKWARD = """
<mujoco model="awkward furuta">
  <compiler angle="radian" inertiafromgeom="false"/>
  <option timestep="0.001" integrator="RK4" gravity="0 0 -9.81"><flag contact="disable"/></option>
  <worldbody>
    <body name="arm" pos="0.01 -0.02 0.3" quat="0.9659258 0 0 0.2588190">
      <joint name="shaft" type="hinge" axis="0 0 -1" pos="0.003 0.001 0" damping="0.0004"
             armature="2e-6"/>
      <inertial pos="0.03 0.004 0.002" mass="0.11" fullinertia="2e-5 6e-5 6.5e-5 1e-6 -2e-6 3e-7"/>
      <body name="encoder" pos="0.08 0.002 0.003">
        <inertial pos="0.002 0 0.001" mass="0.015" diaginertia="1e-6 2e-6 2.5e-6"/>
        <body name="link" pos="0.006 0.001 -0.002">
          <joint name="swing" type="hinge" axis="1 0.2 -0.1" pos="0.001 -0.002 0.003"
                 damping="0.0002" armature="1e-6" ref="0.3"/>
          <inertial pos="0.003 -0.002 0.06" mass="0.03"
                    fullinertia="4e-5 4.2e-5 6e-6 -1e-6 2e-6 -1.5e-6"/>
          <body name="weight" pos="0.001 0.002 0.12" quat="0.9238795 0.3826834 0 0">
            <inertial pos="0 0.001 0.002" mass="0.01" diaginertia="3e-7 4e-7 5e-7"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <general name="drive" joint="shaft" gear="2" gainprm="0.0025" biastype="affine"
             biasprm="0.001 0.0002 -0.0000525" ctrllimited="true" ctrlrange="-8 6"
             forcelimited="true" forcerange="-0.012 0.01" damping="1e-4" armature="1e-6"/>
  </actuator>
</mujoco>
"""


def test_params_from_model_reads_a_user_model_as_it_is():
    """Any orientation, a downward motor axis, a skewed pendulum axis, full inertia tensors,
    rigid child bodies on both parts, a joint ref, gear 2 with a position bias, force and
    control clips, actuator damping and armature: still MuJoCo's accelerations."""
    m = mujoco.MjModel.from_xml_string(AWKWARD)
    d = mujoco.MjData(m)
    p = fp.params_from_model(m, arm="shaft", pendulum="swing", actuator="drive")
    assert p.gravity == pytest.approx(-9.81)           # the axis points down
    assert p.pendulum_mass == pytest.approx(0.04)      # link + weight
    machine = p.machine()
    for s, u, tau in _random_states(np.random.default_rng(2), 50):
        ref = _qacc(m, d, s, u, tau)
        got = np.array(fp.machine_accelerations(machine, s, u, tau))
        np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("edits, message", [
    ([('damping="0.0005"', 'damping="0.0005" frictionloss="0.001"')], "dry friction"),
    ([('damping="0.0015"', 'damping="0.0015" limited="true" range="-2.3 2.3"')], "limited"),
    ([('<flag contact="disable"/>', '<flag contact="enable"/>'),
      ('<geom contype="0" conaffinity="0" mass="0"/>', '<geom mass="0"/>')], "contacts"),
    ([('gravity="0 0 -9.81"', 'gravity="0 1 -9.81"')], "along gravity"),
    ([('biastype="affine"', 'biastype="none" dyntype="filter" dynprm="0.01"')], "dynamics"),
    ([('<body name="arm"', '<body name="free" pos="1 0 0"><freejoint/><inertial pos="0 0 0" '
       'mass="1" diaginertia="1 1 1"/></body><body name="arm"')], "degrees of freedom"),
])
def test_params_from_model_refuses_what_the_ode_does_not_model(edits, message):
    xml = MODEL.read_text()
    for old, new in edits:
        assert old in xml
        xml = xml.replace(old, new, 1)
    m = mujoco.MjModel.from_xml_string(xml)
    with pytest.raises(ValueError, match=message):
        fp.params_from_model(m)


def test_compiled_accelerations_equal_python():
    """register_jitable: the same math inlined into numba code."""
    @njit(cache=False)
    def compiled(machine, states, u, d):
        out = np.empty((states.shape[0], 2))
        for i in range(states.shape[0]):
            out[i, 0], out[i, 1] = fp.machine_accelerations(machine, states[i], u[i], d[i])
        return out

    cases = _random_states(np.random.default_rng(3), 20)
    states = np.array([c[0] for c in cases])
    u, d = np.array([c[1] for c in cases]), np.array([c[2] for c in cases])
    machine = fp.FurutaParams().machine()
    ref = np.array([fp.machine_accelerations(machine, s, a, b) for s, a, b in cases])
    np.testing.assert_allclose(compiled(machine, states, u, d), ref, rtol=1e-14, atol=0.0)


# -- open loop -----------------------------------------------------------------------------
def _volts(t: float) -> float:
    """Within the +/-10 V clip: two tones, enough to swing the pendulum all around."""
    return 6.0 * math.sin(2.0 * math.pi * 1.3 * t) + 3.0 * math.cos(2.0 * math.pi * 0.4 * t)


def _disturbance(t: float) -> float:
    """A +/-2 mN m square wave on the pendulum joint."""
    return 2e-3 if (t % 0.5) < 0.25 else -2e-3


def _textbook_rhs(t: float, x: np.ndarray, u: float, d: float) -> list[float]:
    """The QUBE's uniform rods in Cazzolato & Prime's form, from the published numbers only
    (alpha from the upright, Quanser's signs); independent of furuta_physics and MuJoCo."""
    mr, Lr, mp, Lp, g = 0.095, 0.085, 0.024, 0.129, 9.81
    Rm, kt, km, Dr, Dp = 8.4, 0.042, 0.042, 0.0015, 0.0005
    lp = Lp / 2
    Jr = mr * Lr ** 2 / 3 + 4.0e-6 + 0.6e-6        # rod about its end, rotor, hub
    Jt = mp * Lp ** 2 / 12                          # pendulum, transverse, about its COM
    Ja = Jt / 3e4                                   # pendulum, about its own axis
    Jpp = Jt + mp * lp ** 2                         # pendulum, transverse, about the pivot
    th, al, thd, ald = x
    s, c = math.sin(al), math.cos(al)
    tau = kt * (min(max(u, -10.0), 10.0) - km * thd) / Rm
    m11 = Jr + mp * Lr ** 2 + Jpp * s * s + Ja * c * c
    m12 = -mp * Lr * lp * c
    m22 = Jpp
    f1 = tau - Dr * thd - 2.0 * (Jpp - Ja) * s * c * thd * ald - mp * Lr * lp * s * ald ** 2
    f2 = d - Dp * ald + (Jpp - Ja) * s * c * thd ** 2 + mp * g * lp * s
    det = m11 * m22 - m12 * m12
    return [thd, ald, (m22 * f1 - m12 * f2) / det, (m11 * f2 - m12 * f1) / det]


@pytest.fixture(scope="module")
def open_loop() -> dict[str, np.ndarray]:
    """2 s from (arm 0, pendulum 0.1 rad) at rest: MuJoCo's RK4, the ODE's RK4, DOP853."""
    m = _model()
    dt = float(m.opt.timestep)
    steps = int(round(DURATION_S / dt))
    x0 = np.array([0.0, ALPHA0_RAD, 0.0, 0.0])

    d = mujoco.MjData(m)
    d.qpos[:] = x0[:2]
    mj = [x0.copy()]
    machine = fp.params_from_model(m).machine()
    s, work = x0.copy(), rk4_work(4)
    ode = [x0.copy()]
    x = x0.copy()
    ivp = [x0.copy()]
    for k in range(steps):
        t = k * dt
        u, tau = _volts(t), _disturbance(t)
        d.ctrl[0] = u
        d.qfrc_applied[:] = (0.0, tau)
        mujoco.mj_step(m, d)
        mj.append(np.concatenate([d.qpos, d.qvel]))
        rk4_step(machine, t, s, u, tau, dt, work)
        ode.append(s.copy())
        x = solve_ivp(_textbook_rhs, (t, t + dt), x, method="DOP853", rtol=1e-12, atol=1e-14,
                      args=(u, tau)).y[:, -1]
        ivp.append(x.copy())
    return {"mujoco": np.array(mj), "ode": np.array(ode), "ivp": np.array(ivp)}


def test_open_loop_swings(open_loop):
    """The run is not trivial: the pendulum falls through the bottom and the arm moves."""
    alpha = open_loop["mujoco"][:, 1]
    assert np.max(np.abs(alpha)) > 2.5
    assert np.max(np.abs(open_loop["mujoco"][:, 0])) > 0.5


def test_open_loop_ode_matches_mujoco_rk4(open_loop):
    diff = np.max(np.abs(open_loop["ode"][:, :2] - open_loop["mujoco"][:, :2]))
    print(f"open loop, 2 s: max |angle diff| ODE RK4 vs MuJoCo RK4 = {diff:.2e} rad")
    assert diff <= 1e-10


@pytest.mark.parametrize("which", ["ode", "mujoco"])
def test_open_loop_matches_solve_ivp(open_loop, which):
    diff = np.max(np.abs(open_loop[which][:, :2] - open_loop["ivp"][:, :2]))
    print(f"open loop, 2 s: max |angle diff| {which} vs DOP853 = {diff:.2e} rad")
    assert diff <= 1e-8


# -- linearisation -------------------------------------------------------------------------
def _mujoco_jacobian(m: mujoco.MjModel, x0: np.ndarray, u0: float, h: float = 1e-6):
    """Central differences of mj_forward's qacc around (x0, u0)."""
    d = mujoco.MjData(m)
    A = np.zeros((4, 4))
    A[0, 2] = A[1, 3] = 1.0
    for i in range(4):
        e = np.zeros(4)
        e[i] = h
        A[2:, i] = (_qacc(m, d, x0 + e, u0, 0.0) - _qacc(m, d, x0 - e, u0, 0.0)) / (2 * h)
    B = np.zeros((4, 1))
    B[2:, 0] = (_qacc(m, d, x0, u0 + h, 0.0) - _qacc(m, d, x0, u0 - h, 0.0)) / (2 * h)
    return A, B


@pytest.mark.parametrize("awkward, arm, alpha, volts", [
    (False, 0.0, 0.0, 0.0),           # upright
    (False, 0.0, math.pi, 0.0),       # hanging
    (False, 0.3, 0.7, 2.0),           # not an equilibrium: dM/dal q'' enters
    (True, 0.2, 0.4, 1.0),            # position bias, gear 2, skewed axes
])
def test_linearize_matches_mujoco_central_differences(awkward, arm, alpha, volts):
    if awkward:
        m = mujoco.MjModel.from_xml_string(AWKWARD)
        p = fp.params_from_model(m, arm="shaft", pendulum="swing", actuator="drive")
    else:
        m = _model()
        p = fp.params_from_model(m)
    A, B = fp.linearize(p, pendulum=alpha, arm=arm, u=volts)
    A_mj, B_mj = _mujoco_jacobian(m, np.array([arm, alpha, 0.0, 0.0]), volts)
    np.testing.assert_allclose(A, A_mj, rtol=1e-6, atol=1e-6 * np.max(np.abs(A_mj)))
    np.testing.assert_allclose(B, B_mj, rtol=1e-6, atol=1e-6 * np.max(np.abs(B_mj)))


def test_upright_unstable_hanging_stable():
    p = fp.FurutaParams()
    up = np.linalg.eigvals(fp.linearize(p, pendulum=0.0)[0])
    down = np.linalg.eigvals(fp.linearize(p, pendulum=math.pi)[0])
    print(f"eigenvalues upright: {np.sort_complex(up)}; hanging: {np.sort_complex(down)}")
    # the arm angle is cyclic: one eigenvalue is exactly zero at both equilibria
    for ev in (up, down):
        assert np.sum(np.abs(ev) < 1e-9) == 1
    unstable = up[up.real > 1e-9]
    assert len(unstable) == 1 and abs(unstable[0].imag) < 1e-12
    rest = down[np.abs(down) >= 1e-9]
    assert np.all(rest.real < 0.0)
    assert np.any(np.abs(rest.imag) > 1.0)     # the hanging pendulum oscillates


def test_lqr_on_the_linearisation_balances_the_mujoco_rig():
    m = _model()
    A, B = fp.linearize(fp.params_from_model(m))
    Q = np.diag([5.0, 1.0, 0.05, 0.05])
    R = np.array([[1.0]])
    K = np.linalg.solve(R, B.T @ solve_continuous_are(A, B, Q, R))
    assert np.all(np.linalg.eigvals(A - B @ K).real < 0.0)
    d = mujoco.MjData(m)
    d.qpos[:] = (0.0, ALPHA0_RAD)
    dt = float(m.opt.timestep)
    volts, late = [], []
    for k in range(int(round(3.5 / dt))):
        x = np.concatenate([d.qpos, d.qvel])
        u = float(-(K @ x)[0])
        volts.append(u)
        d.ctrl[0] = u
        mujoco.mj_step(m, d)
        if (k + 1) * dt >= 3.0:
            late.append(abs(d.qpos[1]))
    lo, hi = m.actuator_ctrlrange[0]
    assert lo <= min(volts) and max(volts) <= hi          # the amplifier never clips
    assert max(late) < 0.01
