"""``mpc``'s real-time schemes (rti, sqp) against its IPOPT reference on the same OCP."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from mpc_plans import run_keeping_plans
from tspend import load_scenario, override, run
from tspend.cli.main import main
from tspend.loop.simulation import build_controller


def build(scenario, kind):
    """The kind as the runner builds it: designed on the nominal machine."""
    return build_controller(scenario, kind=kind)


warnings.simplefilter("ignore")


def _pair(name: str, **settings):
    s = override(load_scenario(name), **{"controllers.mpc.horizon": 10, **settings})
    ipopt = build(override(s, **{"controllers.mpc.scheme": "ipopt",
                                 "controllers.mpc.tolerance": 1e-10}), "mpc")
    return s, ipopt


@pytest.mark.parametrize("solver", ["hpipm", "qrqp"])
def test_sqp_iterated_converges_to_ipopts_solution(solver):
    # a tilt far enough that the input's bound is active on the first intervals: the
    # QP's inequalities, not only its equalities, are checked against IPOPT's KKT point
    s, ipopt = _pair("ex3_pendulum_ode", **{"effects.saturation": 60.0})
    sqp = build(override(s, **{"controllers.mpc.scheme": "sqp", "controllers.mpc.solver": solver,
                               "controllers.mpc.sqp_iterations": 40,
                               "controllers.mpc.tolerance": 1e-10}), "mpc")
    state = np.array([0.1, 0.35, 0.0, 0.5])      # cart, pole, their rates
    ref = np.array([0.0, 1.0, 0.0])
    u_ipopt, ok_ipopt, _ = ipopt.solve(state, ref)
    u_sqp, ok_sqp, _ = sqp.solve(state, ref)
    assert ok_ipopt and ok_sqp
    assert np.isclose(np.abs(ipopt.plan_inputs).max(), 60.0, atol=1e-6)   # the bound is active
    assert sqp.diag[3] < 40                                                # it converged
    np.testing.assert_allclose(sqp.plan_inputs, ipopt.plan_inputs, atol=1e-5 * 60.0)
    np.testing.assert_allclose(sqp.plan_states, ipopt.plan_states, atol=1e-6)


def test_one_rti_step_moves_toward_ipopts_solution_and_compiled_equals_the_vm():
    s, ipopt = _pair("pendulum_mujoco")
    fast = build(override(s, **{"controllers.mpc.scheme": "rti"}), "mpc")
    slow = build(override(s, **{"controllers.mpc.scheme": "rti",
                                "controllers.mpc.compiled": False}), "mpc")
    assert fast.rti.compiled and not slow.rti.compiled
    state, ref = np.array([0.2, 0.15, -0.1, 0.3]), np.array([0.05, 0.0, 0.0])
    ipopt.solve(state, ref)
    fast.solve(state, ref)
    slow.solve(state, ref)
    # the generated C and CasADi's virtual machine: the same numbers to rounding
    np.testing.assert_allclose(fast.z, slow.z, rtol=1e-9, atol=1e-9)
    # a second state from the first's shifted plan: one step gets u within 1e-3 of the
    # converged solution's (the Gauss-Newton step from a near-optimal point)
    nxt = fast.plan_states[:, 1] + np.array([0.0, 0.01, 0.0, 0.0])
    ipopt.solve(nxt, ref)
    u_fast, ok, _ = fast.solve(nxt, ref)
    assert ok and fast.diag[3] == 1.0
    assert abs(u_fast - ipopt.plan_inputs[0]) < 1e-3 * max(1.0, abs(ipopt.plan_inputs[0]))


@pytest.mark.parametrize("scheme", ["rti", "sqp"])
def test_closed_loop_cost_within_5_percent_of_ipopts(scheme):
    base = {"run.duration": 1.0, "controllers.mpc.horizon": 10}
    s_ipopt = override(load_scenario("pendulum_mujoco"), **base)
    s_fast = override(s_ipopt, **{"controllers.mpc.scheme": scheme})
    a, b = run(s_ipopt, controller="mpc"), run(s_fast, controller="mpc")
    assert a.status == b.status == "completed"
    assert b.metrics["counters"]["solve_failures"] == 0
    c, dt = b.controller, s_fast.run.dt
    j_ipopt = c.running_cost(a.history["state"], a.history["ref"], a.history["u"], dt)
    j_fast = c.running_cost(b.history["state"], b.history["ref"], b.history["u"], dt)
    assert j_ipopt > 0.0 and abs(j_fast / j_ipopt - 1.0) < 0.05


def test_rti_keeps_the_rail_and_the_actuators_range(monkeypatch):
    s = override(load_scenario("ex3_pendulum_ode"),
                 **{"run.duration": 1.0, "effects.rail": 1.2, "effects.saturation": 150.0,
                    "controllers.mpc.horizon": 15, "controllers.mpc.scheme": "rti"})
    r, plans = run_keeping_plans(monkeypatch, s)
    assert r.status == "completed", r.end.message
    assert len(plans) == 50
    tol = 1e-6
    for S, U, lo, hi in plans:
        # the first state is the measured one (no bound on it); the predicted ones are bounded
        assert np.all(S[0, 1:] >= lo[0] - tol) and np.all(S[0, 1:] <= hi[0] + tol)
        assert np.all(np.abs(U) <= 150.0 + tol)
    assert np.abs(r.history["state"][:, 0]).max() < 1.2
    assert np.abs(r.history["u"]).max() <= 150.0 + tol


@pytest.mark.parametrize("key, value, expect", [
    ("controllers.mpc.scheme", '"fast"', "controllers.mpc.scheme"),
    ("controllers.mpc.solver", '"fatrop"', "qrqp, hpipm, daqp, osqp"),
])
def test_bad_scheme_or_solver_is_one_line_exit_2(key, value, expect, capsys):
    assert main(["run", "pendulum_mujoco", "--controller", "mpc", "--set", f"{key}={value}",
                 "--no-record", "--duration", "0.01"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expect in err[0], err


@pytest.mark.parametrize("solver", ["qrqp", "hpipm"])
def test_an_infeasible_qp_is_a_counted_failure_not_a_plan(solver):
    # 5 m/s toward the rail with 1 N: no input keeps the cart inside, so the QP has no
    # solution; its answer must be refused by the infeasibility check, and counted
    s = override(load_scenario("ex3_pendulum_ode"),
                 **{"effects.rail": 1.2, "effects.saturation": 1.0, "controllers.mpc.horizon": 10,
                    "controllers.mpc.scheme": "rti", "controllers.mpc.solver": solver})
    c = build(s, "mpc")
    u, ok, _ = c.solve(np.array([1.1, 0.0, 5.0, 0.0]), np.zeros(3))
    assert not ok and np.isnan(u) and c.z is None
    u = c.act(np.array([1.1, 0.0, 5.0, 0.0]), np.zeros(3))
    assert c.failures == 1 and abs(u) <= 1.0 and c.diag[1] == 1.0
    # a feasible state afterwards starts cold and succeeds
    u, ok, _ = c.solve(np.array([0.0, 0.05, 0.0, 0.0]), np.zeros(3))
    assert ok and abs(u) <= 1.0 + 1e-9
