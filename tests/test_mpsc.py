"""The predictive safety filter (--safety mpsc, tspend/controllers/mpsc.py) and honest
violation counting, against independent computations: scipy's solve_ivp of the plan the
filter certified, boundary points of the terminal ellipsoid, a bare run that crosses."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("casadi")

from tspend import load_scenario, override, run  # noqa: E402
from tspend.errors import ScenarioError  # noqa: E402


def _filter(**changes):
    from tspend.loop.simulation import prepare

    scn = override(load_scenario("pendulum_finite_rail"),
                   **{"effects.rail": 1.0, "safety.filter": "mpsc", **changes})
    f = prepare(scn, controller="pd").controller
    f._rows = (np.arange(f.model.size),)
    return f


def test_terminal_level_is_the_largest_ellipsoid_inside_the_rows():
    from tspend.controllers.mpsc import terminal_level

    rng = np.random.default_rng(1)
    M = rng.normal(size=(3, 3))
    P = M @ M.T + 3 * np.eye(3)
    rows = [(np.array([1.0, 0.0, 0.0]), 0.7), (np.array([0.3, -1.0, 0.5]), 2.0)]
    c = terminal_level(P, rows)
    # boundary points s = sqrt(c) d / |d|_P: the largest a.s over them reaches b for the
    # binding row and never exceeds any
    d = rng.normal(size=(200000, 3))
    pts = math.sqrt(c) * d / np.sqrt(np.einsum("ij,jk,ik->i", d, P, d))[:, None]
    reach = [float((pts @ a).max()) for a, _ in rows]
    assert all(r <= b + 1e-9 for r, (_, b) in zip(reach, rows))
    assert max(r / b for r, (_, b) in zip(reach, rows)) == pytest.approx(1.0, abs=2e-3)


def _solve_plan(f, s, plan):
    """The certified plan (P5) integrated by scipy: each interval's input, the LQR
    correction at its start held over it; the states every millisecond."""
    from scipy.integrate import solve_ivp

    U, R = plan
    x, out = np.array(s, dtype=float), [np.array(s, dtype=float)]
    for k in range(f.N):
        T = f.dt0 if k == 0 else f.h
        u = U[0] if k == 0 else min(max(float(U[k] - f.K @ (x - R[:, k])), f.u_lo), f.u_hi)
        sol = solve_ivp(lambda t, y: f.model.rhs(y, u), (0.0, T), x, rtol=1e-10, atol=1e-12,
                        t_eval=np.linspace(0.0, T, max(2, int(round(T / 1e-3)) + 1)))
        x = sol.y[:, -1]
        out.append(sol.y.T)
    return np.vstack(out[1:]), x


@pytest.mark.parametrize("u_c", [0.0, 2000.0])
def test_the_certified_plan_keeps_the_rail_and_ends_in_the_ellipsoid_by_scipy(u_c):
    f = _filter()
    # moving towards the rail's end at 0.5 m/s: one sample of either command can still be
    # followed by a plan that brakes in time and catches the pole
    s = np.array([0.3, 0.0, 0.5, 0.0])
    u, _ = f.filter(s, u_c)
    assert f.plan is not None and u == u_c           # certified: passed unchanged
    states, end = _solve_plan(f, s, f.plan)
    # scipy at 1 ms keeps what the certificate checked at its RK4 steps (the rail less
    # 4 % of its half-width, the fall angle less 5 %), to its integration's difference
    assert np.abs(states[:, 0]).max() <= 0.96 + 1e-3
    assert np.abs(states[:, 1]).max() < f.hi[1]
    assert end @ f.P @ end <= f.level * (1 + 1e-3)


def test_round_off_past_a_soft_bound_is_not_a_violation():
    from tspend.controllers.full_model import full_model_and_constraints
    from tspend.loop.simulation import nominal_machine

    scn = override(load_scenario("pendulum_mujoco"), **{"effects.rail": 1.0})
    model, cs = full_model_and_constraints(scn, nominal_machine(scn))
    s = np.zeros(model.size)
    assert cs.violated(s, model.u_hi + 1.6e-10) == ()
    assert cs.violated(s, model.u_hi + 1e-3) == ("force_range",)


def test_mpsc_completes_where_bare_pd_reaches_the_rail():
    changes = {"effects.rail": 1.0, "run.duration": 2.5}
    bare = run(override(load_scenario("pendulum_finite_rail"), **changes), controller="pd",
               keep_history=False)
    assert bare.status == "rail_end"
    safe = run(override(load_scenario("pendulum_finite_rail"),
                        **{**changes, "safety.filter": "mpsc"}), controller="pd",
               keep_history=False)
    assert safe.status == "completed"
    assert safe.metrics["violations"] == 0
    sf = safe.metrics["safety_filter"]
    assert sf["filter"] == "mpsc" and sf["samples"] == 2500
    assert 0.0 < sf["intervention_share"] < 1.0


@pytest.mark.parametrize("key,value", [("horizon", 500), ("substeps", 99), ("plan_period", 3.0)])
def test_plan_sizes_are_bounded(key, value):
    with pytest.raises(ScenarioError, match=f"safety.{key}"):
        override(load_scenario("pendulum_finite_rail"), **{f"safety.{key}": value})
