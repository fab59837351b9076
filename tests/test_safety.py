"""Constraints of the task, violation metrics and the CBF safety filter (docs/safety.md).

Checked against independent references: margins against the boxes written out by hand,
violation counts against the recorded history, the filter's QP against scipy.optimize on
the same problem, its barrier rows against h'' measured along a solve_ivp trajectory of the
model, and a filtered run against the unfiltered one on the same short rail.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import minimize

from tspend.controllers.base import Observation
from tspend.controllers.safety import SafetyFilter, barrier_rows
from tspend.runtime.errors import ScenarioError
from tspend.loop.simulation import prepare, run
from tspend.scenario import load_scenario, override

RAIL = {"effects.rail": 1.0}


def _scenario(**changes):
    return override(load_scenario("ex3_pendulum_ode"), **{"run.duration": 2.0, **changes})


@pytest.mark.parametrize("changes, key", [
    ({"task.constraints.box.nope": {"hi": 1.0}}, "task.constraints.box.nope"),
    ({"task.constraints.box.force": {"lo": -1.0, "hi": 1.0, "hard": True}},
     "task.constraints.box.force.hard"),
    ({"task.constraints.box.slider": {"lo": 1.0, "hi": 0.5}}, "task.constraints.box.slider.hi"),
    ({"task.constraints.linear.c": {"terms": {"slider": 1.0}}}, "task.constraints.linear.c"),
    ({"task.constraints.linear.c": {"terms": {"slider": 1.0, "zz": 1.0}, "max": 1.0}},
     "task.constraints.linear.c.terms.zz"),
    ({"task.constraints.extra": 1}, "task.constraints.extra"),
    ({"safety.solver": "gurobi"}, "safety.solver"),
    ({"safety.alpha_1": 0.0}, "safety.alpha_1"),
    ({"safety.barrier": "cbf"}, "safety.barrier"),
    ({"safety.margin": 1.0}, "safety.margin"),
])
def test_bad_constraints_and_safety_settings_name_the_key(changes, key):
    with pytest.raises(ScenarioError) as err:
        prepare(_scenario(**changes), controller="pd")
    msg = str(err.value)
    assert key in msg and "ex3_pendulum_ode" in msg and "\n" not in msg


def test_margins_are_the_boxes_and_inequalities_written_out():
    scn = _scenario(**RAIL, **{
        "effects.saturation": 500.0,
        "task.constraints.box.hinge_dot": {"lo": -0.5, "hi": 2.0},
        "task.constraints.linear.stop": {"terms": {"slider": 1.0, "slider_dot": 0.5, "u": 0.001},
                                         "max": 0.9}})
    cs = prepare(scn, controller="pd").task.constraints
    assert cs.constraint_names == ("rail", "force_range", "hinge_dot", "stop")
    assert [c.hard for c in cs] == [True, False, False, False]
    rng = np.random.default_rng(3)
    S = rng.normal(scale=1.5, size=(50, 4))
    u = rng.normal(scale=900.0, size=50)
    m = cs.margins(S, u)
    x, hd, xd = S[:, 0], S[:, 3], S[:, 2]
    np.testing.assert_allclose(m[:, 0], np.minimum(1.0 - x, x + 1.0))
    np.testing.assert_allclose(m[:, 1], np.minimum(500.0 - u, u + 500.0))  # the saturation
    np.testing.assert_allclose(m[:, 2], np.minimum(2.0 - hd, hd + 0.5))
    np.testing.assert_allclose(m[:, 3], 0.9 - (x + 0.5 * xd + 0.001 * u))


def test_a_hard_box_ends_the_run_as_constraint_and_a_soft_one_is_counted():
    hard = run(_scenario(**{"task.constraints.box.hinge_dot": {"lo": -0.01, "hi": 0.01,
                                                                "hard": True}}),
               controller="pd")
    assert hard.status == "constraint" and "task.constraints.box.hinge_dot" in hard.end.message
    soft = run(_scenario(**{"task.constraints.box.hinge": {"lo": -0.02, "hi": 0.02}}),
               controller="pd")
    assert soft.status == "completed"
    hinge = soft.history["state"][:, 1]
    outside = (hinge > 0.02) | (hinge < -0.02)
    got = soft.metrics["constraints"]["hinge"]
    assert got["samples_outside"] == outside.sum() > 0
    assert soft.metrics["violations"] >= outside.sum()
    assert got["time_outside_s"] == pytest.approx(outside.sum() * 0.001)
    assert got["max_depth"] == pytest.approx(np.max(np.abs(hinge) - 0.02))
    assert got["min_margin"] == pytest.approx(np.min(0.02 - np.abs(hinge)))
    # the compiled loop (pd has one) and the generic one measure the same
    generic = run(_scenario(**{"task.constraints.box.hinge": {"lo": -0.02, "hi": 0.02}}),
                  controller="pd", compiled=False, keep_history=False)
    assert generic.metrics["constraints"] == soft.metrics["constraints"]


def _filter(**changes) -> tuple[SafetyFilter, object]:
    parts = prepare(_scenario(**RAIL, **{"safety.filter": "cbf", **changes}), controller="pd")
    filt = parts.controller
    assert isinstance(filt, SafetyFilter) and filt.kind == "pd+cbf"
    s0 = np.zeros(4)
    filt.step(Observation(0.0, s0, s0[[1, 3]], np.zeros(3), parts.task.names,
                          parts.task.constraints), 0.001)
    return filt, parts


def test_barrier_rows_against_h_derivatives_along_the_model():
    """(S1): c u <= d is -(h'' + (a1 + a2) h' + a1 a2 h) <= 0 with h'' measured by
    differences along a tight solve_ivp trajectory of the model at constant u."""
    filt, _ = _filter()
    model, cfg = filt.model, filt.cfg
    _, A, b = filt._rows
    rng = np.random.default_rng(0)
    for _ in range(5):
        s = rng.normal(scale=[0.4, 0.2, 0.5, 0.3])
        u = float(rng.normal(scale=200.0))
        f, g = model.input_map(s)
        c, d = barrier_rows(A, b, model.dof, s, f, g, cfg.alpha_1, cfg.alpha_2)
        tau = 1e-3
        sol = solve_ivp(lambda t, y: model.rhs(y, u), (0.0, tau), s, rtol=1e-12, atol=1e-12,
                        dense_output=True)
        back = solve_ivp(lambda t, y: model.rhs(y, u), (0.0, -tau), s, rtol=1e-12, atol=1e-12)
        for i, (row, bound) in enumerate(zip(A, b)):
            h = lambda y: bound - row[:-1] @ y  # noqa: E731
            h0, hp, hm = h(s), h(sol.y[:, -1]), h(back.y[:, -1])
            h_dot, h_ddot = (hp - hm) / (2 * tau), (hp - 2 * h0 + hm) / tau ** 2
            condition = h_ddot + (cfg.alpha_1 + cfg.alpha_2) * h_dot + cfg.alpha_1 * cfg.alpha_2 * h0
            assert c[i] * u - d[i] == pytest.approx(-condition, rel=1e-5, abs=1e-5)


@pytest.mark.parametrize("saturation", [0.0, 30.0])
def test_the_qp_is_scipys_solution_of_the_same_problem(saturation):
    """Where the barrier conditions and the input's range can all hold, u is scipy's
    minimiser of (u - u_c)^2 under them (SLSQP); where they cannot (linprog finds no u),
    the filter reports a positive slack."""
    from scipy.optimize import linprog

    filt, _ = _filter(**{"effects.saturation": saturation})
    model, cfg = filt.model, filt.cfg
    _, A, b = filt._rows
    lo, hi = (-saturation, saturation) if saturation else (-np.inf, np.inf)
    rng = np.random.default_rng(1)
    feasible = infeasible = 0
    for _ in range(40):
        s = rng.normal(scale=[0.5, 0.1, 1.5, 0.3])
        u_c = float(rng.normal(scale=1500.0))
        u, slack = filt.filter(s, u_c)
        f, g = model.input_map(s)
        c, d = barrier_rows(A, b, model.dof, s, f, g, cfg.alpha_1, cfg.alpha_2)
        lp = linprog([0.0], A_ub=c[:, None], b_ub=d,
                     bounds=[(None if np.isinf(lo) else lo, None if np.isinf(hi) else hi)])
        if lp.status == 2:
            infeasible += 1
            assert slack > 0.0
            continue
        feasible += 1
        K = max(1.0, abs(u_c), abs(float(lp.x[0])))   # SLSQP on a well-scaled variable
        res = minimize(lambda z: (z[0] - u_c / K) ** 2, x0=np.array([lp.x[0] / K]),
                       method="SLSQP",
                       bounds=[(None if np.isinf(lo) else lo / K, None if np.isinf(hi) else hi / K)],
                       constraints=[{"type": "ineq",
                                     "fun": lambda z: d / np.abs(c) / K - np.sign(c) * z[0]}],
                       options={"ftol": 1e-12, "maxiter": 500})
        assert res.success
        assert u == pytest.approx(K * res.x[0], rel=1e-5, abs=1e-6)   # SLSQP's own tolerance
        # and exactly the projection of u_c onto the interval the rows leave (1-D)
        upper = min([hi, *(d[c > 0] / c[c > 0])])
        lower = max([lo, *(d[c < 0] / c[c < 0])])
        assert u == pytest.approx(min(max(u_c, lower), upper), rel=1e-9, abs=1e-9)
        assert slack == pytest.approx(0.0, abs=1e-9)
    assert feasible > 10 and (infeasible > 0 or saturation == 0.0)


def test_filtered_run_never_leaves_the_rail_the_unfiltered_one_does():
    scn = _scenario(**RAIL, **{"run.duration": 3.0})
    bare = run(scn, controller="pd", keep_history=False)
    assert bare.status == "rail_end" and bare.metrics["violations"] >= 1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        safe = run(override(scn, **{"safety.filter": "cbf"}), controller="pd")
    assert safe.status != "rail_end"
    assert np.abs(safe.history["state"][:, 0]).max() < 1.0
    assert safe.metrics["constraints"]["rail"]["samples_outside"] == 0
    assert safe.metrics["violations"] == 0
    share = safe.metrics["safety_filter"]["intervention_share"]
    du = safe.history["safety_du"]
    assert share == pytest.approx(np.mean(du > 1e-9 * 2000.0), abs=1e-3) and share > 0
    u_c = safe.history["safety_u_commanded"]
    np.testing.assert_allclose(np.abs(safe.history["u"] - u_c), du, atol=1e-9)  # no range here
    assert math.isfinite(safe.metrics["safety_filter"]["qp_ms"]["median"])


def test_cli_safety_flag_writes_the_filter_and_violations_and_refuses_a_plant_without_a_model(
        tmp_path):
    import json

    from cli_harness import tspend

    out = tmp_path / "m.json"
    r = tspend("run", "ex3_pendulum_ode", "--controller", "pd", "--set", "effects.rail=1.0",
               "--duration", "0.5", "--safety", "cbf", "--no-record", "--metrics", str(out),
               cwd=tmp_path)
    m = json.loads(out.read_text())
    assert m["controller"]["kind"] == "pd+cbf" and m["constraints"]["rail"]["samples_outside"] == 0
    assert 0.0 < m["safety_filter"]["intervention_share"] <= 1.0 and "safety filter" in r.out
    bad = tspend("run", "ex2_duffing", "--safety", "cbf", "--no-record", cwd=tmp_path)
    assert bad.status == 2 and "no full-state model" in bad.one_error_line()


def test_braking_rows_against_h_b_along_the_model():
    """(S4): c u <= d is -(h_b' + alpha_1 h_b) <= 0 with h_b' measured along a tight
    solve_ivp trajectory, for a cart moving toward either end (v > 0 on that row)."""
    from tspend.controllers.safety import braking_rows

    filt, _ = _filter(**{"safety.barrier": "braking"})
    model, cfg = filt.model, filt.cfg
    _, A, b = filt._rows
    a_max = filt._a_max
    rng = np.random.default_rng(2)
    for sign in (1.0, -1.0):
        s = np.array([0.3 * sign, 0.05, 1.2 * sign, -0.1]) + rng.normal(scale=0.01, size=4)
        u = float(rng.normal(scale=100.0))
        f, g = model.input_map(s)
        c, d = braking_rows(A, b, model.dof, s, f, g, cfg.alpha_1, a_max)
        tau = 1e-4
        ends = [solve_ivp(lambda t, y: model.rhs(y, u), (0.0, span), s, rtol=1e-12,
                          atol=1e-12).y[:, -1] for span in (tau, -tau)]
        approaching = 0
        for i, (row, bound) in enumerate(zip(A, b)):
            a_q = row[:model.dof]
            h_b = lambda y: (bound - a_q @ y[:model.dof]  # noqa: E731
                             - max(a_q @ y[model.dof:], 0.0) ** 2 / (2 * a_max[i]))
            if a_q @ s[model.dof:] <= 0.0:
                assert c[i] == 0.0 and d[i] > 0.0     # moving away: no condition
                continue
            approaching += 1
            h_dot = (h_b(ends[0]) - h_b(ends[1])) / (2 * tau)
            assert c[i] * u - d[i] == pytest.approx(-(h_dot + cfg.alpha_1 * h_b(s)), rel=1e-5,
                                                    abs=1e-5)
        assert approaching == 1


def test_lyapunov_barrier_keeps_rail_and_pole_where_the_cart_barrier_drops_the_pole():
    """(S5): on the 1 m rail the cart-only barrier (S1) keeps the rail and lets the pole
    fall; the LQR ellipsoid keeps both, and the ellipsoid lies inside the rail (its largest
    |slider|, found by scipy on the boundary, is the tightened rail)."""
    from tspend.controllers.safety import wrap

    scn = override(load_scenario("scenarios/pendulum_finite_rail.toml"),
                   **{"effects.rail": 1.0, "run.duration": 6.0, "safety.filter": "cbf"})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cart_only = run(scn, controller="pd", keep_history=False)
        both = run(override(scn, **{"safety.barrier": "lyapunov"}), controller="pd",
                   keep_history=False)
    assert cart_only.status == "fell"
    assert cart_only.metrics["constraints"]["rail"]["samples_outside"] == 0
    assert both.status == "completed"
    assert both.metrics["constraints"]["rail"]["samples_outside"] == 0
    assert both.metrics["joints"]["slider"]["max_abs"] < 1.0
    # the ellipsoid s^T P s <= c against the rail tightened by the margin
    filt, _ = _filter(**{"safety.barrier": "lyapunov"})
    P, c = filt._P, filt._level
    best = minimize(lambda s: -s[0], np.full(4, 1e-3), method="SLSQP",
                    constraints=[{"type": "ineq", "fun": lambda s: c - s @ P @ s}])
    assert -best.fun == pytest.approx(1.0 - 0.05, rel=1e-5)
