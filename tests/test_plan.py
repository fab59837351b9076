"""Planned swing-ups (issue 29): the transcription's plan against an independent integration
(scipy's solve_ivp of the domain's numeric equations), its bounds, the plan file, the
``tspend plan`` command's exits, and ``tvlqr`` following a plan on MuJoCo."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

pytest.importorskip("casadi")

from tspend.cli.main import main  # noqa: E402
from tspend.controllers.full_model import full_model  # noqa: E402
from tspend.loop.simulation import nominal_machine  # noqa: E402
from tspend.controllers.trajectory import (PlanFailed, plan_swingup, read_plan,  # noqa: E402
                                           write_plan)
from tspend.loop.simulation import run  # noqa: E402
from tspend.scenario import load_scenario, override  # noqa: E402

#: the single cart-pole hanging at rest (models/cartpole.xml: a 3 m pole, +/-2000 N, +/-8 m)
SCENARIO = "swingup_mujoco"
HORIZON, INTERVAL, STEP = 1.6, 0.02, 0.01


@pytest.fixture(scope="module")
def planned():
    scn = load_scenario(SCENARIO)
    model = full_model(scn, nominal_machine(scn))
    s0 = np.array([0.0, math.pi, 0.0, 0.0])
    plan = plan_swingup(model, s0, HORIZON, INTERVAL, scn.run.dt, step=STEP, margin=0.05,
                        units=(("m", "rad", "m/s", "rad/s"), "force", "N"))
    return scn, model, s0, plan


def test_plan_reaches_the_upright_within_its_bounds(planned) -> None:
    scn, model, s0, plan = planned
    assert plan.solver["success"] and plan.solver["status"] == "Solve_Succeeded"
    assert np.array_equal(plan.states[0], s0) and plan.t[-1] == pytest.approx(HORIZON)
    assert np.abs(plan.states[-1]).max() < 1e-8                 # the upright at rest
    assert np.all(plan.u <= model.u_hi + 1e-9) and np.all(plan.u >= model.u_lo - 1e-9)
    rail = model.q_hi[0] - 0.05
    assert np.abs(plan.states[:, 0]).max() <= rail + 1e-9
    # held over each interval: piecewise constant on the shooting grid
    per = int(round(INTERVAL / scn.run.dt))
    assert np.all(plan.u[:-1].reshape(-1, per) == plan.u[:-1:per][:, None])


def test_plan_satisfies_the_dynamics_by_solve_ivp(planned) -> None:
    """Each interval integrated by scipy (DOP853, tight tolerances) from the plan's node
    with its held input lands on the plan's next node: the planner's RK4 at 10 ms is
    within 1e-6 of the exact flow on this machine."""
    scn, model, _, plan = planned
    per = int(round(INTERVAL / scn.run.dt))
    worst = 0.0
    for k in range(0, plan.t.size - 1, per):
        u = float(plan.u[k])
        sol = solve_ivp(lambda t, s: model.rhs(s, u), (0.0, INTERVAL), plan.states[k],
                        method="DOP853", rtol=1e-12, atol=1e-12)
        worst = max(worst, float(np.abs(sol.y[:, -1] - plan.states[k + per]).max()))
    assert worst < 1e-6


def test_plan_file_round_trip(planned, tmp_path) -> None:
    import pyarrow.parquet as pq

    *_, plan = planned
    path = tmp_path / "p.parquet"
    write_plan(plan, path)
    back = read_plan(path)
    assert back.state_names == ("slider", "hinge", "slider_dot", "hinge_dot")
    assert np.array_equal(back.states, plan.states) and np.array_equal(back.u, plan.u)
    schema = pq.read_schema(path)
    assert schema.field("hinge").metadata[b"unit"] == b"rad"
    assert schema.field("u").metadata[b"unit"] == b"N"
    assert back.solver["iterations"] == plan.solver["iterations"] > 0


def test_a_horizon_no_input_can_meet_fails_and_says_so(planned) -> None:
    scn, model, s0, _ = planned
    with pytest.raises(PlanFailed, match="IPOPT found no plan"):
        plan_swingup(model, s0, 0.1, INTERVAL, scn.run.dt, step=STEP, max_iter=30)


def test_tvlqr_follows_the_plan_on_mujoco(planned, tmp_path) -> None:
    scn, model, s0, plan = planned
    path = tmp_path / "p.parquet"
    write_plan(plan, path)
    run_scn = override(scn, **{"run.duration": HORIZON + 1.0, "task.goal_by": HORIZON + 0.5,
                               "controllers.tvlqr.plan": str(path)})
    result = run(run_scn, controller="tvlqr")
    assert result.status == "completed", result.end.message
    h = result.history
    n = plan.t.size - 1
    following = h["mode"][:n] == 0.0
    assert following.all() and (h["mode"][n:] == 1.0).all()
    # MuJoCo's RK4 at 1 ms against the plan's at 10 ms: TVLQR holds it close to the plan
    err = np.abs(h["state"][:n] - plan.states[:n])
    assert err.max() < 1e-3
    assert np.abs(h["state"][-1]).max() < 1e-3


def test_plan_command_exits(tmp_path) -> None:
    out = tmp_path / "p.parquet"
    args = ["plan", SCENARIO, "--out", str(out), "--set", "controllers.tvlqr.horizon=0.02"]
    assert main(args) == 2 and not out.exists()        # shorter than 2 intervals
    args = ["plan", SCENARIO, "--out", str(out), "--set", "controllers.tvlqr.horizon=0.1",
            "--set", "controllers.tvlqr.max_iter=20"]
    assert main(args) == 1 and not out.exists()        # the solver found none
    assert main(["plan", "ex2_duffing", "--out", str(out)]) == 2 and not out.exists()
    args = ["plan", SCENARIO, "--out", str(out), "--set", "controllers.tvlqr.horizon=1.6",
            "--metrics", str(tmp_path / "m.json")]
    assert main(args) == 0 and read_plan(out).t.size == 1601


def test_the_batched_matrix_exponential_is_scipys() -> None:
    from scipy.linalg import expm

    from tspend.controllers.tvlqr import expm_stack

    rng = np.random.default_rng(3)
    M = rng.normal(size=(5, 7, 7)) * np.array([0.01, 0.1, 1.0, 3.0, 10.0])[:, None, None]
    got = expm_stack(M)
    for k in range(5):
        want = expm(M[k])
        assert np.abs(got[k] - want).max() <= 1e-12 * max(1.0, np.abs(want).max())


def test_a_plan_on_the_run_step_is_what_mujoco_does_open_loop() -> None:
    """With the planner's RK4 step equal to run.dt, the plan's inputs applied open loop to
    the MuJoCo plant (RK4 at 1 ms) give the plan's states: the planner's model is the
    simulated machine (the gap is IPOPT's constraint tolerance, grown along the swing)."""
    from tspend.loop.simulation import build_plant

    scn = load_scenario(SCENARIO)
    s0 = np.array([0.0, math.pi, 0.0, 0.0])
    plan = plan_swingup(full_model(scn, nominal_machine(scn)), s0, HORIZON, INTERVAL, scn.run.dt, step=scn.run.dt)
    plant = build_plant(scn)
    plant.reset(np.array([math.pi, 0.0]))
    assert np.array_equal(plant.full_state(), s0)
    worst = 0.0
    for k in range(plan.t.size - 1):
        plant.step(float(plan.u[k]), 0.0, scn.run.dt)
        worst = max(worst, float(np.abs(plant.full_state() - plan.states[k + 1]).max()))
    assert worst < 1e-7


def _small_plan(**change) -> "Plan":
    from tspend.controllers.trajectory import Plan

    n, dt = 5, 0.001
    t = dt * np.arange(n)
    fields = dict(t=t, states=np.zeros((n, 4)), u=np.zeros(n),
                  state_names=("slider", "hinge", "slider_dot", "hinge_dot"),
                  state_units=("m", "rad", "m/s", "rad/s"), u_name="force", u_unit="N",
                  dt=dt, interval=0.002)
    fields.update(change)
    return Plan(**fields)


@pytest.mark.parametrize("label,change,phrase", [
    ("t backwards", {"t": 0.001 * np.arange(5)[::-1]}, "t does not increase at row 1"),
    ("t repeated", {"t": np.array([0.0, 0.001, 0.001, 0.002, 0.003])}, "t does not increase"),
    ("NaN in u", {"u": np.array([0.0, 1.0, np.nan, 0.0, 0.0])}, "column u holds nan at row 2"),
    ("inf in a state", {"states": np.where(np.eye(5, 4) > 0, np.inf, 0.0)},
     "column slider holds inf at row 0"),
    ("0 rows", {"t": np.zeros(0), "states": np.zeros((0, 4)), "u": np.zeros(0)}, "0 rows"),
    ("1 row", {"t": np.zeros(1), "states": np.zeros((1, 4)), "u": np.zeros(1)}, "1 rows"),
    ("off its step", {"t": np.array([0.0, 0.001, 0.005, 0.006, 0.007])}, "not on its step"),
])
def test_a_bad_plan_file_is_refused_on_load(tmp_path, label, change, phrase) -> None:
    from tspend.runtime.errors import ScenarioError

    path = tmp_path / "bad.parquet"
    write_plan(_small_plan(**change), path)
    with pytest.raises(ScenarioError, match=phrase):
        read_plan(path)
    write_plan(_small_plan(), tmp_path / "good.parquet")
    assert read_plan(tmp_path / "good.parquet").t.size == 5


def test_run_refuses_a_plan_running_backwards_with_exit_2(tmp_path, capsys) -> None:
    path = tmp_path / "bad.parquet"
    write_plan(_small_plan(t=0.001 * np.arange(5)[::-1]), path)
    rec = tmp_path / "r.rrd"
    status = main(["run", SCENARIO, "--controller", "tvlqr", "--duration", "0.01", "--set",
                   f"controllers.tvlqr.plan={str(path)!r}".replace("'", '"'), "--out", str(rec)])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "t does not increase" in err[0], err
    assert not rec.exists()
