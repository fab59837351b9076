"""[randomize] on a machine read from its MJCF (the articulated and Furuta kinds): the drawn
numbers, named by the model's bodies and joints, reach the compiled model (read back with
MuJoCo's own arrays), the derived equations simulate that machine (their accelerations
against MuJoCo's mj_forward), a drawn number needs no new derivation, the controllers are
designed on the model as it is, and a bad name is one line and exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import mujoco
import numpy as np
import pytest

from tspend import build_plant, load_scenario, override
from tspend.cli.main import main
from tspend.loop.simulation import prepare
from tspend.plants import randomize
from tspend.scenario import parse_scenario

ROOT = Path(__file__).resolve().parents[1]
NAME = "double_cartpole_mujoco_randomized"
TEXT = (ROOT / "scenarios" / f"{NAME}.toml").read_text()
LINK1 = '"link1.mass" = {dist = "uniform", low = 0.9, high = 1.1, relative = true}'


def _at(seed: int, text: str = TEXT):
    return override(parse_scenario(text, str(ROOT / "scenarios" / f"{NAME}.toml")),
                    **{"run.seed": seed})


@pytest.mark.parametrize("seed", [0, 3])
def test_drawn_masses_reach_the_compiled_model_with_their_inertia(seed):
    drawn = randomize.draw(_at(seed)).values
    assert set(drawn) == {"x0[0]", "x0[1]", "link1.mass", "link2.mass"}
    nominal = mujoco.MjModel.from_xml_path(str(ROOT / "models" / "double_cartpole.xml"))
    model = build_plant(_at(seed)).model
    for body in ("link1", "link2"):
        b = nominal.body(body).id
        got = float(model.body_mass[b])
        assert got == pytest.approx(drawn[f"{body}.mass"], rel=1e-12)
        assert 0.9 * nominal.body_mass[b] <= got <= 1.1 * nominal.body_mass[b]
        # the inertia scales with the mass, the centre of mass stays
        np.testing.assert_allclose(model.body_inertia[b],
                                   nominal.body_inertia[b] * got / nominal.body_mass[b], rtol=1e-12)
        np.testing.assert_array_equal(model.body_ipos[b], nominal.body_ipos[b])
    assert model.body_mass[nominal.body("cart").id] == nominal.body_mass[nominal.body("cart").id]


def test_two_seeds_draw_different_masses_recorded_in_the_metrics(tmp_path):
    docs = []
    for seed in (0, 1):
        out = tmp_path / f"m{seed}.json"
        assert main(["run", NAME, "--seed", str(seed), "--duration", "0.05", "--no-record",
                     "--metrics", str(out)]) == 0
        docs.append(json.loads(out.read_text()))
    a, b = docs[0]["drawn"], docs[1]["drawn"]
    assert set(a) == set(b) == {"x0[0]", "x0[1]", "link1.mass", "link2.mass"}
    assert a["link1.mass"] != b["link1.mass"] and a["link2.mass"] != b["link2.mass"]
    # the machine the run reports is the drawn one
    assert docs[0]["plant"]["link1.mass"] == pytest.approx(a["link1.mass"], rel=1e-12)


@pytest.mark.parametrize("seed", [0, 5])
def test_derived_equations_match_mujoco_on_the_drawn_machine(seed):
    """q'' of the derived ODE (built from the drawn compiled model) against MuJoCo's
    mj_forward on the MuJoCo plant's model, at random states and inputs inside the rail
    and the motor's range (no constraint active)."""
    scn = _at(seed)
    mj, ode = build_plant(scn), build_plant(scn, "articulated_ode")
    nominal_ode = build_plant(load_scenario("double_cartpole_mujoco"), "articulated_ode")
    model, data = mj.model, mujoco.MjData(mj.model)
    rng = np.random.default_rng(seed)
    nv = model.nv
    differs = 0.0
    for _ in range(20):
        q = rng.uniform([-1.0, -np.pi, -np.pi], [1.0, np.pi, np.pi])
        v = rng.uniform(-3.0, 3.0, nv)
        u = float(rng.uniform(-30.0, 30.0))
        data.qpos[:], data.qvel[:], data.ctrl[:] = q, v, u
        mujoco.mj_forward(model, data)
        assert data.nefc == 0
        want = np.array(data.qacc)
        got = ode.machine.accelerations(np.concatenate([q, v]), u)
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * np.abs(want).max())
        other = nominal_ode.machine.accelerations(np.concatenate([q, v]), u)
        differs = max(differs, float(np.abs(other - want).max() / np.abs(want).max()))
    assert differs > 1e-4  # the nominal machine is another machine


def test_a_drawn_number_needs_no_new_derivation():
    """The derivation is keyed by the tree's structure; the numbers are its parameters."""
    plain = build_plant(load_scenario("double_cartpole_mujoco"))
    drawn = build_plant(_at(2))
    assert drawn.machine.tree.structure_key() == plain.machine.tree.structure_key()
    assert drawn.machine.module is plain.machine.module
    i = drawn.machine.parameter_names.index("link2.mass")
    assert drawn.machine.p[i] == randomize.draw(_at(2)).values["link2.mass"] != plain.machine.p[i]


def test_a_scenario_without_randomize_builds_the_model_as_written():
    plain = load_scenario("double_cartpole_mujoco")
    assert randomize.draw(plain).scenario is plain
    model = build_plant(plain).model
    ref = mujoco.MjModel.from_xml_path(str(ROOT / "models" / "double_cartpole.xml"))
    for name in ("body_mass", "body_inertia", "body_ipos", "dof_damping", "dof_armature"):
        np.testing.assert_array_equal(getattr(model, name), getattr(ref, name), err_msg=name)


def test_lqr_is_designed_on_the_nominal_machine():
    scn = _at(4)
    k_run = prepare(scn, controller="lqr").controller.K
    nominal = prepare(load_scenario("double_cartpole_mujoco"), controller="lqr").controller.K
    drawn = prepare(randomize.draw(scn).scenario, controller="lqr").controller.K
    np.testing.assert_array_equal(k_run, nominal)
    assert np.abs(drawn - nominal).max() > 1e-6 * np.abs(nominal).max()


def test_joint_damping_and_armature_are_drawn_into_both_backends():
    text = TEXT.replace(LINK1, '"hinge1.damping" = {dist = "uniform", low = 0.01, high = 0.02}\n'
                               'slider.armature = {dist = "uniform", low = 0.1, high = 0.2}')
    scn = _at(1, text)
    drawn = randomize.draw(scn).values
    model = build_plant(scn).model
    ode = build_plant(scn, "articulated_ode").machine.parameters()
    for joint, what, arr in (("hinge1", "damping", model.dof_damping),
                             ("slider", "armature", model.dof_armature)):
        want = drawn[f"{joint}.{what}"]
        assert float(arr[model.joint(joint).dofadr[0]]) == want
        assert ode[f"{joint}.{what}"] == want


def test_furuta_draws_its_pendulum_mass_on_both_backends():
    text = (ROOT / "scenarios" / "furuta_mujoco.toml").read_text() + (
        '\n[randomize]\npendulum.mass = {dist = "uniform", low = 0.9, high = 1.1, '
        'relative = true}\n')
    scn = override(parse_scenario(text, "furuta.toml"), **{"run.seed": 2})
    m = randomize.draw(scn).values["pendulum.mass"]
    assert 0.9 * 0.024 <= m <= 1.1 * 0.024
    for kind in ("furuta_mujoco", "furuta_ode"):
        assert build_plant(scn, kind).machine.parameters()["pendulum.mass"] == pytest.approx(
            m, rel=1e-12)


BAD = [
    ("no such body", LINK1, LINK1.replace("link1", "link9"),
     ["randomize.link9.mass", "no body 'link9'", "link1, link2", "hinge1"]),
    ("a joint has no mass", LINK1, LINK1.replace("link1", "hinge1"),
     ["randomize.hinge1.mass", "no body 'hinge1'", "cart, link1, link2"]),
    ("unknown quantity", LINK1, LINK1.replace("mass", "colour"),
     ["randomize.link1.colour", "unknown key", "BODY.mass"]),
    ("a mass <= 0", LINK1, '"link1.mass" = {dist = "uniform", low = -0.1, high = 0.5}',
     ["randomize.link1.mass", "must be > 0"]),
    ("relative on a zero damping", LINK1,
     '"hinge1.damping" = {dist = "uniform", low = 0.5, high = 2.0, relative = true}',
     ["randomize.hinge1.damping.relative", "is 0"]),
]


@pytest.mark.parametrize("name,old,new,words", BAD, ids=[b[0] for b in BAD])
def test_bad_model_name_or_value_exits_2_in_one_line(tmp_path, capsys, name, old, new, words):
    assert old in TEXT
    path = tmp_path / "bad.toml"
    path.write_text(TEXT.replace(old, new, 1))
    status = main(["run", str(path), "--no-record", "--duration", "0.01"])
    err = capsys.readouterr().err.strip()
    assert status == 2, err
    assert len(err.splitlines()) == 1, err
    assert "bad.toml" in err
    for w in words:
        assert w in err, (w, err)


def test_set_on_a_quoted_name_updates_its_draw():
    """``--set randomize.link1.mass.low=...`` reaches the file's ``"link1.mass"`` entry
    (TOML reads the dotted override as nested tables)."""
    scn = override(_at(0), **{"randomize.link1.mass.low": 0.5, "randomize.link1.mass.high": 0.6})
    (d,) = [d for d in scn.randomize if d.name == "link1.mass"]
    assert (d.a, d.b, d.relative) == (0.5, 0.6, True)
    assert 0.25 <= randomize.draw(scn).values["link1.mass"] <= 0.3


def test_a_mass_from_geoms_is_scaled_through_the_geoms():
    """A body without an explicit inertial (the compiler's inertiafromgeom) gets its geoms'
    mass or density scaled: mass and inertia by the same factor, the frame unchanged."""
    from tspend.plants.articulated.model_numbers import check_values, write_values

    xml = """<mujoco><worldbody><body name="b"><joint name="j" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0 0 0.5" size="0.02"/>
      <geom type="sphere" pos="0.1 0 0.5" size="0.05" mass="0.3"/></body></worldbody></mujoco>"""
    spec = mujoco.MjSpec.from_string(xml)
    before = spec.compile()
    b = before.body("b").id
    want = 1.2 * float(before.body_mass[b])
    write_values(spec, (("b.mass", want),), "x.xml")
    after = spec.compile()
    check_values(after, (("b.mass", want),), "x.xml")
    assert float(after.body_mass[b]) == pytest.approx(want, rel=1e-12)
    np.testing.assert_allclose(after.body_inertia[b], 1.2 * before.body_inertia[b], rtol=1e-9)
    np.testing.assert_allclose(after.body_ipos[b], before.body_ipos[b], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(np.abs(after.body_iquat[b]), np.abs(before.body_iquat[b]),
                               atol=1e-12)
