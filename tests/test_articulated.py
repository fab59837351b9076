"""The articulated domain's derived equations against independent oracles: MuJoCo's own
``mj_forward`` on several tree shapes, and the hand-written cart-pole and Furuta
equations; the derivation cache; the refusals.

Most shapes are evaluated through the derivation's CasADi function (the same graph the
numba module is printed from); the numba module itself is checked on the double
cart-pole, so the tests stay fast (one cold compile)."""

from __future__ import annotations

import math
import textwrap

import mujoco
import numpy as np
import pytest

from tspend.errors import ScenarioError
from tspend.plants.articulated import derive as derive_module
from tspend.plants.articulated.machine import Machine, derivation_of
from tspend.plants.articulated.tree import read_tree


@pytest.fixture(autouse=True)
def tmp_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("TSPEND_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


def _model(body: str, actuators: str, option: str = 'gravity="0 0 -9.81"') -> mujoco.MjModel:
    xml = f"""
    <mujoco>
      <compiler angle="radian"/>
      <option timestep="0.001" integrator="RK4" {option}><flag contact="disable"/></option>
      <worldbody>{body}</worldbody>
      <actuator>{actuators}</actuator>
    </mujoco>"""
    return mujoco.MjModel.from_xml_string(textwrap.dedent(xml))


_DOUBLE_SRC = """
<mujoco><compiler angle="radian"/>
  <option timestep="0.001" integrator="RK4"><flag contact="disable"/></option>
  <worldbody>
    <body name="cart"><joint name="x" type="slide" axis="1 0 0" range="-3 3" armature="0.2" damping="0.3"/>
      <inertial pos="0.01 0 0.02" mass="1.5" diaginertia="0.01 0.02 0.03"/>
      <body name="l1"><joint name="h1" axis="0 1 0" damping="0.05" stiffness="0.4" springref="0.2" armature="0.01"/>
        <inertial pos="0.01 0.02 0.25" mass="0.5" fullinertia="0.01 0.012 0.005 0.001 -0.0005 0.0003"/>
        <body name="l2" pos="0.02 0 0.5"><joint name="h2" axis="0 1 0" damping="0.02"/>
          <inertial pos="0 0 0.375" mass="0.75" diaginertia="0.035 0.035 0.001"/></body></body></body>
  </worldbody>
  <actuator><motor name="m" joint="x" gear="2" ctrlrange="-20 20"/></actuator>
</mujoco>"""


SHAPES = {
    # cart + two poles, with armature, damping, a spring about a non-zero reference, a
    # full inertia and off-axis centres of mass
    "double_cartpole": mujoco.MjModel.from_xml_string(_DOUBLE_SRC),
    # an acrobot: two links on horizontal axes, the elbow driven
    "acrobot": _model("""
      <body name="a"><joint name="shoulder" axis="0 1 0"/>
        <inertial pos="0 0 0.5" mass="1" diaginertia="0.083 0.083 0.001"/>
        <body name="b" pos="0 0 1"><joint name="elbow" axis="0 1 0"/>
          <inertial pos="0 0 0.5" mass="1" diaginertia="0.33 0.33 0.001"/></body></body>""",
                      '<motor name="elbow" joint="elbow" ctrlrange="-5 5"/>'),
    # a reaction wheel: the wheel's centre of mass on its axis, an affine (back-EMF)
    # actuator with a force range
    "wheel": _model("""
      <body name="p"><joint name="pend" axis="1 0 0"/>
        <inertial pos="0 0 0.3" mass="0.5" diaginertia="0.02 0.02 0.001"/>
        <body name="w" pos="0 0 0.4"><joint name="wheel" axis="1 0 0"/>
          <inertial pos="0 0 0" mass="0.2" diaginertia="0.001 0.0005 0.0005"/></body></body>""",
                    '<general name="motor" joint="wheel" gaintype="fixed" gainprm="0.05" '
                    'biastype="affine" biasprm="0 0 -0.002" ctrlrange="-12 12" forcerange="-0.4 0.4"/>'),
    # a Furuta-like arm with tilted axes, rotated bodies, off-axis centres of mass, a
    # gravity not along -z and an affine gain (gain depending on position and rate)
    "tilted": _model("""
      <body name="arm" quat="0.9 0.1 0.2 0.05"><joint name="arm" axis="0.1 0.2 1" pos="0.01 0 0.02" armature="0.003"/>
        <inertial pos="0.1 0.02 0.01" quat="0.8 0.3 0.1 0.2" mass="0.3" diaginertia="0.004 0.003 0.001"/>
        <body name="pole" pos="0.2 0.03 0.05" quat="0.7 0.2 -0.1 0.3"><joint name="pole" axis="1 0.3 -0.2" pos="0 0.01 0"/>
          <inertial pos="0.01 -0.02 0.15" quat="0.6 0.2 0.5 0.1" mass="0.1" diaginertia="0.002 0.0015 0.0008"/>
          <body name="tip" pos="0 0 0.3"><joint name="tip" type="slide" axis="0.2 0.1 1" stiffness="3" springref="0.05"/>
            <inertial pos="0.01 0 0" mass="0.05" diaginertia="0.0001 0.0001 0.0001"/></body></body></body>""",
                     '<general name="u" joint="arm" gaintype="affine" gainprm="1.5 0.1 -0.05" '
                     'biastype="affine" biasprm="0.02 -0.3 -0.04" gear="1.3" ctrlrange="-2 2"/>',
                     option='gravity="0.5 -0.8 -9.7"'),
}


def _states(machine: Machine, rng: np.random.Generator, n: int):
    for _ in range(n):
        s = np.empty(2 * machine.nv)
        for j, jf in enumerate(machine.tree.joints):
            lo, hi = jf.range if (jf.kind == "slide" and jf.range) else (-math.pi, math.pi)
            s[j] = rng.uniform(lo * 0.999, hi * 0.999) if jf.kind == "slide" else rng.uniform(lo, hi)
        s[machine.nv:] = rng.uniform(-20.0, 20.0, machine.nv)
        u = np.array([rng.uniform(*(a.ctrlrange or (-1.0, 1.0))) * 1.2 for a in machine.tree.actuators])
        yield s, u


def _casadi_qdd(machine: Machine, s: np.ndarray, u: np.ndarray, qfrc: np.ndarray | None = None) -> np.ndarray:
    nv = machine.nv
    M, r = machine.derivation.dynamics(s[:nv], s[nv:], u, np.zeros(nv) if qfrc is None else qfrc,
                                       machine.p)
    return np.linalg.solve(np.asarray(M).reshape(nv, nv, order="F"), np.asarray(r).ravel())


def _mj_qacc(model, data, s, u, qfrc=None):
    nv = model.nv
    mujoco.mj_resetData(model, data)
    data.qpos[:], data.qvel[:], data.ctrl[:] = s[:nv], s[nv:], u
    if qfrc is not None:
        data.qfrc_applied[:] = qfrc
    mujoco.mj_forward(model, data)
    assert data.nefc == 0
    return np.asarray(data.qacc).copy()


def _machine(name: str) -> Machine:
    model = SHAPES[name]
    return Machine(model, name, actuator=model.actuator(0).name)


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_derived_accelerations_match_mj_forward(name):
    """Over the full circle, rates to 20, inputs past the control range (the clips):
    the derived q'' is MuJoCo's to round-off, including a generalised force."""
    machine = _machine(name)
    model = machine.model
    data = mujoco.MjData(model)
    rng = np.random.default_rng(3)
    worst = 0.0
    for s, u in _states(machine, rng, 300):
        qfrc = rng.normal(size=machine.nv)
        ref = _mj_qacc(model, data, s, u, qfrc)
        got = _casadi_qdd(machine, s, u, qfrc)
        worst = max(worst, float(np.max(np.abs(got - ref) / np.maximum(1.0, np.abs(ref)))))
    assert worst <= 1e-10, worst


def test_compiled_module_matches_mj_forward_and_caches(tmp_cache, monkeypatch):
    """The numba module printed from the derivation agrees with mj_forward; it is written
    once into the cache, keyed by the tree's structure, and reused by a machine of other
    numbers (a parameter vector, not a new derivation)."""
    monkeypatch.setattr(derive_module, "_LOADED", {})  # as a new process would
    machine = _machine("double_cartpole")
    files = sorted((tmp_cache / "articulated").glob("tspend_articulated_*.py"))
    assert len(files) == 1
    model, data = machine.model, mujoco.MjData(machine.model)
    rng = np.random.default_rng(5)
    M, r, sdot = np.zeros(machine.nv ** 2), np.zeros(machine.nv), np.zeros(2 * machine.nv)
    worst = 0.0
    for s, u in _states(machine, rng, 300):
        ref = _mj_qacc(model, data, s, u)
        machine.module.rhs(s, u, np.zeros(machine.nv), machine.p, M, r, sdot)
        worst = max(worst, float(np.max(np.abs(sdot[machine.nv:] - ref) / np.maximum(1.0, np.abs(ref)))))
    assert worst <= 1e-10, worst
    # other masses, same structure: the same derivation and file
    spec = mujoco.MjSpec.from_string(_DOUBLE_SRC)
    spec.bodies[2].mass = 0.9
    heavier = Machine(spec.compile(), "heavier")
    assert heavier.derivation.key() == machine.derivation.key()
    assert heavier.module is machine.module
    assert heavier.parameters()["l1.mass"] == pytest.approx(0.9)
    assert sorted((tmp_cache / "articulated").glob("tspend_articulated_*.py")) == files
    # a different structure (an axis) is another derivation
    assert read_tree(SHAPES["acrobot"]).structure_key() != machine.tree.structure_key()


def test_unwritable_cache_still_runs(monkeypatch, tmp_path):
    """No cache folder that can be written: the module is built in a temporary folder."""
    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.setenv("TSPEND_CACHE_DIR", str(blocker / "below"))
    assert derive_module.cache_dir() is None


def test_roles_from_the_model():
    """Slide = cart; a hinge gravity acts on = pole; a balanced wheel = rotor; a vertical
    axis gravity does no work about = arm; a scenario may name the poles."""
    assert _machine("double_cartpole").roles == ("cart", "pole", "pole")
    assert _machine("acrobot").roles == ("pole", "pole")
    assert _machine("wheel").roles == ("pole", "rotor")
    furuta = mujoco.MjModel.from_xml_path("models/furuta.xml")
    assert Machine(furuta, "furuta").roles == ("arm", "pole")
    m = Machine(SHAPES["acrobot"], "acrobot", poles=("elbow",))
    assert m.roles[1] == "pole" and m.poles == (1,)
    with pytest.raises(ScenarioError, match="no joint named 'knee'"):
        Machine(SHAPES["acrobot"], "acrobot", poles=("knee",))


@pytest.mark.parametrize("scenario", ["pendulum_mujoco", "furuta_mujoco"])
def test_derived_equations_match_the_hand_written_ones(scenario):
    """The cart-pole's (C1)-(C2) and the Furuta's Lagrange equations, written by hand,
    are oracles of the derivation from the same compiled MJCF (<= 1e-12)."""
    from tspend.loop.simulation import build_plant
    from tspend.plants.effects import EffectsPlant
    from tspend.plants.registry import domain_of
    from tspend.scenario import load_scenario

    scn = load_scenario(scenario)
    mj = build_plant(scn, scn.plant.kind)
    mj = mj.inner if isinstance(mj, EffectsPlant) else mj
    ode = domain_of(scn.plant.kind).ode_of(mj)
    machine = Machine(mj.mj_model(), scenario)
    assert tuple(ode.state_names) == machine.state_names
    order = np.asarray(ode.full_order)
    rng = np.random.default_rng(7)
    worst = 0.0
    for s, u in _states(machine, rng, 200):
        internal = np.empty_like(s)
        internal[order] = s
        ref = ode.rhs(0.0, internal, float(u[0]), 0.0)[order][machine.nv:]
        got = _casadi_qdd(machine, s, u)
        worst = max(worst, float(np.max(np.abs(got - ref) / np.maximum(1.0, np.abs(ref)))))
    assert worst <= 1e-12, worst


@pytest.mark.parametrize("body, reason", [
    ('<body><freejoint/><geom size="0.1" mass="1"/></body>', "free joint"),
    ('<body><joint type="ball"/><geom size="0.1" mass="1"/></body>', "ball joint"),
])
def test_refusals(body, reason):
    model = mujoco.MjModel.from_xml_string(f"<mujoco><worldbody>{body}</worldbody></mujoco>")
    with pytest.raises(ScenarioError, match=reason):
        Machine(model, "m")


def test_activation_dynamics_and_equalities_are_refused():
    xml = """<mujoco><worldbody>
      <body><joint name="a" axis="0 1 0"/><geom size="0.1" mass="1"/>
        <body pos="0 0 1"><joint name="b" axis="0 1 0"/><geom size="0.1" mass="1"/></body></body>
      </worldbody><equality><joint joint1="a" joint2="b"/></equality>
      <actuator><general joint="a" dyntype="filter" dynprm="0.1"/></actuator></mujoco>"""
    with pytest.raises(ScenarioError) as e:
        Machine(mujoco.MjModel.from_xml_string(xml), "m")
    assert "equality" in str(e.value) and "activation dynamics" in str(e.value)


def test_linearisation_is_exact():
    """(A, B) at the upright by CasADi's differentiation against central differences of
    MuJoCo's mj_forward."""
    machine = _machine("double_cartpole")
    A, B = machine.linearisation()
    model, data = machine.model, mujoco.MjData(machine.model)
    nv, h = machine.nv, 1e-6
    s0 = np.zeros(2 * nv)
    for i in range(2 * nv):
        e = np.zeros(2 * nv)
        e[i] = h
        col = (_mj_qacc(model, data, s0 + e, [0.0]) - _mj_qacc(model, data, s0 - e, [0.0])) / (2 * h)
        np.testing.assert_allclose(A[nv:, i], col, atol=1e-6)
    col = (_mj_qacc(model, data, s0, [h]) - _mj_qacc(model, data, s0, [-h])) / (2 * h)
    np.testing.assert_allclose(B[nv:, 0], col, atol=1e-6)


def test_compiled_loop_is_the_generic_loop(paths):
    """The ODE on the compiled closed loop (the generated module's machine_rhs in the
    shared RK4) steps exactly as the generic Python loop does."""
    from tspend import load_scenario, override, run

    scn = override(load_scenario("double_cartpole_ode"), **{"run.duration": 0.3})
    fast = run(scn, controller="lqr")
    slow = run(scn, controller="lqr", compiled=False)
    assert paths == ["compiled", "generic"]
    np.testing.assert_array_equal(fast.history["x"], slow.history["x"])
    assert fast.metrics["joints"]["hinge2"]["max_abs"] == slow.metrics["joints"]["hinge2"]["max_abs"]


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
    m = _machine("double_cartpole")
    assert unstabilisable(*m.linearisation(), m.state_names) == ""


def test_compiled_mujoco_loop_is_the_generic_loop(paths):
    """The MuJoCo backend on the compiled loop (MuJoCo's C mj_step from compiled code)
    steps exactly as the generic loop does."""
    from tspend import load_scenario, override, run

    scn = override(load_scenario("double_cartpole_mujoco"), **{"run.duration": 0.3})
    fast = run(scn, controller="lqr")
    slow = run(scn, controller="lqr", compiled=False)
    assert paths == ["compiled", "generic"]
    np.testing.assert_array_equal(fast.history["x"], slow.history["x"])


def test_casadi_f_of_state_input_and_parameters():
    """f(s, u, p) over CasADi: at the nominal p it is the compiled rhs; its derivative in
    a mass is the finite difference of two machines (identification's gradient)."""
    import casadi as ca

    machine = _machine("double_cartpole")
    f = machine.casadi_f()
    rng = np.random.default_rng(2)
    s, u = next(_states(machine, rng, 1))
    u = np.clip(u, -20, 20)
    got = np.asarray(f(s, u, machine.p)).ravel()
    want = np.empty(2 * machine.nv)
    machine.module.rhs(s, u, np.zeros(machine.nv), machine.p, np.zeros(9), np.zeros(3), want)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    i = machine.parameter_names.index("l1.mass")
    S, U, P = ca.SX.sym("s", 6), ca.SX.sym("u", 1), ca.SX.sym("p", machine.p.size)
    J = ca.Function("J", [S, U, P], [ca.jacobian(f(S, U, P), P)])
    dp = np.zeros(machine.p.size)
    dp[i] = 1e-6
    fd = (np.asarray(f(s, u, machine.p + dp)) - np.asarray(f(s, u, machine.p - dp))).ravel() / 2e-6
    np.testing.assert_allclose(np.asarray(J(s, u, machine.p))[:, i], fd, rtol=1e-5, atol=1e-6)
