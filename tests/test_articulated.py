"""The articulated domain: equations derived from the MJCF, held to MuJoCo and to the
hand-written equations of the cart-pole and the Furuta pendulum.

Oracles: MuJoCo's own ``mj_forward`` (accelerations) and central differences of it
(linearisation), the hand-written cart-pole and Furuta equations (now test oracles of the
derivation), and a plain-MuJoCo run for what ``lqr`` claims.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest

from tspend import load_scenario, override
from tspend.runtime.errors import ScenarioError
from tspend.loop.simulation import run
from tspend.plants.articulated.machine import Machine, load_machine
from tspend.plants.registry import DOMAINS

from cli_harness import ROOT, tspend

MACHINES = ("double_cartpole", "triple_cartpole", "acrobot", "pendubot", "reaction_wheel",
            "rotary_double")

#: a tree that exercises every term: a slide and a hinge in one body, tilted and offset
#: axes, rotated body and inertial frames, a joint reference (qpos0), armature, damping,
#: stiffness with a spring reference, an affine (motor-with-back-EMF) actuator clipped in
#: ctrl and force, a second actuator, and gravity off the vertical (three joints: numba's
#: compile grows with the generated code; the six machines cover longer chains)
ODD_TREE = """
<mujoco>
  <compiler angle="radian" inertiafromgeom="false"/>
  <option timestep="0.001" integrator="RK4" gravity="0.3 -0.2 -9.7"><flag contact="disable"/></option>
  <worldbody>
    <body name="base" pos="0.1 -0.2 0.3" quat="0.9 0.1 -0.2 0.3">
      <joint name="slide" type="slide" axis="1 0.2 0" damping="0.7" armature="0.05"/>
      <joint name="turn" type="hinge" axis="0 0 1" pos="0.05 0 0" ref="0.3" damping="0.02"/>
      <inertial pos="0.02 0.01 -0.03" quat="0.8 0.3 0.1 -0.2" mass="1.7" diaginertia="0.03 0.02 0.01"/>
      <geom type="box" size="0.1 0.1 0.1"/>
      <body name="link" pos="0.2 0 0.1" quat="0.95 0 0.3 0">
        <joint name="tilt" type="hinge" axis="0.3 1 0.2" pos="0 0.02 0" stiffness="1.5"
               springref="0.2" armature="0.01"/>
        <inertial pos="0.05 -0.02 0.4" quat="0.7 0.7 0 0" mass="0.6" diaginertia="0.04 0.035 0.006"/>
        <geom type="capsule" fromto="0 0 0 0 0 0.8" size="0.02"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <general name="drive" joint="tilt" gear="1.3" gaintype="affine" gainprm="2 0.1 0"
             biastype="affine" biasprm="0.1 -0.2 -0.05" ctrllimited="true" ctrlrange="-3 2"
             forcelimited="true" forcerange="-4 5"/>
    <motor name="push" joint="slide" gear="2" ctrllimited="true" ctrlrange="-1 1"/>
  </actuator>
</mujoco>
"""


def _machine(xml: str, actuator: str = "") -> Machine:
    return Machine(mujoco.MjModel.from_xml_string(xml), "<test>", actuator)


def _worst_against_mj_forward(machine: Machine, act: int, n: int, seed: int = 1,
                              u_span: float = 6.0) -> float:
    m = machine.model
    d = mujoco.MjData(m)
    rng = np.random.default_rng(seed)
    worst = 0.0
    for _ in range(n):
        q = rng.uniform(-math.pi, math.pi, machine.nv)
        for j, jf in enumerate(machine.tree.joints):
            if jf.range is not None:
                q[j] = rng.uniform(*jf.range)
        qd = rng.uniform(-20.0, 20.0, machine.nv)
        u = rng.uniform(-u_span, u_span)
        d.qpos[:], d.qvel[:], d.ctrl[:] = q, qd, 0.0
        d.ctrl[act] = u
        mujoco.mj_forward(m, d)
        mine = machine.accelerations(np.concatenate([q, qd]), u)
        worst = max(worst, float(np.max(np.abs(mine - d.qacc) / np.maximum(1.0, np.abs(d.qacc)))))
    return worst


def test_every_term_of_an_odd_tree_matches_mj_forward() -> None:
    # inputs well past both clips, so the ctrl and force ranges are exercised
    for act, name in ((0, "drive"), (1, "push")):
        machine = _machine(ODD_TREE, name)
        # the base is tilted: gravity does work on "turn" too
        assert machine.roles == ("cart", "pole", "pole")
        assert _worst_against_mj_forward(machine, act, 300, u_span=8.0) <= 1e-9


@pytest.mark.parametrize("name", MACHINES)
def test_each_machine_matches_mj_forward(name: str) -> None:
    machine = load_machine(ROOT / "models" / f"{name}.xml")
    a = machine.actuator
    span = max(abs(v) for v in a.ctrlrange) * 1.2
    assert _worst_against_mj_forward(machine, machine.actuator_index, 200, u_span=span) <= 1e-9


def test_the_hand_written_cartpole_and_furuta_equations_agree() -> None:
    """The hand-written equations (tspend/studies/cartpole_greybox.py; the Furuta's in
    tests/oracles/furuta_equations.py) are the derivation's oracles: the same
    accelerations at random states."""
    from tspend.studies.cartpole_greybox import machine_accelerations, machine_of

    rng = np.random.default_rng(7)
    scn = load_scenario("pendulum_mujoco")
    hand = machine_of(DOMAINS["cartpole"].build(scn).params)
    machine = load_machine(ROOT / "models" / "cartpole.xml")
    assert machine.state_names == DOMAINS["cartpole"].build(scn).state_names
    lo, hi = machine.actuator.ctrlrange or (-50.0, 50.0)
    worst = 0.0
    for _ in range(300):
        s = np.concatenate([rng.uniform(-math.pi, math.pi, 2), rng.uniform(-20, 20, 2)])
        u = rng.uniform(lo, hi)
        mine = machine.accelerations(s, u)
        q_dd, x_dd = machine_accelerations(hand, s[1], s[3], s[0], s[2], u, 0.0)
        theirs = np.array([x_dd, q_dd])
        worst = max(worst, float(np.max(np.abs(mine - theirs) / np.maximum(1.0, np.abs(theirs)))))
    assert worst <= 1e-12, ("pendulum_mujoco", worst)


def test_the_furuta_domain_steps_the_derived_equations_which_the_hand_written_agree_with() -> None:
    """The Furuta domain's plants and models are the derived equations; the hand-written
    ones (tests/oracles/furuta_equations.py) agree with them to 1e-12 at random states
    (full circle, 20 rad/s, volts beyond the clip, a pendulum torque), and the
    coefficients the domain reports are theirs."""
    from tests.oracles import furuta_equations as fp

    plant = DOMAINS["furuta"].build(load_scenario("furuta_ode"))
    machine = plant.machine
    oracle = fp.params_from_model(machine.model).machine()
    rng = np.random.default_rng(8)
    sdot, worst = np.empty(4), 0.0
    for _ in range(1000):
        s = np.concatenate([rng.uniform(-math.pi, math.pi, 2), rng.uniform(-20, 20, 2)])
        u, d = rng.uniform(-14.0, 14.0), rng.uniform(-0.02, 0.02)
        plant.rhs_into(0.0, s, u, d, sdot)
        theirs = np.asarray(fp.machine_accelerations(oracle, s, u, d))
        worst = max(worst, float(np.max(np.abs(sdot[2:] - theirs) / np.maximum(1.0, np.abs(theirs)))))
    print(f"furuta: derived vs hand-written, worst relative difference {worst:.1e}")
    assert worst <= 1e-12
    for name, value in plant.parameters().items():
        want = getattr(oracle, name)
        assert value == pytest.approx(want, rel=1e-12, abs=1e-15), name
    # the swing-up's model: q'' and the pendulum's energy, as compiled code calls them
    scn = load_scenario("furuta_ode")
    model = DOMAINS["furuta"].full_model(scn, DOMAINS["furuta"].build(scn))
    for _ in range(200):
        s = np.concatenate([rng.uniform(-math.pi, math.pi, 2), rng.uniform(-20, 20, 2)])
        assert model.energy(s) == pytest.approx(fp.pendulum_energy(oracle, s[1], s[3]),
                                                rel=1e-12, abs=1e-15)
        np.testing.assert_allclose(model.numeric(s, 2.0), fp.machine_accelerations(oracle, s, 2.0, 0.0),
                                   rtol=1e-12, atol=1e-12)


def test_the_linearisation_is_mujocos_central_difference() -> None:
    machine = load_machine(ROOT / "models" / "double_cartpole.xml")
    A, B = machine.linearisation()
    m = machine.model
    d = mujoco.MjData(m)
    nv = machine.nv

    def f(s, u):
        d.qpos[:], d.qvel[:], d.ctrl[0] = s[:nv], s[nv:], u
        mujoco.mj_forward(m, d)
        return np.concatenate([s[nv:], d.qacc])

    h = 1e-6
    A_fd = np.column_stack([(f(np.eye(2 * nv)[i] * h, 0.0) - f(-np.eye(2 * nv)[i] * h, 0.0)) / (2 * h)
                            for i in range(2 * nv)])
    B_fd = ((f(np.zeros(2 * nv), h) - f(np.zeros(2 * nv), -h)) / (2 * h))[:, None]
    assert np.allclose(A, A_fd, rtol=1e-6, atol=1e-6) and np.allclose(B, B_fd, rtol=1e-6, atol=1e-8)


def test_roles_come_from_the_model_and_the_scenario_may_name_the_poles() -> None:
    roles = {n: load_machine(ROOT / "models" / f"{n}.xml").roles for n in MACHINES}
    assert roles["double_cartpole"] == ("cart", "pole", "pole")
    assert roles["triple_cartpole"] == ("cart", "pole", "pole", "pole")
    assert roles["acrobot"] == roles["pendubot"] == ("pole", "pole")
    assert roles["reaction_wheel"] == ("pole", "rotor")
    assert roles["rotary_double"] == ("arm", "pole", "pole")
    only = load_machine(ROOT / "models" / "double_cartpole.xml", poles=("hinge2",))
    assert only.roles == ("cart", "rotor", "pole") and only.view_joint == 2
    with pytest.raises(ScenarioError, match="no joint named 'nope'"):
        load_machine(ROOT / "models" / "double_cartpole.xml", poles=("nope",))


@pytest.mark.parametrize("xml,why", [
    ("<mujoco><worldbody><body><freejoint/><geom size='0.1'/></body></worldbody></mujoco>",
     "free joint"),
    ("<mujoco><worldbody><body><joint type='ball'/><geom size='0.1'/></body></worldbody></mujoco>",
     "ball joint"),
    ("<mujoco><worldbody><body><joint name='h' axis='0 1 0'/><geom size='0.1'/></body></worldbody>"
     "<actuator><general joint='h' dyntype='filter' dynprm='0.1'/></actuator></mujoco>",
     "activation dynamics"),
])
def test_what_cannot_be_derived_is_refused_with_the_reason(xml: str, why: str) -> None:
    with pytest.raises(ScenarioError, match=why):
        _machine(xml)


def test_a_refused_model_is_one_line_and_exit_2(tmp_path: Path) -> None:
    (tmp_path / "ball.xml").write_text(
        "<mujoco><worldbody><body><joint name='b' type='ball'/><geom size='0.1'/></body>"
        "</worldbody></mujoco>")
    r = tspend("run", "double_cartpole_mujoco", "--set", f"plant.model={tmp_path / 'ball.xml'}",
               cwd=ROOT, timeout=300)
    assert r.status == 2 and "ball joint" in r.one_error_line()


def test_the_derivation_is_cached_on_disk(tmp_path: Path) -> None:
    """A second process finds the generated module (and numba's compiled code) there."""
    code = ("import time; t = time.perf_counter(); "
            "from tspend.plants.articulated.machine import load_machine; "
            "m = load_machine('models/acrobot.xml'); import numpy as np; "
            "m.accelerations(np.zeros(4), 0.0); print(time.perf_counter() - t)")
    env = {"TSPEND_CACHE_DIR": str(tmp_path), "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    cold = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=300)
    assert cold.returncode == 0, cold.stderr
    files = sorted(p.name for p in (tmp_path / "articulated").glob("*.py"))
    assert len(files) == 1
    before = (tmp_path / "articulated" / files[0]).stat().st_mtime_ns
    warm = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=300)
    assert warm.returncode == 0, warm.stderr
    assert (tmp_path / "articulated" / files[0]).stat().st_mtime_ns == before
    assert list((tmp_path / "articulated").glob("__pycache__/*.nbi"))  # numba's index


@pytest.mark.parametrize("name", MACHINES)
def test_lqr_balances_every_machine_from_a_tilt_of_each_pole(name: str) -> None:
    scn = override(load_scenario(f"{name}_mujoco"), **{"run.duration": 4.0})
    r = run(scn, controller="lqr")
    assert r.status == "completed"
    machine = load_machine(ROOT / "models" / f"{name}.xml")
    poles = [j for j, role in zip(machine.joint_names, machine.roles) if role == "pole"]
    # every pole the motor does not drive stays within 0.25 rad (the acrobot's driven elbow
    # swings further: it is what balances the shoulder)
    assert poles and all(r.metrics["joints"][p]["max_abs"] <= 0.25 for p in poles
                         if p != machine.joint_names[machine.actuated])
    # and at the end every pole is back near upright, at rest
    s = r.plant.full_state()
    idx = [r.plant.state_names.index(p) for p in poles]
    assert np.max(np.abs(s[idx])) < 0.02


def test_inspect_names_every_joints_role(tmp_path: Path) -> None:
    r = tspend("inspect", "models/double_cartpole.xml", "--json", str(tmp_path / "i.json"),
               cwd=ROOT, timeout=300)
    assert r.status == 0, r.err
    facts = json.loads((tmp_path / "i.json").read_text())
    assert {k: v["role"] for k, v in facts["joints"].items()} == {
        "slider": "cart", "hinge1": "pole", "hinge2": "pole"}
    assert facts["controllable"] is True and "role cart" in r.out


@pytest.mark.parametrize("name", ["double_cartpole_ode", "furuta_ode", "furuta_mujoco"])
def test_the_compiled_loop_steps_the_derived_equations_as_the_generic_one(name, paths) -> None:
    """The derived ODE on the compiled closed loop (RK4 over the generated ``rhs_c`` by
    its C address) gives the generic loop's run bit for bit; so does the Furuta's MuJoCo
    plant on the compiled MuJoCo loop."""
    s = override(load_scenario(name), **{"run.duration": 1.0})
    fast = run(s, controller="lqr", compiled=True)
    slow = run(s, controller="lqr", compiled=False)
    assert paths == ["compiled", "generic"]
    assert fast.status == slow.status == "completed"
    assert fast.end.steps_done == slow.end.steps_done > 900
    for key in ("u", "x", "state"):
        np.testing.assert_array_equal(fast.history[key], slow.history[key], err_msg=key)


@pytest.mark.parametrize("name, unit", [("double_cartpole_ode", "N"), ("acrobot_ode", "N m"),
                                        ("furuta_ode", "V")])
def test_the_recording_labels_u_in_the_unit_of_the_models_actuator(name, unit) -> None:
    """u's unit in the recording and the exported table is the model's (a slide's force, a
    hinge's torque, a motor's volts by its back-EMF bias), not a fixed one per domain."""
    from tspend.loop.simulation import prepare, run_info
    from tspend.recorder.series import specs_of

    s = load_scenario(name)
    parts = prepare(s, controller="lqr")
    info = run_info(s, parts.plant, 10, controller=parts.controller, task=parts.task)
    assert info.input_unit == unit
    spec = next(sp for sp in specs_of(info) if sp.entity == "series/control")
    assert f"u ({unit})" in spec.title
    assert spec.columns[0] == "u_" + unit.replace(" ", "_")


def test_a_nan_mass_model_of_a_derived_ode_exits_2_in_one_line_and_leaves_no_log(tmp_path):
    """The ODE derived from an MJCF reads it through MuJoCo too: a NaN mass exits 2 with
    MuJoCo's warning in the one line, and no MUJOCO_LOG.TXT is left in the working folder
    (issue 51, item 18: the ODE was not counted as reading an MJCF)."""
    from cli_harness import tspend as cli

    text = (Path(__file__).parents[1] / "models" / "double_cartpole.xml").read_text()
    import re

    (tmp_path / "nan.xml").write_text(re.sub(r'mass="[^"]*"', 'mass="nan"', text, count=1))
    r = cli("run", "double_cartpole_ode", "--set", 'plant.model="nan.xml"', "--duration",
            "0.1", "--no-record", cwd=tmp_path, timeout=300)
    assert r.status == 2 and "NaN" in r.one_error_line() and r.out == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["nan.xml"]
