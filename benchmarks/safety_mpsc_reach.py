"""Whether a drawn start of the randomised cart-pole (benchmarks/safety_filter.py's
cartpole_rail: pendulum_mujoco_randomized, 1 m rail) can be certified by --safety mpsc at
all: the least peak |cart| any input within the actuator's range reaches while bringing
the machine to rest upright, on the drawn machine itself and on every vertex of the
[randomize] box (the models the certificate (P6) must keep inside its bound).

    python benchmarks/safety_mpsc_reach.py --seeds 0,15

For each seed: an NLP (CasADi + IPOPT) over 3 s of inputs held for 1 ms, then every 10 ms
(a grid that holds every input the certificate's plans apply: 1 ms, then RK4 steps of
50 ms), RK4 at that grid on the domain's own model: min t subject to |x_k| <= t, the
input's range, and the state at rest upright at the end.  A vertex whose least peak is
above the certificate's bound (hi_check of the rail) is evidence that no plan is
certified from that start, whatever the QP does: not a proof, since a certified plan
ends in the terminal set X_f, not at rest (asking rest within 3 s may cost a longer
excursion), and its tracked inputs are not held on this grid.  The drawn machine's own
least peak below 1 m says the start was recoverable by an input that knew the machine.  Writes
benchmarks/results/safety_mpsc_reach.json.
"""

from __future__ import annotations

import argparse
import json
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"


def least_peak(model, s0: np.ndarray, horizon_s: float = 3.0) -> float:
    """min over inputs of max |cart| from ``s0`` to rest upright (module docstring)."""
    import casadi as ca

    F0, F = model.rk4_map(0.001, 1), model.rk4_map(0.01, 1)
    N = int(round((horizon_s - 0.001) / 0.01)) + 1
    opti = ca.Opti()
    # the input scaled to [-1, 1] (the range is +/-2000 N: IPOPT stalled unscaled)
    X, V, t = opti.variable(model.size, N + 1), opti.variable(1, N), opti.variable()
    scale = max(abs(model.u_lo), abs(model.u_hi))
    opti.subject_to(X[:, 0] == s0)
    for k in range(N):
        opti.subject_to(X[:, k + 1] == (F0 if k == 0 else F)(X[:, k], scale * V[0, k]))
    opti.subject_to(opti.bounded(model.u_lo / scale, V, model.u_hi / scale))
    opti.subject_to(opti.bounded(-t, X[0, :], t))
    opti.subject_to(X[:, N] == 0)
    opti.minimize(t)
    opti.set_initial(t, 1.0)
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "max_iter": 3000, "sb": "yes"})
    return float(opti.solve().value(t))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0,15", help="comma-separated seeds (at most 40)")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    if not 1 <= len(seeds) <= 40:
        ap.error("--seeds: 1 to 40 seeds")
    warnings.simplefilter("ignore")
    from safety_filter import MACHINES
    from tspend import load_scenario, override
    from tspend.controllers.full_model import full_model
    from tspend.controllers.mpsc import vertex_models
    from tspend.loop.simulation import prepare
    from tspend.plants import registry
    from tspend.plants.randomize import draw

    name, changes = MACHINES["cartpole_rail"]
    base = override(load_scenario(name), **{k: v for k, v in changes.items()
                                            if not k.startswith("controllers.")})
    filt = prepare(override(base, **{"safety.filter": "mpsc"}), controller="pd").controller
    bound = float(filt.cert.hi_check[0])
    vertices, params = vertex_models(base)
    out = {"certificate_bound_m": bound, "rail_m": 1.0, "vertex_parameters": params,
           "seeds": {}}
    path = RESULTS / "safety_mpsc_reach.json"
    if path.is_file():
        out["seeds"] = json.loads(path.read_text()).get("seeds", {})
    for seed in seeds:
        drawn = draw(override(base, **{"run.seed": seed})).scenario
        theta, rate = drawn.plant.x0
        s0 = np.array([0.0, theta, 0.0, rate])
        own = least_peak(full_model(drawn, registry.build(replace(drawn, randomize=()))), s0)
        peaks = [least_peak(m, s0) for m in vertices]
        out["seeds"][str(seed)] = {"x0": [float(theta), float(rate)], "own_least_peak_m": own,
                                   "vertex_least_peak_m": peaks,
                                   "worst_vertex_least_peak_m": max(peaks),
                                   "vertices_above_bound": int(sum(p > bound for p in peaks))}
        print(f"seed {seed}: x0 {theta:+.3f} rad {rate:+.3f} rad/s; own machine {own:.3f} m; "
              f"worst vertex {max(peaks):.3f} m; {sum(p > bound for p in peaks)} of "
              f"{len(peaks)} vertices above the certificate's {bound:.3f} m", flush=True)
    path.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
