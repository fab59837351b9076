"""Per-sample compute of ``mpc``'s real-time scheme, its IPOPT reference and do-mpc, one run.

    python benchmarks/mpc_speed.py [--scenario pendulum_mujoco] [--samples 250]
                                   [--scheme rti] [--solver qrqp] [--no-dompc]
                                   [--set effects.saturation=60 ...]

1. Runs the scenario under ``mpc`` with the fast scheme (20 ms period) and keeps the
   state and reference row at every control sample.
2. Replays those samples, in order, through three solvers of the same OCP (same shooting
   map ``F`` over the domain's equations, horizon, ``Q``, ``R``, terminal ``P``, bounds),
   each warm-started from its own last solution: the fast scheme, the IPOPT scheme, and
   do-mpc (a discrete model ``x+ = F(x, u)``, the same stage and terminal costs, the
   references as time-varying parameters, IPOPT underneath).  The three are interleaved
   sample by sample, so that the machine's load falls on all alike, and timed by wall
   clock and by the process's CPU time (the load inflates the first, much less the second);
   "warm" leaves out the first sample (a cold start: no plan yet).
   ``--solver hpipm,qrqp`` times the fast scheme on each QP solver named (the first is the
   one run in closed loop).
3. Prints median and max per solver and the ratios ``median(IPOPT) / median(X)`` from
   this run; the largest difference of each first input from IPOPT's; and the closed-loop
   cost (``MPCController.running_cost``) of the fast scheme against IPOPT's, both run on
   the scenario for the same samples.

``--constraints`` only times the cost of the task's constraints in the OCP (docs/safety.md):
a soft box on the cart (+/-0.75 m) and a linear row on its position, speed and force, run
closed loop with them (so that they bind), then the samples replayed, interleaved, through
the fast scheme with and without them (``controllers.mpc.constraints``) on each QP solver
that takes them (hpipm, daqp) and through the unconstrained default (qrqp); prints CPU
medians and the ratios with/without on the same solver, measured in this run.

``--costs pendulum_mujoco:5,furuta_mujoco:5,...`` only runs each scenario closed loop under
IPOPT and under the fast scheme and prints the two costs, their ratio and the compute.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tspend import load_scenario, override, run  # noqa: E402
from tspend.loop.simulation import build_controller  # noqa: E402
from tspend.controllers.full_model import wrap_angle  # noqa: E402
from short_mode import short_defaults


def dompc_peer(c):
    """do-mpc on ``c``'s OCP (an ``MPCController``): ``step(state, ref) -> u``."""
    import casadi as ca
    import do_mpc

    N, nx, h = c.N, c.nx, c.s.period
    model = do_mpc.model.Model("discrete")
    x = model.set_variable("_x", "s", (nx, 1))
    u = model.set_variable("_u", "u", (1, 1))
    sr = model.set_variable("_tvp", "sr", (nx, 1))
    ur = model.set_variable("_tvp", "ur", (1, 1))
    F = c.model.rk4_map(h, c.s.substeps, name="F")   # the controller's own RK4 map
    model.set_rhs("s", F(x, u))
    model.setup()
    mpc = do_mpc.controller.MPC(model)
    mpc.settings.n_horizon = N
    mpc.settings.t_step = h
    mpc.settings.store_full_solution = False
    mpc.settings.nlpsol_opts = {"ipopt.print_level": 0, "ipopt.sb": "yes", "print_time": 0,
                                "ipopt.max_iter": c.s.max_iter, "ipopt.tol": c.s.tolerance}
    e = x - sr
    Q, P = ca.DM(c.Q), ca.DM(c.lqr.P)
    mpc.set_objective(lterm=h * (ca.mtimes([e.T, Q, e]) + c.R * (u - ur) ** 2),
                      mterm=ca.mtimes([e.T, P, e]))
    mpc.set_rterm(u=0.0)
    for j in range(nx):
        if c.state_lo[j] > -1e18:
            mpc.bounds["lower", "_x", "s", j] = c.state_lo[j]
        if c.state_hi[j] < 1e18:
            mpc.bounds["upper", "_x", "s", j] = c.state_hi[j]
    if np.isfinite(c.u_lo):
        mpc.bounds["lower", "_u", "u"] = c.u_lo
    if np.isfinite(c.u_hi):
        mpc.bounds["upper", "_u", "u"] = c.u_hi
    tvp = mpc.get_tvp_template()
    now = dict(zip(("Sr", "Ur"), c.references(np.zeros(3))))

    def tvp_fun(t_now):
        for k in range(N + 1):
            tvp["_tvp", k, "sr"] = now["Sr"][:, k]
            tvp["_tvp", k, "ur"] = now["Ur"][min(k, N - 1)]
        return tvp

    mpc.set_tvp_fun(tvp_fun)
    mpc.setup()
    started = [False]

    def step(state, ref):
        s0 = np.array(state, dtype=float)
        s0[c.model.pole] = float(ref[0]) + wrap_angle(s0[c.model.pole] - float(ref[0]))
        now["Sr"], now["Ur"] = c.references(ref)
        if not started[0]:
            mpc.x0 = s0.reshape(-1, 1)
            mpc.set_initial_guess()
            started[0] = True
        return float(np.asarray(mpc.make_step(s0.reshape(-1, 1))).ravel()[0])

    return step


def build(scenario, kind: str):
    """``kind`` designed on the scenario's nominal machine and reset, as a run builds it
    (mpc designs on a model of the machine)."""
    return build_controller(scenario, kind=kind)


def timed(fn, *args):
    w, c = time.perf_counter(), time.process_time()
    out = fn(*args)
    return out, 1e3 * (time.perf_counter() - w), 1e3 * (time.process_time() - c)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenario", default="pendulum_mujoco")
    ap.add_argument("--samples", type=int, default=250)
    ap.add_argument("--horizon", type=int, default=30)
    ap.add_argument("--scheme", default="rti", choices=("rti", "sqp"))
    ap.add_argument("--solver", default="qrqp",
                    help="QP solver(s) of the fast scheme, comma-separated")
    ap.add_argument("--no-dompc", action="store_true", help="leave the peer out")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a scenario override (a number), e.g. effects.saturation=60")
    ap.add_argument("--uncompiled", action="store_true",
                    help="also the fast scheme with compiled = false (CasADi's virtual machine)")
    ap.add_argument("--constraints", action="store_true",
                    help="only the cost of the task's constraints in the OCP")
    ap.add_argument("--costs", metavar="SCENARIO:SECONDS,...",
                    help="only the closed-loop costs: the fast scheme against IPOPT on each")
    short_defaults(ap, samples=10)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    if args.costs:
        costs(args)
        return
    if args.constraints:
        constraints(args)
        return
    qp_solvers = args.solver.split(",")
    base = {"controllers.mpc.horizon": args.horizon, "controllers.mpc.solver": qp_solvers[0]}
    for item in args.set:
        key, _, value = item.partition("=")
        base[key] = float(value)
    period = 0.02
    s_fast = override(load_scenario(args.scenario),
                      **{**base, "run.duration": period * args.samples,
                         "controllers.mpc.scheme": args.scheme})
    s_ipopt = override(s_fast, **{"controllers.mpc.scheme": "ipopt"})
    print(f"# mpc_speed: {args.scenario}, horizon {args.horizon}, {args.samples} samples of "
          f"{period * 1e3:g} ms, fast scheme {args.scheme} on {args.solver}; {args.set}; "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores at start")
    r_fast = run(s_fast, controller="mpc")
    h = r_fast.history
    every = int(round(period / s_fast.run.dt))
    held = np.arange(0, h["t"].size, every)
    states, refs = h["state"][held], h["ref"][held]

    fast, ipopt = build(s_fast, "mpc"), build(s_ipopt, "mpc")
    solvers = {f"{args.scheme}/{qp_solvers[0]}": fast.act, "ipopt": ipopt.act}
    for name in qp_solvers[1:]:
        other = build(override(s_fast, **{"controllers.mpc.solver": name}), "mpc")
        solvers[f"{args.scheme}/{name}"] = other.act
    if args.uncompiled:
        vm = build(override(s_fast, **{"controllers.mpc.compiled": False}), "mpc")
        solvers[f"{args.scheme}/{qp_solvers[0]}/vm"] = vm.act
    if not args.no_dompc:
        solvers["do-mpc"] = dompc_peer(ipopt)
    wall = {k: [] for k in solvers}
    cpu = {k: [] for k in solvers}
    u = {k: [] for k in solvers}
    for st, rf in zip(states, refs):
        for name, fn in solvers.items():
            out, w, c = timed(fn, st, rf)
            wall[name].append(w)
            cpu[name].append(c)
            u[name].append(out)
    base_w, base_c = np.median(wall["ipopt"]), np.median(cpu["ipopt"])
    print(f"{'solver':<14} {'wall median':>12} {'wall max':>10} {'cpu median':>11} "
          f"{'cpu max':>9} {'cpu max warm':>13} {'ipopt/x wall':>13} {'ipopt/x cpu':>12} "
          f"{'max|u-u_ipopt|':>15}")
    for name in solvers:
        w, c = np.asarray(wall[name]), np.asarray(cpu[name])
        du = np.max(np.abs(np.asarray(u[name]) - np.asarray(u["ipopt"])))
        print(f"{name:<14} {np.median(w):>10.3f}ms {w.max():>8.2f}ms {np.median(c):>9.3f}ms "
              f"{c.max():>7.2f}ms {c[1:].max():>11.2f}ms "
              f"{base_w / np.median(w):>12.1f}x {base_c / np.median(c):>11.1f}x "
              f"{du:>15.3g}")
    # the closed loop: the fast scheme's run above against IPOPT's on the same scenario
    r_ipopt = run(s_ipopt, controller="mpc")
    dt = s_fast.run.dt
    j_fast = fast.running_cost(h["state"], h["ref"], h["u"], dt)
    hi = r_ipopt.history
    j_ipopt = fast.running_cost(hi["state"], hi["ref"], hi["u"], dt)
    m_fast, m_ipopt = r_fast.metrics, r_ipopt.metrics
    print(f"closed loop {period * args.samples:g} s: cost {args.scheme} {j_fast:.6g}, ipopt "
          f"{j_ipopt:.6g}, ratio {j_fast / j_ipopt:.6f}; controller_ms median/max "
          f"{args.scheme} {m_fast['controller_ms']['median']:.3f}/"
          f"{m_fast['controller_ms']['max']:.2f}, ipopt "
          f"{m_ipopt['controller_ms']['median']:.3f}/{m_ipopt['controller_ms']['max']:.2f}; "
          f"failures {m_fast['counters']['solve_failures']:.0f}/"
          f"{m_ipopt['counters']['solve_failures']:.0f}")


#: the constraints ``--constraints`` adds: a soft box and a velocity-dependent linear row
CONSTRAINTS = {"task.constraints.box.slider": {"lo": -0.75, "hi": 0.75},
               "task.constraints.linear.ahead": {"terms": {"slider": 1.0, "slider_dot": 0.3,
                                                           "force": 1e-4},
                                                 "min": -0.7, "max": 0.7}}


def constraints(args) -> None:
    """Per-sample CPU time with and without the task's constraints in the OCP."""
    period = 0.02
    s = override(load_scenario(args.scenario),
                 **{"controllers.mpc.horizon": args.horizon, "run.duration": period * args.samples,
                    "controllers.mpc.scheme": args.scheme, **CONSTRAINTS})
    print(f"# mpc_speed --constraints: {args.scenario}, horizon {args.horizon}, {args.samples} "
          f"samples, {args.scheme}; load average {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} cores at start")
    r = run(override(s, **{"controllers.mpc.solver": "hpipm"}), controller="mpc")
    h = r.history
    held = np.arange(0, h["t"].size, int(round(period / s.run.dt)))
    states, refs = h["state"][held], h["ref"][held]
    outside = {k: v["samples_outside"] for k, v in r.metrics["constraints"].items()}
    print(f"closed loop with them (hpipm): {r.status}, samples outside {outside}, failures "
          f"{r.metrics['counters']['solve_failures']:.0f}")
    cases = {}
    for solver in ("qrqp", "hpipm", "daqp"):
        cases[f"{solver} without"] = build(override(s, **{"controllers.mpc.solver": solver,
                                                          "controllers.mpc.constraints": False}),
                                           "mpc")
        if solver != "qrqp":
            cases[f"{solver} with"] = build(override(s, **{"controllers.mpc.solver": solver}),
                                            "mpc")
    cpu = {k: [] for k in cases}
    for st, rf in zip(states, refs):
        for name, c in cases.items():
            _, _, ms = timed(c.act, st, rf)
            cpu[name].append(ms)
    print(f"{'case':<14} {'cpu median':>11} {'cpu max warm':>13} {'failures':>9} "
          f"{'with/without':>13} {'/ qrqp without':>15}")
    ref = np.median(cpu["qrqp without"])
    for name, c in cases.items():
        x = np.asarray(cpu[name])
        solver = name.split()[0]
        ratio = (f"{np.median(x) / np.median(cpu[solver + ' without']):>12.2f}x"
                 if name.endswith("with") else f"{'':>13}")
        print(f"{name:<14} {np.median(x):>9.3f}ms {x[1:].max():>11.2f}ms "
              f"{c.failures:>9d} {ratio} {np.median(x) / ref:>14.2f}x")


def costs(args) -> None:
    """The fast scheme's closed-loop cost against IPOPT's on each scenario named."""
    print(f"# mpc_speed --costs: {args.scheme} on {args.solver.split(',')[0]} against ipopt, "
          f"horizon {args.horizon}; load average {os.getloadavg()[0]:.1f} at start")
    print(f"{'scenario':<26} {'s':>4} {'J ipopt':>10} {'J fast':>10} {'fast/ipopt':>11} "
          f"{'fast ms med/max':>16} {'ipopt ms med/max':>17} {'failures':>9}")
    ratios = []
    for item in args.costs.split(","):
        name, _, seconds = item.partition(":")
        s = override(load_scenario(name), **{"run.duration": float(seconds or 5.0),
                                             "controllers.mpc.horizon": args.horizon,
                                             "controllers.mpc.solver": args.solver.split(",")[0]})
        out = {}
        for scheme in ("ipopt", args.scheme):
            si = override(s, **{"controllers.mpc.scheme": scheme})
            r = run(si, controller="mpc")
            h = r.history
            out[scheme] = (r.controller.running_cost(h["state"], h["ref"], h["u"], si.run.dt),
                           r.metrics, r.status)
        (ji, mi, sti), (jf, mf, stf) = out["ipopt"], out[args.scheme]
        ratios.append(jf / ji)
        def ms(m: dict) -> str:
            return f"{m['controller_ms']['median']:.2f}/{m['controller_ms']['max']:.1f}"

        print(f"{name:<26} {s.run.duration:>4g} {ji:>10.5g} {jf:>10.5g} {jf / ji:>11.6f} "
              f"{ms(mf):>16} {ms(mi):>17} "
              f"{mf['counters']['solve_failures']:.0f}/{mi['counters']['solve_failures']:.0f}"
              f"{'' if sti == stf == 'completed' else f' ({sti}, {stf})'}")
    print(f"largest |fast/ipopt - 1| over {len(ratios)} scenarios: "
          f"{max(abs(r - 1.0) for r in ratios):.2e}")


if __name__ == "__main__":
    main()
