"""The predictive safety filter (--safety mpsc, tspend/controllers/mpsc.py) and honest
violation counting, against independent computations: scipy's solve_ivp of the plan the
filter certified, boundary points of the terminal ellipsoid, a bare run that crosses."""

from __future__ import annotations

import math

from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("casadi")

from tspend import load_scenario, override, run  # noqa: E402
from tspend.runtime.errors import ScenarioError  # noqa: E402


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


def _solve_plan(f, s, plan, model=None, nodes=None):
    """The certified plan (P5) integrated by scipy: the first sample's input held, then
    each interval with the LQR correction towards the reference interpolated between the
    nodes, evaluated continuously (the runner tracks at every sample) or, where the
    certificate holds it, at each sample's start and held over the sample; the states
    every millisecond (and, into ``nodes``, at the plan's nodes after the first)."""
    from scipy.integrate import solve_ivp

    U, R = plan
    c = f.cert
    model = c.model if model is None else model
    x, out = np.array(s, dtype=float), [np.array(s, dtype=float)]

    def follow(law, T, x):
        sol = solve_ivp(lambda t, y: model.rhs(y, law(t, y)), (0.0, T), x, rtol=1e-10,
                        atol=1e-12, max_step=1e-3,
                        t_eval=np.linspace(0.0, T, max(2, int(round(T / 1e-3)) + 1)))
        out.append(sol.y.T)
        return sol.y[:, -1]

    def law(t, y, k):
        a = 0.0 if k + 1 >= c.N else t / c.h
        ref = (1 - a) * R[:, k] + a * R[:, min(k + 1, c.N - 1)]
        return min(max(float(U[k] - c.K @ (y - ref)), c.u_lo), c.u_hi)

    x = follow(lambda t, y: U[0], c.sample_s, x)
    nodes = [] if nodes is None else nodes
    nodes.append(x)
    for k in range(1, c.N):
        if not c.held:
            x = follow(lambda t, y, k=k: law(t, y, k), c.h, x)
        for j in range(c.substeps if c.held else 0):   # u from each sample's start, held
            u = law(j * c.sample_s, x, k)
            x = follow(lambda t, y, u=u: u, c.sample_s, x)
        nodes.append(x)
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
    # the disturbance's tube and 4 % of its half-width), to its integration's difference
    c = f.cert
    assert np.abs(states[:, 0]).max() <= c.hi_check[0] + 1e-3
    assert np.abs(states[:, 1]).max() < c.hi[1]
    assert end @ c.P @ end <= c.level * (1 + 1e-3)


def test_a_plan_sampled_every_20_ms_is_certified_as_the_runner_holds_it_by_scipy():
    # run.control_period 20 ms: the runner holds u over each sample, so (P5) does too,
    # on a plan grid of whole samples (5 per plan period here)
    f = _filter(**{"run.control_period": 0.02})
    c = f.cert
    assert c.sample_s == 0.02 and c.held and c.substeps == 5
    assert c.h == pytest.approx(5 * 0.02)
    s = np.array([0.3, 0.0, 0.5, 0.0])
    f.filter(s, 0.0)
    assert f.plan is not None
    rollout, _ = f.roll.nominal(s, *f.plan)
    nodes: list = []
    states, end = _solve_plan(f, s, f.plan, nodes=nodes)
    # the certificate's own nominal rollout against scipy's at the plan's nodes (RK4 at
    # 20 ms against a tight integration of the same held inputs)
    assert np.abs(np.array(nodes) - rollout[:, 1:].T).max() < 2e-3
    assert np.abs(states[:, 0]).max() <= c.hi_check[0] + 1e-3
    assert end @ c.P @ end <= c.level * (1 + 1e-3)


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


@pytest.mark.parametrize("key,value", [("horizon", 500), ("substeps", 99), ("plan_period", 3.0),
                                       ("budget_ms", 5000.0)])
def test_plan_sizes_are_bounded(key, value):
    with pytest.raises(ScenarioError, match=f"safety.{key}"):
        override(load_scenario("pendulum_finite_rail"), **{f"safety.{key}": value})


def test_refuse_unadmitted_takes_true_or_false_only():
    with pytest.raises(ScenarioError, match="safety.refuse_unadmitted"):
        override(load_scenario("pendulum_finite_rail"), **{"safety.refuse_unadmitted": "yes"})


def test_a_start_no_plan_can_certify_is_refused_before_its_first_input(tmp_path, capsys):
    """safety.refuse_unadmitted: the pole 1.3 rad from upright and falling at 2 rad/s on
    a 1 m rail.  scipy's integration of the model from it, under either end of the
    input's range held and under none, passes the certificate's pole bound within 0.2 s
    (no plan keeps it); the run ends "refused" before its first input, exit 4, with the
    certificate's reason on stderr and in m.json."""
    import json

    from scipy.integrate import solve_ivp

    from tspend.cli.main import main

    start = [1.3, 2.0]
    c = _filter(**{"plant.x0": start}).cert
    s = np.array([0.0, start[0], 0.0, start[1]])
    for u in (c.u_lo, 0.0, c.u_hi):
        sol = solve_ivp(lambda t, y, u=u: c.model.rhs(y, u), (0.0, 0.2), s, max_step=1e-3,
                        rtol=1e-9)
        assert np.abs(sol.y[1]).max() > c.hi_check[1]
    metrics = tmp_path / "m.json"
    status = main(["run", "pendulum_finite_rail", "--controller", "pd", "--no-record",
                   "--set", "effects.rail=1.0", "--set", 'safety.filter="mpsc"',
                   "--set", f"plant.x0={start}", "--set", "safety.refuse_unadmitted=true",
                   "--metrics", str(metrics)])
    err = capsys.readouterr().err
    assert status == 4
    assert "refused at t = 0.0000 s" in err and "no plan certified from the start" in err
    m = json.loads(metrics.read_text())
    sf = m["safety_filter"]
    assert m["steps"] == 0 and sf["samples"] == 0
    assert sf["start_admitted"] is False and "robust plan (P11)" in sf["start_refusal"]
    # without the setting the same start runs (its samples counted uncertified)
    main(["run", "pendulum_finite_rail", "--controller", "pd", "--no-record", "--duration",
          "0.05", "--set", "effects.rail=1.0", "--set", 'safety.filter="mpsc"',
          "--set", f"plant.x0={start}"])
    assert "refused" not in capsys.readouterr().err


def test_ctrl_c_during_a_simulated_runs_admission_claims_no_verdict(tmp_path, capsys):
    """A SIGINT 0.1 s into the robust plan's IPOPT (P11) at the admission of the start
    above (about 0.4 s of IPOPT here): the run ends interrupted (130) before its first
    input, and the filter's block claims neither an admission nor a refusal.  CasADi turns
    a signal inside IPOPT's callback into a failed solve: the run had gone on to apply its
    first sample, and its block had said "no plan certified from the start"."""
    import json
    import os
    import signal
    import threading

    from tspend.cli.main import main
    from tspend.controllers import mpsc

    real_plan, timers = mpsc.RobustAdmission.plan, []

    def plan(self, s, warm):
        timers.append(threading.Timer(0.1, os.kill, (os.getpid(), signal.SIGINT)))
        timers[-1].start()
        return real_plan(self, s, warm)

    metrics = tmp_path / "m.json"
    mpsc.RobustAdmission.plan = plan
    try:
        status = main(["run", "pendulum_finite_rail", "--controller", "pd", "--no-record",
                       "--set", "effects.rail=1.0", "--set", 'safety.filter="mpsc"',
                       "--set", "plant.x0=[1.3, 2.0]", "--metrics", str(metrics)])
    finally:
        mpsc.RobustAdmission.plan = real_plan
        for timer in timers:
            timer.join()
    assert status == 130 and len(timers) == 1
    m = json.loads(metrics.read_text())
    sf = m["safety_filter"]
    assert m["status"] == "interrupted" and m["steps"] == 0 and sf["samples"] == 0
    assert sf["start_admitted"] is None and sf["start_refusal"] is None
    assert "interrupted" in capsys.readouterr().err


def test_the_fast_path_passes_a_certifiable_command_without_the_qp():
    f = _filter()

    def no_qp(*args, **kwargs):
        raise AssertionError("the QP ran")

    f.sqp.iterate = no_qp
    # near the upright at rest, a small command: followed by the LQR it stays inside
    s = np.array([0.05, 0.01, 0.0, 0.0])
    u, slack = f.filter(s, 5.0)
    assert u == 5.0 and slack == 0.0 and f.fast == 1
    # and the plan it certified is what scipy's integration of (P5) keeps inside
    states, end = _solve_plan(f, s, f.plan)
    assert np.abs(states[:, 0]).max() <= f.cert.hi_check[0] + 1e-3
    assert end @ f.cert.P @ end <= f.cert.level * (1 + 1e-3)


def test_disturbance_input_is_mujocos_mass_matrix_solve():
    """E read off one step of the machine against MuJoCo's own mass matrix: the hinge
    torque tau = -d m l / (M + m) (tspend/plants/mujoco_plant.py) solved through M(q)."""
    import mujoco

    from tspend.controllers.full_model import full_model
    from tspend.controllers.mpsc import disturbance_input
    from tspend.loop.simulation import nominal_machine

    scn = load_scenario("pendulum_finite_rail")
    machine = nominal_machine(scn)
    model = full_model(scn, machine)
    E = disturbance_input(scn, model)
    mm = machine.mj_model()
    data = mujoco.MjData(mm)
    mujoco.mj_forward(mm, data)
    M_full = np.zeros((mm.nv, mm.nv))
    mujoco.mj_fullM(mm, data, M_full)
    M, m, l = 10.0, 1.0, 3.0                          # models/cartpole.xml's own
    tau = np.zeros(mm.nv)
    tau[mm.joint("hinge").dofadr[0]] = -m * l / (M + m)
    qacc = np.linalg.solve(M_full, tau)
    for name in ("slider", "hinge"):
        i = model.state_names.index(name + "_dot")
        assert E[i] == pytest.approx(qacc[mm.joint(name).dofadr[0]], rel=1e-3, abs=1e-9)
    assert np.all(E[:model.dof] == 0.0) and np.abs(E).max() > 0.0


def test_disturbance_tube_is_reached_by_the_worst_bang_bang_disturbance():
    """(P7) against scipy's lsim: d = d_max sign(c_i exp(A_cl (T - t)) E) drives e_i(T)
    to the L1 bound as T grows, and no input of that size goes beyond it."""
    from scipy.linalg import expm
    from scipy.signal import lsim

    from tspend.controllers.full_model import full_model
    from tspend.controllers.lqr import default_state_weights, design_model, lqr_full_gain
    from tspend.controllers.mpsc import disturbance_input, disturbance_tube
    from tspend.loop.simulation import nominal_machine

    scn = load_scenario("pendulum_finite_rail")
    machine = nominal_machine(scn)
    model = full_model(scn, machine)
    A, B = design_model(scn, machine)
    b_pole = float(B[model.dof + model.pole, 0])
    K, _ = lqr_full_gain(A, B, np.diag(default_state_weights(model)), b_pole ** 2)
    A_cl = A - np.outer(B[:, 0], np.ravel(K))
    w = disturbance_tube(scn, model, A_cl)
    E = disturbance_input(scn, model)
    # what docs/safety.md quotes: 15 mm on the cart, 0.8 mrad on the pole
    assert w[0] == pytest.approx(0.0150, abs=5e-4) and w[1] == pytest.approx(8e-4, abs=5e-5)
    d_max = 0.05                                     # the scenario's square wave
    T, dt = 60.0, 2e-3
    t = np.arange(0.0, T + dt / 2, dt)
    for i in range(model.dof):                       # the cart and the pole's angle
        c = np.eye(model.size)[i]
        d = d_max * np.sign([c @ expm(A_cl * (T - ti)) @ E for ti in t])
        _, y, _ = lsim((A_cl, E[:, None], c[None, :], np.zeros((1, 1))), d, t)
        assert abs(y[-1]) == pytest.approx(w[i], rel=0.02)
        # the scenario's own square wave stays inside
        _, y2, _ = lsim((A_cl, E[:, None], c[None, :], np.zeros((1, 1))),
                        np.asarray(scn.disturbance(t)), t)
        assert np.abs(y2).max() <= w[i] * (1 + 1e-6)


def _randomized_start(seed):
    """benchmarks/safety_filter.py's randomised cart-pole (1 m rail, 3 s) behind mpsc, and
    the start its seed draws (the cart at rest at the centre)."""
    from tspend.plants.randomize import draw

    scn = override(load_scenario("pendulum_mujoco_randomized"),
                   **{"effects.rail": 1.0, "run.duration": 3.0, "safety.filter": "mpsc",
                      "run.seed": seed})
    theta, rate = draw(scn).scenario.plant.x0
    return scn, np.array([0.0, theta, 0.0, rate])


def test_the_recovery_plan_is_what_scipy_integrates_and_travels_less_than_the_lqr():
    """(P8) from a start no plan is certified from (seed 15, docs/safety.md): its inputs
    held over its intervals and integrated by scipy reproduce its states; it keeps every
    bound relaxed by its own t, ends in the ellipsoid, and its cart travels less than the
    saturated LQR's from the same start (the model's own rollout)."""
    from scipy.integrate import solve_ivp

    from tspend.loop.simulation import prepare

    scn, s = _randomized_start(15)
    f = prepare(scn, controller="pd").controller
    rec, c = f.recovery, f.cert
    U, X, t = rec.plan(s)
    grid = np.concatenate([[0.0], c.sample_s + rec.h * np.arange(rec.M)])
    x, peak, node_peak = s.copy(), 0.0, 0.0
    for k in range(rec.M):
        sol = solve_ivp(lambda _, y: c.model.rhs(y, U[k]), (grid[k], grid[k + 1]), x,
                        rtol=1e-10, atol=1e-12, max_step=2e-3)
        x = sol.y[:, -1]
        peak = max(peak, float(np.abs(sol.y[0]).max()))
        node_peak = max(node_peak, abs(float(x[0])))
        assert np.allclose(x, X[:, k + 1], atol=2e-3 * (1 + np.abs(X[:, k + 1]))), k
    # t is in shares of the constraint's half-width (the rail's 1 m), kept at the nodes;
    # between them (20 ms) the cart may turn round past its node (10 mm here)
    assert rec.room[0] == pytest.approx(1.0)
    assert t < 0.0
    assert node_peak <= c.hi[0] + t * 1.0 + 2e-3
    assert peak <= c.hi[0] + t * 1.0 + 0.02
    assert x @ c.P @ x <= c.level
    assert np.all((U >= c.u_lo - 1e-6) & (U <= c.u_hi + 1e-6))
    # the saturated LQR alone from the same start, on the same model, goes farther
    y, lqr_peak = s.copy(), 0.0
    for _ in range(3000):
        y = np.asarray(rec.maps[0](y, f.terminal_input(y))).ravel()
        lqr_peak = max(lqr_peak, abs(float(y[0])))
    assert lqr_peak > peak + 0.05


def test_a_start_with_no_certified_plan_completes_on_mujoco_through_the_recovery_plan():
    """The run docs/safety.md quotes for seed 15: MuJoCo's machine (not the model) stays
    on the rail and up, the recovery plan acted and its samples are counted uncertified."""
    scn, _ = _randomized_start(15)
    r = run(scn, controller="pd", keep_history=False)
    sf = r.metrics["safety_filter"]
    assert sf["recovery_plans"] >= 1 and sf["uncertified_samples"] >= 1
    assert r.status == "completed" and r.metrics["violations"] == 0
    assert r.metrics["joints"]["slider"]["max_abs"] < 1.0


def _randomized_filter(seed):
    from tspend.loop.simulation import prepare

    scn, s = _randomized_start(seed)
    f = prepare(scn, controller="pd").controller
    f._rows = (np.arange(f.model.size),)
    return f, s


def test_the_rollout_on_every_corner_is_what_scipy_integrates():
    """The certificate's compiled rollouts (mapaccum over one RK4 step, one per model)
    against scipy's integration of (P5) on the corner machines themselves: the least and
    largest cart position and the last state of each."""
    f, s = _randomized_filter(3)
    assert f.roll.models == 17 and len(f.cert.corner_names) == 4
    U, R = f.lqr_tail(s)
    U[0] = f.terminal_input(s)
    summary = f.roll.run(s, U, R).copy()
    nx = f.model.size
    for m in (0, 5, 16):
        model = f.cert.model if m == 0 else f.cert.corners[m - 1]
        states, end = _solve_plan(f, s, (U, R), model=model)
        assert summary[m, 0] == pytest.approx(states[:, 0].min(), abs=2e-3)
        assert summary[m, nx] == pytest.approx(states[:, 0].max(), abs=2e-3)
        assert summary[m, 2 * nx:] == pytest.approx(end, abs=2e-3)


def test_the_compiled_check_is_the_rollout_model_by_model():
    """The compiled check (one C call, ``mpsc_check.c``) and the same check in CasADi's
    virtual machine against the whole rollout: the same summary when every model keeps
    its bounds; a plan that leaves the rail stopped at the first model that breaks a
    bound, which is then checked first; and no model once the deadline is gone (but the
    first of a check whose guard is not measured yet: a check stopped between models, its
    verdict unknown)."""
    import time

    from tspend.controllers.mpsc import Rollout, certificate_rollout

    f, s = _randomized_filter(3)
    compiled = f.roll
    assert compiled._compiled is not None
    virtual = Rollout(certificate_rollout(f.cert), f.cert)
    U, R = f.lqr_tail(s)
    U[0] = f.terminal_input(s)
    whole = virtual.run(s, U, R).copy()
    assert f.verdict(whole) is None
    far = time.perf_counter() + 60.0
    for roll in (compiled, virtual):
        summary, run, cpu_s = roll.check(s, U, R, far, 1e-6)
        assert run == 17 and cpu_s > 0.0
        np.testing.assert_allclose(summary, whole, rtol=1e-12, atol=1e-12)
        # pushed towards the rail's end at speed: some model breaks a bound
        away = s.copy()
        away[0], away[2] = 0.9, 3.0
        broken, run, _ = roll.check(away, U, R, far, 1e-6)
        first = int(roll.order[0])
        assert broken is False and 1 <= run <= 17
        assert roll.excess[first] > 0.0 and f.verdict(roll.run(away, U, R)) is not None
        # the model that broke a bound is tried first: the next check stops at once
        assert roll.check(away, U, R, far, 1e-6)[:2] == (False, 1)
        gone, run, _ = roll.check(s, U, R, time.perf_counter() - 1.0, 1e-6)
        assert gone is None and run == 0
        # an unmeasured guard (a first probe): the first model runs, none after it
        gone, run, _ = roll.check(s, U, R, time.perf_counter() - 1.0, math.inf)
        assert gone is None and run == 1


def test_a_check_ends_before_the_deadline_less_its_verdict():
    """(P9) per model: with a budget for half a rollout, a check started as a probe runs
    the models that fit (each given MODEL_GUARD times its share of the rollout's
    estimate), stops between two, and the sample ends within the budget (but for a wait
    for a core); it is counted as cut short."""
    from tspend.controllers.mpsc import MODEL_GUARD, StepCost

    f, s = _randomized_filter(3)
    f.admit(s)
    assert f.admitted and f.roll.models == 17
    whole = f._cost["roll"].estimate
    assert MODEL_GUARD * whole / f.roll.models < 0.25 * whole
    f.cert = replace(f.cert, budget_s=0.5 * whole)
    # a probe: started whatever the budget, stopped by the guard before each model
    f._cost["roll"] = StepCost(probe=True)
    f._cost["roll"].last = whole
    started = []
    check = f.roll.check
    f.roll.check = lambda *a: started.append(a[3]) or check(*a)
    # the reserve measured after a check stopped short first (the work after it, the
    # other tails refused, is longer than after a sample with no step)
    for _ in range(2):
        f.filter(s, 5.0)
    f.over_budget_by_cause = dict.fromkeys(f.over_budget_by_cause, 0)
    cut, tried = f.cut_short, len(started)
    for _ in range(4):
        f.filter(s, 5.0)
    # each check stopped short adds a whole rollout's time: after COST_RANK of them the
    # estimate no longer fits and none starts
    assert len(started) > tried and f.cut_short - cut == len(started) - tried
    # the filter's own: a sample whose thread waited for a core (a loaded machine) is not
    causes = f.over_budget_by_cause
    assert causes["probe"] == causes["step_over_its_estimate"] == 0, causes


def test_a_start_no_plan_covers_is_not_admitted_and_says_why():
    """Seed 15's start (docs/safety.md): no tail and no QP plan is certified on the 17
    models; the refusal names the bound, and scipy's integration of the saturated LQR
    from it on the nominal model indeed leaves that bound."""
    f, s = _randomized_filter(15)
    f.recovery.plan = lambda state: None
    f.robust = None  # (P11): its own test below
    f.admit(s)
    assert f.admitted is False and f.plan is None
    assert "slider's certified bound" in f.refusal and "nominal model" in f.refusal
    U, R = f.lqr_tail(s)
    U[0] = f.terminal_input(s)
    states, _ = _solve_plan(f, s, (U, R))
    assert np.abs(states[:, 0]).max() > f.cert.hi_check[0]


def test_the_robust_plan_admits_a_start_the_lqr_and_the_qp_do_not_and_scipy_agrees():
    """(P11) from seed 18's start (docs/safety.md): no tail and no QP plan is certified;
    the robust plan is, and scipy's integration of it on the nominal model and on three
    corner machines keeps the cart within the certified bound and ends in X_f (to the
    integrators' difference)."""
    f, s = _randomized_filter(18)
    robust = f.robust
    f.robust = None
    f.admit(s)
    assert f.admitted is False
    f.reset_plan()
    f.robust = robust
    f.admit(s)
    assert f.admitted is True and f.robust_admitted and f.plan is not None
    c = f.cert
    for m in (0, 1, 8, 16):
        states, end = _solve_plan(f, s, f.plan, model=c.model if m == 0 else c.corners[m - 1])
        assert np.abs(states[:, 0]).max() <= c.hi_check[0] + 2e-3
        assert end @ c.P @ end <= c.level * (1 + 1e-2)


def test_no_step_starts_past_the_budget():
    """(P9): with a budget shorter than one rollout the filter tries none: the certified
    plan made at admission goes on (tracked), counted as a fallback and as skipped."""
    f = _filter(**{"safety.budget_ms": 1e-3})
    s = np.array([0.05, 0.01, 0.0, 0.0])
    f.admit(s)
    assert f.admitted and f.plan is not None and f._cost["roll"].estimate > 1e-6
    runs = []
    original = f.roll.check
    f.roll.check = lambda *a: runs.append(1) or original(*a)
    for _ in range(5):
        u, _ = f.filter(s, 5.0)
    assert runs == [] and f.fallbacks == 5 and f.fast == 0 and f.skipped == 5
    assert u == pytest.approx(f.tracking_input(s, f.stage_at(4 * f.cert.sample_s),
                                               4 * f.cert.sample_s))
    sf = f.more_metrics()
    assert sf["budget_ms"] == pytest.approx(1e-3) and sf["budget_skipped_samples"] == 5
    assert sf["certified_samples"] == 0 and sf["uncertified_samples"] == 0


def test_admission_prices_a_samples_qp_step_by_its_slowest_sqp_step():
    """(P9): admission runs several SQP steps of (P4) and a sample runs one, which may cost
    what admission's first, cold one did: on a fake clock where the first step takes 3 ms
    and the others 0.2 ms, the QP's estimate is 3 ms (their average per admission step had
    priced it at 0.5 ms or less, and a sample's QP then ran to 3.5 ms), so a 1 ms budget
    never starts it."""
    f = _filter(**{"safety.budget_ms": 1.0})
    s = np.array([0.05, 0.01, 0.0, 0.0])
    now, steps = [0.0], []
    f._clock = f._cpu_clock = lambda: now[0]
    real_evaluate = f.sqp._evaluate

    def evaluate():
        # one SQP step: the compiled QP's call
        now[0] += 0.2e-3 if steps else 3e-3
        steps.append(now[0])
        real_evaluate()

    f.sqp._evaluate = evaluate
    f.admit(s)
    assert len(steps) >= 2
    assert f._cost["qp"].estimate == pytest.approx(3e-3)
    f._deadline = now[0] + 1e-3
    assert f._affords("qp") is False


def _on_a_fake_clock(f, roll_costs_s, finish_s):
    """``f`` on a fake clock that only the rollouts (``roll_costs_s`` in turn, repeated)
    and the fallback's bookkeeping (``finish_s``) advance, every rollout refused (so every
    tail and bisection is wanted): ``(run, rollouts started per sample)``."""
    from tspend.controllers.mpsc import FIXED_COST_RANK, StepCost

    now, costs, started = [0.0], list(roll_costs_s), []
    clock = lambda: now[0]  # noqa: E731
    f._clock = f._cpu_clock = clock
    # the QP unmeasured: never started (its real time is not on this clock)
    f._cost["roll"], f._cost["qp"] = StepCost(), StepCost()
    f._reserve = StepCost(rank=FIXED_COST_RANK)
    for cost in costs:
        f._cost["roll"].measured(cost)
    run_rollout, fallback = f.roll.run, f.fallback

    def rollout(s, U, R, until_s, guard_s):
        # every model, whatever the (real) clock: the fake one moves by the rollout's cost
        started[-1].append(now[0])
        out = run_rollout(s, U, R), f.roll.models, 0.0
        now[0] += costs[sum(map(len, started)) % len(costs)]
        return out

    def bookkeeping(*args):
        now[0] += finish_s
        return fallback(*args)

    f.roll.check, f.fallback = rollout, bookkeeping
    f.verdict = lambda V: "refused"

    def sample(s, u_c):
        started.append([])
        t0 = now[0]
        u, _ = f.filter(s, u_c)
        return u, now[0] - t0

    sample.now = now  # the fake clock, for a test that moves it itself
    return sample, started


@pytest.mark.parametrize("collect", [True, False])
def test_a_collection_in_a_sample_does_not_price_the_fixed_work(collect):
    """(P9): the work after the last step (the reserve) is estimated by the largest of its
    recent times, and a sample in which the garbage collector ran is left out: on a fake
    clock, one sample's bookkeeping takes 3 ms more with a collection in it, and the next
    samples still start rollouts; the same 3 ms without a collection is the reserve's
    estimate, which then leaves no room in the 1 ms budget, and no rollout starts."""
    import gc

    f = _filter(**{"safety.budget_ms": 1.0})
    s = np.array([0.05, 0.01, 0.0, 0.0])
    f.admit(s)
    sample, started = _on_a_fake_clock(f, [0.1e-3], 0.05e-3)
    for _ in range(3):
        sample(s, 5.0)
    assert len(started[-1]) >= 3
    bookkeeping = f.fallback

    def slow_once(*args):
        f.fallback = bookkeeping
        sample.now[0] += 3e-3
        if collect:
            gc.collect()
        return bookkeeping(*args)

    f.fallback = slow_once
    sample(s, 5.0)
    for _ in range(3):
        sample(s, 5.0)
    if collect:
        assert f._reserve.estimate < 0.1e-3 and len(started[-1]) >= 3
    else:
        assert f._reserve.estimate >= 3e-3 and started[-1] == []


@pytest.mark.parametrize("finish_ms,fits", [(0.125, 3), (0.3, 2), (0.6, 1)])
def test_the_reserve_for_the_work_after_the_last_step_is_honoured(finish_ms, fits):
    """(P9) on a fake clock: rollouts of 0.25 ms, a budget of 1 ms, bookkeeping after the
    last step of ``finish_ms``: the first sample (reserve unmeasured) starts no step; then
    every sample starts exactly the rollouts that end by 1 ms less the reserve (0, 0.25,
    0.5 ms ...), and no sample, bookkeeping included, runs past the budget."""
    f = _filter(**{"safety.budget_ms": 1.0})
    s = np.array([0.05, 0.01, 0.0, 0.0])
    f.admit(s)
    assert f.admitted
    sample, started = _on_a_fake_clock(f, [0.25e-3], finish_ms * 1e-3)
    for i in range(5):
        u, elapsed = sample(s, 5.0)
        assert elapsed <= 1e-3
        assert u == pytest.approx(f.tracking_input(s, f.stage_at(i * f.cert.sample_s),
                                                   i * f.cert.sample_s))
    assert [len(x) for x in started] == [0] + [fits] * 4
    assert started[1] == pytest.approx([0.25e-3 * j + started[1][0] for j in range(fits)])
    assert f.over_budget == 0 and f.fallbacks == 5


def test_a_rollout_dearer_than_the_last_ones_is_not_started_late():
    """(P9): the estimate is a high quantile of the recent times, not the average: with
    rollouts of 0.1 and 0.4 ms in turn (average 0.25), none starts later than 0.4 ms before
    the deadline, so no sample runs past 1 ms; one 3 ms call (a collection inside it) does
    not move the estimate."""
    f = _filter(**{"safety.budget_ms": 1.0})
    s = np.array([0.05, 0.01, 0.0, 0.0])
    f.admit(s)
    sample, started = _on_a_fake_clock(f, [0.1e-3, 0.4e-3] * 8, 0.05e-3)
    for _ in range(6):
        assert sample(s, 5.0)[1] <= 1e-3
    assert f.over_budget == 0 and max(map(len, started)) >= 2
    assert all(t - x[0] <= 0.95e-3 - 0.4e-3 + 1e-12 for x in started for t in x)
    f._cost["roll"].measured(3e-3)
    assert f._cost["roll"].estimate == pytest.approx(0.4e-3)
    assert sample(s, 5.0)[1] <= 1e-3 and len(started[-1]) >= 1


def test_a_sample_past_the_budget_is_counted_by_its_cause():
    """(P9) on a fake clock, a 1 ms budget: a rollout started as a probe (no recent times:
    estimate 0) that takes 2 ms; a 2 ms rollout started on an estimate of 0.1 ms; a sample
    whose steps fit but whose thread waited 2 ms for a core (the wall clock moves, the CPU
    clock does not).  Each is one sample over the budget, counted under its cause."""
    from tspend.controllers.mpsc import StepCost

    s = np.array([0.05, 0.01, 0.0, 0.0])
    causes = {}
    for case in ("probe", "step_over_its_estimate", "waited_for_a_core"):
        f = _filter(**{"safety.budget_ms": 1.0})
        f.admit(s)
        costs = {"probe": [2e-3], "step_over_its_estimate": [0.1e-3] * 4 + [2e-3],
                 "waited_for_a_core": [0.1e-3]}[case]
        sample, _ = _on_a_fake_clock(f, costs, 0.05e-3)
        if case == "probe":
            f._cost["roll"] = StepCost(probe=True)  # no times: a probe's zero estimate
        if case == "waited_for_a_core":
            cpu, waited = f._cpu_clock, [0.0]
            f._clock = lambda: cpu() + waited[0]
            real_fallback = f.fallback

            def preempted(*args):
                waited[0] += 2e-3  # off the CPU: the wall clock moves on, the CPU's not
                return real_fallback(*args)

            f.fallback = preempted
        for _ in range(3):
            sample(s, 5.0)
        causes[case] = dict(f.more_metrics()["over_budget_by_cause"])
        assert f.over_budget == sum(causes[case].values()) >= 1, (case, causes[case])
    assert all(set(k for k, n in c.items() if n) == {case} for case, c in causes.items()), causes


def test_a_check_cut_short_prices_the_models_not_run_at_a_whole_checks_pace():
    """(P9): a check stopped between two models measures a whole rollout as the models it
    ran plus the rest at the last whole check's time per model (here 10 at 40 us and 7 at
    20 us: 540 us), not at its own pace (680 us): a check is cut short when it runs slow,
    and pricing the rest at that pace blocked every rollout after a slow spell."""
    from tspend.controllers.mpsc import StepCost

    f = _filter(**{"safety.budget_ms": 1.0})
    s = np.array([0.05, 0.01, 0.0, 0.0])
    f.admit(s)
    now = [0.0]
    f._clock = f._cpu_clock = lambda: now[0]
    f._cost["roll"], f._deadline = StepCost(probe=True), 1.0
    f._cost["roll"].new_sample()  # no times yet: a probe's zero estimate
    n = f.roll.models
    outcomes = [(f.roll._summary, n, n * 20e-6), (None, 10, 10 * 40e-6)]

    def check(*args):
        V, run, cpu_s = outcomes.pop(0)
        now[0] += cpu_s  # the fake clocks move by the models' time only
        return V, run, cpu_s

    f.roll.check, f.verdict = check, lambda V: "refused"
    U, R = f.lqr_tail(s)
    assert f.certifies(s, U, R) is False
    assert f._cost["roll"].last == pytest.approx(n * 20e-6)
    assert f.certifies(s, U, R) is None and f.cut_short == 1
    assert f._cost["roll"].last == pytest.approx(10 * 40e-6 + (n - 10) * 20e-6)


def test_the_estimate_is_a_high_quantile_of_the_last_samples_calls():
    """(P9)'s estimate: a lone slow call does not move it (the COST_RANK-th largest); a
    spell of slow calls is the estimate until COST_WINDOW samples have passed, with or
    without calls meanwhile; then, with fewer than COST_RANK calls left, the rollout's is 0
    for one call a sample (a probe) and another step's (the QP's) its last time."""
    from tspend.controllers.mpsc import COST_RANK, COST_WINDOW, StepCost

    roll = StepCost(probe=True)
    for t in [0.4e-3] * 10 + [3e-3]:
        roll.measured(t)
    assert roll.estimate == 0.4e-3
    roll.new_sample()
    for t in [0.8e-3] * COST_RANK:
        roll.measured(t)
    estimates = []
    for _ in range(COST_WINDOW + 2):
        roll.new_sample()
        estimates.append(roll.estimate)
    assert estimates[:COST_WINDOW - 1] == [0.8e-3] * (COST_WINDOW - 1)
    assert estimates[-1] == 0.0 and not roll.times
    # fewer than COST_RANK times: one probe a sample, then their largest
    roll.measured(0.5e-3)
    assert roll.estimate == 0.5e-3
    roll.new_sample()
    assert roll.estimate == 0.0
    qp = StepCost()
    qp.measured(4e-3)
    for _ in range(3 * COST_WINDOW):
        qp.new_sample()
    assert qp.estimate == 4e-3


def test_the_terminal_set_is_invariant_on_every_vertex_model_by_scipy():
    """(P10) on the randomised cart-pole: the design's decay rate is scipy's generalised
    eigenvalue of ``(A_i - B_i K)^T P + P (A_i - B_i K)`` against ``P`` on every vertex
    linearisation (an independent computation of the same bound), and starts on the
    boundary of X_f, integrated by solve_ivp on each nonlinear vertex model under the
    saturated LQR, stay inside X_f and every certified bound."""
    from scipy.integrate import solve_ivp
    from scipy.linalg import eigh

    from tspend.controllers import mpsc
    from tspend.loop.simulation import nominal_machine

    scn = override(load_scenario("pendulum_mujoco_randomized"),
                   **{"effects.rail": 1.0, "safety.filter": "mpsc"})
    corners, names = mpsc.vertex_models(scn)
    c = mpsc.design(scn, nominal_machine(scn), corners, names, scn.run.dt)
    assert c.terminal == "vertex_lyapunov" and c.decay_rate < 0.0
    models = [c.model, *corners]
    rates, riccati = [], []
    for m in models:
        A, B = m.linearisation()
        Acl = A - np.outer(B[:, 0], c.K)
        rates.append(eigh(Acl.T @ c.P + c.P @ Acl, c.P, eigvals_only=True).max())
        riccati.append(eigh(Acl.T @ c.P_cost + c.P_cost @ Acl, c.P_cost, eigvals_only=True).max())
    assert max(rates) == pytest.approx(c.decay_rate, rel=1e-6)
    # the Riccati matrix alone is no such function on these corners (why (P10) searches)
    assert max(riccati) > 0.0
    rng = np.random.default_rng(3)
    d = rng.normal(size=(6, c.model.size))
    starts = math.sqrt(c.level) * d / np.sqrt(np.einsum("ij,jk,ik->i", d, c.P, d))[:, None]
    bounded = np.isfinite(c.lo_check)
    for m in models:
        for s in starts:
            sol = solve_ivp(lambda t, y: m.rhs(y, mpsc.lqr_input(c, y)), (0.0, 2.0), s,
                            rtol=1e-9, atol=1e-11, max_step=5e-3)
            V = np.einsum("it,ij,jt->t", sol.y, c.P, sol.y)
            assert V.max() <= c.level * (1 + 1e-6)
            assert np.all(sol.y[bounded] >= c.lo_check[bounded, None])
            assert np.all(sol.y[bounded] <= c.hi_check[bounded, None])
