"""``tspend plan SCENARIO --out plan.parquet``: a planned swing-up to the upright.

Trajectory optimisation (:mod:`tspend.controllers.trajectory`: direct multiple shooting,
IPOPT, on the domain's own equations) from the scenario's initial state at its seed (the
state a run at that seed starts from; ``--nominal``: the scenario's own, nothing drawn) to the upright at rest, within the actuator's range
and the positions' ranges; the settings are ``[controllers.tvlqr]``'s (``horizon``,
``interval``, ``step``, ``margin``, ``max_iter``, ``tolerance``; ``--set`` overrides them).
The file holds ``t``, every state by the plant's names and ``u`` on the run's step, the
units and the solver's figures in the Parquet metadata; ``tspend run SCENARIO --controller
tvlqr --set controllers.tvlqr.plan=PATH`` follows it.

Exit status: 0 a plan was written; 1 the solver found none (why on stderr; nothing
written); 2 bad input (a machine without a symbolic full-state model, a horizon shorter
than 2 intervals, a start outside the bounds, an output path).
"""

from __future__ import annotations

import argparse
import json

from tspend.cli.common import (EXIT_OK, add_metrics_option, add_scenario_options, load_with_overrides,
                             plan as plan_outputs, printable, say, scenario_inputs)
from tspend.runtime.outputs import OutputRequest, display

#: the solver found no plan (nothing written)
EXIT_NO_PLAN = 1


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("plan", help="plan a swing-up to the upright by trajectory optimisation",
                       description=__doc__.split("\n\n")[1].replace("\n", " "))
    p.add_argument("scenario", metavar="SCENARIO", help="a scenario name or .toml path")
    add_scenario_options(p, recording=False)
    p.add_argument("--out", required=True, metavar="PATH.parquet", help="the plan to write "
                   "(an existing file is replaced only by a complete plan)")
    p.add_argument("--nominal", action="store_true",
                   help="plan from the scenario's own initial state, without what [randomize] "
                        "draws at the seed")
    add_metrics_option(p, "the solver's figures")
    return p


def cmd(args: argparse.Namespace) -> int:
    import time

    import numpy as np

    from tspend.controllers import unsupported
    from tspend.controllers.trajectory import (PlanFailed, check_plan_input,
                                               plan_swingup, write_plan)
    from tspend.controllers.tvlqr import plan_of
    from tspend.runtime.errors import ScenarioError
    from tspend.loop.simulation import build_plant, nominal_machine

    scn = load_with_overrides(args)
    why = unsupported(scn, "tvlqr")
    if why:
        raise ScenarioError(why.replace("controller 'tvlqr' cannot run", "cannot plan"))
    requests = [OutputRequest("--out", "plan", ".parquet", args.out)]
    if args.metrics is not None:
        requests.append(OutputRequest("--metrics", "solver figures", ".json", args.metrics))
    targets = [p.target for p in plan_outputs(requests, scenario_inputs(scn))]
    model, s, units = plan_of(scn, nominal_machine(scn))
    if args.nominal:   # the scenario's own x0 and q0, nothing drawn
        from tspend.plants.registry import build as build_nominal

        machine = build_nominal(scn)
        machine.reset(np.asarray(scn.plant.x0, dtype=float))
        start = machine.full_state().copy()
    else:
        start = build_plant(scn).full_state().copy()
    where = f"{scn.path or scn.name}: controllers.tvlqr"
    check_plan_input(model, start, s.horizon, s.interval, scn.run.dt, s.margin, where, s.step)
    print(f"planning {scn.name}: {s.horizon:g} s to the upright, intervals of {s.interval:g} s "
          f"(RK4 step {s.step:g} s), from {', '.join(f'{n} = {v:.4g}' for n, v in zip(model.state_names, start))}",
          flush=True)
    started = time.perf_counter()
    guard = getattr(args, "guard", None)
    # IPOPT turns a signal's exception into a status of its own: the guard knows better
    stopped = None if guard is None else (lambda: guard.stop.signal_name is not None)
    try:
        result = plan_swingup(model, start, s.horizon, s.interval, scn.run.dt, step=s.step,
                              margin=s.margin, max_iter=s.max_iter, tolerance=s.tolerance,
                              where=where, units=units, stopped=stopped)
    except PlanFailed as exc:
        if guard is not None:
            guard.raise_if_stopped()  # an interrupt, not "no plan": its own exit status
        say(f"no plan: {printable(exc)}; nothing written")
        return EXIT_NO_PLAN
    wall = time.perf_counter() - started
    result.solver["planning_s"] = wall
    from tspend.runtime.outputs import write_atomic

    write_atomic(targets[0], lambda tmp: write_plan(result, tmp), what="plan")
    figures = dict(result.solver, scenario=scn.name, seed=scn.run.seed, horizon_s=s.horizon,
                   interval_s=s.interval, max_abs_u=float(abs(result.u).max()),
                   u_unit=result.u_unit)
    if args.metrics is not None:
        write_atomic(targets[1], lambda tmp: tmp.write_text(json.dumps(figures, indent=2) + "\n"),
                     what="solver figures")
    print(f"plan: {display(targets[0])} ({result.t.size} rows of {result.dt:g} s)")
    print(f"  solver      IPOPT {result.solver['status']}, {result.solver['iterations']} "
          f"iterations, cost {result.solver['cost']:.6g}")
    print(f"  planning_s  {wall:.3g} (IPOPT {result.solver['total_solve_s']:.3g} s)")
    print(f"  max |u|     {figures['max_abs_u']:.4g} {result.u_unit}")
    return EXIT_OK
