"""[randomize]: what a seed draws reaches the compiled MJCF (read back with MuJoCo's own
arrays) and the ODE identically; the same seed draws the same machine; the draws follow
their declared distributions (scipy's) within their bounds; a bad table exits 2."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy import stats

from tspend import build_plant, load_scenario, override, run
from tspend.cli.main import main
from tspend.plants import randomize
from tspend.plants.randomize import Draw

ROOT = Path(__file__).resolve().parents[1]
MJ = "pendulum_mujoco_randomized"
ODE = "ex3_pendulum_ode_randomized"


def _at(name: str, seed: int, duration: float | None = None):
    changes = {"run.seed": seed}
    if duration is not None:
        changes["run.duration"] = duration
    return override(load_scenario(name), **changes)


def _read_back(model: mujoco.MjModel) -> dict[str, float]:
    """M, m, l and the gear of a compiled cart-pole, from MuJoCo's arrays directly."""
    hinge, slide, act = model.joint("hinge").id, model.joint("slider").id, model.actuator("force").id
    pole, cart = int(model.jnt_bodyid[hinge]), int(model.jnt_bodyid[slide])
    m = float(model.body_mass[pole])
    return {"m": m, "M": float(model.body_subtreemass[cart]) - m,
            "l": float(np.linalg.norm(model.body_ipos[pole] - model.jnt_pos[hinge])),
            "gear": float(model.actuator_gear[act, 0] * model.actuator_gainprm[act, 0])}


@pytest.mark.parametrize("seed", [0, 7])
def test_drawn_parameters_reach_the_compiled_mjcf_and_the_ode_identically(seed):
    scn = _at(MJ, seed)
    drawn = randomize.draw(scn).values
    assert set(drawn) == {"x0[0]", "x0[1]", "m", "l", "M", "gear"}
    mj = build_plant(scn)
    got = _read_back(mj.model)
    for name in ("m", "M", "l", "gear"):
        assert got[name] == pytest.approx(drawn[name], rel=1e-12), name
    ode = build_plant(scn, "cartpole_ode")
    for name in ("m", "M", "l", "gear"):
        assert getattr(ode.params, name) == pytest.approx(drawn[name], rel=1e-12), name
    # the initial state: hinge angle and velocity on both backends
    for plant in (mj, ode):
        s = dict(zip(plant.state_names, plant.full_state()))
        assert (s["hinge"], s["hinge_dot"]) == (drawn["x0[0]"], drawn["x0[1]"])


def test_an_ode_scenario_on_mujoco_gets_the_same_machine():
    scn = _at(ODE, 3)
    drawn = randomize.draw(scn).values
    got = _read_back(build_plant(scn, "cartpole_mujoco").model)
    p = build_plant(scn).params
    for name in ("m", "M", "l", "gear"):
        assert got[name] == pytest.approx(drawn[name], rel=1e-12)
        assert getattr(p, name) == drawn[name]


def test_both_backends_run_the_same_drawn_machine():
    scn = _at(MJ, 2, duration=2.0)
    a = run(scn, keep_history=False).metrics
    b = run(scn, keep_history=False, plant_kind="cartpole_ode").metrics
    assert a["drawn"] == b["drawn"] == randomize.draw(scn).values
    assert a["rmse"] == pytest.approx(b["rmse"], rel=1e-6)
    assert a["rmse"] != run(_at(MJ, 3, 2.0), keep_history=False).metrics["rmse"]


def test_same_seed_same_draw_and_streams_are_independent():
    a, b = randomize.draw(_at(MJ, 5)).values, randomize.draw(_at(MJ, 5)).values
    assert a == b
    assert randomize.draw(_at(MJ, 6)).values != a
    # dropping an entry leaves the other entries' draws as they were
    text = load_scenario(MJ).text.replace(
        'm = {dist = "uniform", low = 0.8, high = 1.2, relative = true}', "")
    from tspend.scenario import parse_scenario

    fewer = randomize.draw(override(parse_scenario(text, "x.toml"), **{"run.seed": 5})).values
    assert "m" not in fewer and all(fewer[k] == a[k] for k in fewer)
    # a scenario without [randomize] is untouched
    plain = load_scenario("pendulum_mujoco")
    assert randomize.draw(plain).scenario is plain and randomize.draw(plain).values == {}


@pytest.mark.parametrize("name", [ODE, MJ])
def test_compiled_and_python_loops_run_the_drawn_machine_alike(name):
    """The paper's controller runs in the compiled loop (analytic RK4 or MuJoCo's mj_step
    from compiled code) on the plant built for the run: the drawn one."""
    scn = _at(name, 4, duration=1.0)
    fast = run(scn, keep_history=False).metrics
    slow = run(scn, keep_history=False, compiled=False).metrics
    assert fast["controller_ms"]["median"] is None      # the compiled loop ran
    assert slow["controller_ms"]["median"] is not None  # the generic loop ran
    assert fast["drawn"] == slow["drawn"]
    assert fast["rmse"] == pytest.approx(slow["rmse"], rel=1e-12)
    assert fast["plant"]["m"] == pytest.approx(fast["drawn"]["m"], rel=1e-12)
    nominal = run(override(load_scenario(name.replace("_randomized", "")),
                           **{"run.duration": 1.0, "run.seed": 4}), keep_history=False).metrics
    assert nominal["rmse"] != fast["rmse"]


def test_sweep_rows_carry_drawn_columns():
    from tspend.sweep import sweep

    rows = sweep(_at(ODE, 0, duration=0.2), seeds=[0, 1], controllers=["pd"], jobs=1)
    for name in ("x0[0]", "x0[1]", "m", "l", "M", "gear"):
        col = f"drawn.{name}"
        assert col in rows.columns
        assert list(rows[col]) == [randomize.draw(_at(ODE, s)).values[name] for s in (0, 1)]


# -- the distributions ----------------------------------------------------------------------
@settings(max_examples=60, deadline=None)
@given(lo=st.floats(-10, 10), width=st.floats(1e-6, 10), nominal=st.floats(0.1, 10),
       relative=st.booleans(), seed=st.integers(0, 2**31))
def test_uniform_draws_stay_in_their_bounds(lo, width, nominal, relative, seed):
    d = Draw("p", "uniform", lo, lo + width, relative, lo, lo + width)
    v = d.sample(np.random.default_rng(seed), nominal)
    k = nominal if relative else 1.0
    assert min(lo * k, (lo + width) * k) <= v <= max(lo * k, (lo + width) * k)


@settings(max_examples=60, deadline=None)
@given(mean=st.floats(-5, 5), std=st.floats(1e-3, 5), below=st.floats(0, 10),
       above=st.floats(1e-6, 10), seed=st.integers(0, 2**31))
def test_truncated_normal_draws_stay_in_their_bounds(mean, std, below, above, seed):
    lo, hi = mean - below, mean + above
    d = Draw("p", "normal", mean, std, False, lo, hi)
    assert lo <= d.sample(np.random.default_rng(seed), 1.0) <= hi


def test_draws_over_seeds_follow_the_declared_distributions():
    scn = load_scenario(ODE)
    values = [randomize.draw(override(scn, **{"run.seed": s})).values for s in range(300)]
    m = np.array([v["m"] for v in values]) / 1.0          # relative to the nominal m = 1
    ref = stats.truncnorm((0.8 - 1.0) / 0.1, (1.2 - 1.0) / 0.1, loc=1.0, scale=0.1)
    assert stats.kstest(m, ref.cdf).pvalue > 1e-3
    assert stats.kstest(m, stats.uniform(0.8, 0.4).cdf).pvalue < 1e-3  # the test can tell
    mj = load_scenario(MJ)
    M = np.array([randomize.draw(override(mj, **{"run.seed": s})).values["M"]
                  for s in range(300)])
    assert stats.kstest(M, stats.uniform(8.0, 4.0).cdf).pvalue > 1e-3
    assert M.min() >= 8.0 and M.max() <= 12.0


# -- bad tables ------------------------------------------------------------------------------
MJ_TEXT = (ROOT / "scenarios" / f"{MJ}.toml").read_text()
M_LINE = 'M = {dist = "uniform", low = 0.8, high = 1.2, relative = true}'

BAD = [
    ("unknown key", M_LINE, 'mass = {dist = "uniform", low = 1.0, high = 2.0}',
     ["randomize.mass", "unknown key", "allowed", "gear", "x0"]),
    ("not a parameter", M_LINE, 'model = {dist = "uniform", low = 1.0, high = 2.0}',
     ["randomize.model", "unknown key"]),
    ("unknown distribution", M_LINE, 'M = {dist = "gauss", low = 0.8, high = 1.2}',
     ["randomize.M.dist", "'gauss' is not allowed", "uniform, normal"]),
    ("low above high", M_LINE, 'M = {dist = "uniform", low = 1.2, high = 0.8}',
     ["randomize.M.low", "must be < high"]),
    ("key of the other distribution", M_LINE, 'M = {dist = "uniform", mean = 1.0, std = 0.1}',
     ["randomize.M.mean", "unknown key", "for dist 'uniform'"]),
    ("negative mass", M_LINE, 'M = {dist = "uniform", low = -1.0, high = 12.0}',
     ["randomize.M.low", "M must be > 0", "-1"]),
    ("untruncated normal on a mass", M_LINE, 'M = {dist = "normal", mean = 10.0, std = 1.0}',
     ["randomize.M.dist", "M must be > 0", "give low"]),
    ("zero std", M_LINE, 'M = {dist = "normal", mean = 10.0, std = 0.0, low = 5.0}',
     ["randomize.M.std", "> 0"]),
    ("not a table", M_LINE, "M = 3.0", ["randomize.M", "must be a table"]),
    ("x0 length", '{dist = "uniform", low = -0.1, high = 0.1}]',
     '{dist = "uniform", low = -0.1, high = 0.1}, {}]', ["randomize.x0", "list of 2 tables"]),
    ("relative on a zero nominal", M_LINE,
     'cart_damping = {dist = "uniform", low = 0.5, high = 2.0, relative = true}',
     ["randomize.cart_damping.relative", "is 0"]),
]


@pytest.mark.parametrize("name,old,new,words", BAD, ids=[b[0] for b in BAD])
def test_bad_randomize_table_exits_2_naming_file_and_key(tmp_path, capsys, name, old, new, words):
    assert old in MJ_TEXT
    path = tmp_path / "bad.toml"
    path.write_text(MJ_TEXT.replace(old, new, 1))
    status = main(["run", str(path), "--no-record", "--duration", "0.01"])
    err = capsys.readouterr().err.strip()
    assert status == 2, err
    assert len(err.splitlines()) == 1, err
    assert str(path) in err or "bad.toml" in err
    for w in words:
        assert w in err, (w, err)


def test_run_seeds_draw_different_machines(tmp_path):
    import json

    docs = []
    for seed in (0, 1):
        out = tmp_path / f"m{seed}.json"
        assert main(["run", MJ, "--seed", str(seed), "--duration", "0.5", "--no-record",
                     "--metrics", str(out)]) == 0
        docs.append(json.loads(out.read_text()))
    assert docs[0]["drawn"] and docs[1]["drawn"] and docs[0]["drawn"] != docs[1]["drawn"]
    assert set(docs[0]["drawn"]) == set(docs[1]["drawn"])
    assert not math.isclose(docs[0]["drawn"]["m"], docs[1]["drawn"]["m"])


def test_furuta_draws_its_initial_state_on_both_backends():
    """The Furuta reads its machine from the MJCF: x0 drawn on both backends, a key that is
    neither its [plant]'s nor a model's number refused (the model's numbers are drawn in
    tests/test_randomize_articulated.py)."""
    from tspend.scenario import parse_scenario

    text = (ROOT / "scenarios" / "furuta_mujoco.toml").read_text() + (
        '\n[randomize]\nx0 = [{dist = "uniform", low = -0.1, high = 0.1}, {}]\n')
    scn = override(parse_scenario(text, "furuta.toml"), **{"run.seed": 2})
    drawn = randomize.draw(scn).values
    assert set(drawn) == {"x0[0]"} and -0.1 <= drawn["x0[0]"] <= 0.1
    for kind in ("furuta_mujoco", "furuta_ode"):
        s = dict(zip(*(lambda p: (p.state_names, p.full_state()))(build_plant(scn, kind))))
        assert s["pendulum"] == drawn["x0[0]"] and s["pendulum_dot"] == scn.plant.x0[1]
    with pytest.raises(Exception, match="randomize.m: unknown key"):
        parse_scenario(text.replace("[randomize]\n", '[randomize]\nm = {dist = "uniform", '
                                    'low = 0.1, high = 0.2}\n'), "furuta.toml")


def test_draw_values_are_each_seeds_draw():
    """The draw of many seeds as arrays (the MJX backend's machines) is, seed by seed, the
    CPU backend's: numpy's seeded Generator computed for all seeds at once, and the
    per-seed path for seeds beyond 32 bits."""
    import numpy as np

    from tspend.plants.randomize import _rng, draw, draw_values, first_uniforms
    from tspend.scenario import load_scenario, override

    seeds = np.concatenate([np.arange(300), [2**31, 2**32 - 1, 2**32, 2**40]])
    got = first_uniforms(seeds, "x0[1]")
    want = np.array([_rng(int(s), "x0[1]").random() for s in seeds])
    assert np.array_equal(got, want)
    for name in ("pendulum_mujoco_randomized", "double_cartpole_mujoco_randomized"):
        scn = load_scenario(name)
        values = draw_values(scn, [0, 5, 77, 2**32 + 3])
        for i, seed in enumerate([0, 5, 77, 2**32 + 3]):
            one = draw(override(scn, **{"run.seed": seed})).values
            assert list(one) == list(values)
            assert all(one[k] == values[k][i] for k in one), (name, seed)
