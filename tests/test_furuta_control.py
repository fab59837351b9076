"""Issue 20 on the second domain: swing-up and MPC on the Furuta pendulum, from the domain's
own model (the equations derived from models/furuta.xml), against independent checks.

* the symbolic (CasADi) equations the MPC optimises over equal the numeric ones the plant
  steps, and MuJoCo's own accelerations of models/furuta.xml;
* swing-up: the energy the arm puts in is never negative before the catch (the rate
  of the domain's energy along the model's flow, at the applied voltage, against the
  rate at zero arm acceleration), the sampled energy rises to the catch, the pendulum
  ends upright; the scenario holds the arm within its range and the motor within 10 V;
* MPC: the arm's range and the voltage bound hold in every predicted trajectory and in
  the simulated one, and the bound is active;
* the sweep summary reports a run the task ended by its status, not as diverged.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tspend import load_scenario, override, run
from tspend.controllers.full_model import full_model, wrap_angle
from tspend.loop.simulation import nominal_machine
from mpc_plans import run_keeping_plans


def energy_rate(model, s, u, h=1e-6):
    """``dE/dt = grad E . s'(s, u)``: the domain's energy along the model's flow."""
    f = model.rhs(s, u)
    return (model.energy(s + h * f) - model.energy(s - h * f)) / (2 * h)


def test_symbolic_furuta_equations_are_the_numeric_ones_and_mujocos():
    casadi = pytest.importorskip("casadi")
    import mujoco

    s = load_scenario("furuta_mujoco")
    model = full_model(s, nominal_machine(s))
    f = model.symbolic()
    x, u = casadi.SX.sym("x", 4), casadi.SX.sym("u")
    F = casadi.Function("F", [x, u], [f(x, u)])
    mj = mujoco.MjModel.from_xml_path("models/furuta.xml")
    data = mujoco.MjData(mj)
    rng = np.random.default_rng(3)
    for _ in range(20):
        st = rng.uniform([-2, -math.pi, -8, -15], [2, math.pi, 8, 15])
        volts = float(rng.uniform(-10, 10))
        sym = np.asarray(F(st, volts)).ravel()
        np.testing.assert_allclose(sym, model.rhs(st, volts), rtol=1e-12, atol=1e-12)
        data.qpos[:], data.qvel[:], data.ctrl[:] = st[:2], st[2:], volts
        mujoco.mj_forward(mj, data)
        np.testing.assert_allclose(sym[2:], data.qacc, rtol=1e-9, atol=1e-9)


def test_furuta_swingup_energy_rises_until_the_catch():
    # the arm's range off (the scenario's bound and the domain's default stop at the
    # cable), as on the cart-pole: braking at a range's end may take energy out
    s = override(load_scenario("furuta_swingup"), **{"task.state_bounds": {},
                                                     "task.joint_limits": False,
                                                     "run.duration": 5.0})
    r = run(s)
    assert r.controller.kind == "swingup" and r.status == "completed", r.end.message
    h = r.history
    caught = int(np.argmax(h["mode"] > 0.5))
    assert caught > 0 and h["t"][caught] < 4.0
    model = full_model(s, nominal_machine(s))
    state, u = h["state"][:caught], h["u"][:caught]
    # E' is affine in u: what the input adds is E'(u) - E'(u_0), u_0 the voltage that
    # leaves the arm unaccelerated; the law never takes energy out
    added = []
    for st, uk in zip(state, u):
        a0, du = model.input_map(st)
        u0 = -a0[model.actuated] / du[model.actuated]
        added.append(energy_rate(model, st, uk) - energy_rate(model, st, u0))
    added = np.array(added)
    assert added.min() >= -1e-9 * np.abs(added).max()
    E = h["energy"][:caught]
    mgl = -0.5 * E[0]                           # hanging at rest: E = -2 m g l
    assert E[0] == pytest.approx(model.energy(np.array([0.0, math.pi, 0.0, 0.0])))
    # sampled, E dips only by what the pendulum's damping and the arm's centrifugal pull
    # take out over a sample: a small fraction of m g l, and it ends at the upright's
    assert np.diff(E).min() > -0.005 * mgl
    assert np.maximum.accumulate(E)[-1] > -0.1 * mgl and E[-1] > -0.1 * mgl
    assert abs(wrap_angle(h["state"][-1, 1])) < 0.05
    assert np.abs(h["e"][:, 0]).max() <= math.pi + 1e-12      # the wrapped error


def test_furuta_swingup_scenario_keeps_the_arm_and_the_motor_in_range():
    r = run(load_scenario("furuta_swingup"))
    assert r.status == "completed", r.end.message
    assert r.metrics["rmse_ss"] < 1e-3
    assert r.metrics["joints"]["arm"]["max_abs"] < 2.356
    assert np.abs(r.history["u"]).max() <= 10.0 + 1e-12
    # one catch: the hysteresis holds it
    assert np.count_nonzero(np.diff(r.history["mode"])) == 1


def test_mpc_on_furuta_holds_the_arm_range_and_the_voltage(monkeypatch):
    pytest.importorskip("casadi")
    s = override(load_scenario("furuta_mujoco"),
                 **{"run.duration": 0.4, "plant.x0": [0.3, 0.0], "task.state_bounds": {"arm": 1.5},
                    "controllers.mpc.horizon": 15})
    r, plans = run_keeping_plans(monkeypatch, s)
    assert r.status == "completed", r.end.message
    assert len(plans) == 20 and r.history["solve_failures"][-1] == 0
    tol = 1e-6
    for S, U, lo, hi in plans:
        assert lo[0] == pytest.approx(-1.45) and hi[0] == pytest.approx(1.45)  # 1.5 - margin
        assert np.all(S[0] >= lo[0] - tol) and np.all(S[0] <= hi[0] + tol)
        assert np.all(np.abs(U) <= 10.0 + tol)
    h = r.history
    assert np.abs(h["state"][:, 0]).max() < 1.5
    assert np.abs(h["u"]).max() <= 10.0 + tol
    # the range was active: the plans lean on it (unconstrained, the arm swings 2.3 rad)
    assert max(np.abs(S[0]).max() for S, *_ in plans) > 1.45 - 1e-3


def test_sweep_summary_reports_terminations_by_status():
    import pandas as pd

    from tspend.cli.sweep import summary

    frame = pd.DataFrame({"scenario": ["a"] * 4, "controller": ["pd"] * 4,
                          "status": ["completed", "fell", "rail_end", "diverged"],
                          "rmse_ss": [0.1, math.inf, math.inf, math.inf]})
    row = summary(frame, []).iloc[0]
    assert (row["completed"], row["fell"], row["rail_end"], row["diverged"]) == (1, 1, 1, 1)
    assert "joint_limit" not in row.index      # only the terminations that occurred


def test_the_kinds_table_in_the_docs_is_the_declarations():
    from pathlib import Path

    from tspend.controllers import kinds_table

    text = (Path(__file__).resolve().parents[1] / "docs" / "controllers.md").read_text()
    begin, end = "<!-- kinds x domains: begin -->", "<!-- kinds x domains: end -->"
    block = text[text.index(begin) + len(begin):text.index(end)].strip()
    assert block == kinds_table()
    # and the table says what the refusals do: mpc on the chains, swingup too
    assert "| `mpc` |" in block and "no (full_state, symbolic_model)" in block
