"""What balances what: every controller kind on every articulated machine, over seeds.

Each seed draws the machine's start: every pole tilted by an angle uniform in
[-TILT, TILT] rad (the cart, arm or wheel at 0, all at rest), the same start for every kind.
Each run lasts DURATION s on MuJoCo.  A run counts as balanced when it ends `completed`
(no pole past the fall angle, no joint past its range) with every pole within 0.05 rad
of upright at the end.  Kinds a machine cannot serve are refused in one line (the reason
is printed); `policy` needs a trained policy per machine (none is shipped for these),
`mpc` is left out (its IPOPT solve on these machines takes ~0.2 s a sample: see
docs/controllers.md).

Writes the table between the markers in docs/controllers.md (``--write``) and prints it.

    python benchmarks/machines_table.py [--seeds 0:20] [--jobs 2] [--write]
"""

from __future__ import annotations

import argparse
import math
import re
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
MACHINES = ("double_cartpole", "triple_cartpole", "acrobot", "pendubot", "reaction_wheel",
            "rotary_double")
KINDS = ("lqr", "pd", "second_type", "first_type", "sliding_mode", "feedback_linearization",
         "wang_indirect", "swingup")
TILT = 0.1
DURATION = 5.0
UPRIGHT = 0.05
BEGIN, END = "<!-- machines x kinds: begin -->", "<!-- machines x kinds: end -->"


def one(job: tuple[str, str, int]) -> dict:
    from tspend import load_scenario, override
    from tspend.controllers import unsupported
    from tspend.runtime.errors import ScenarioError
    from tspend.loop.simulation import run
    from tspend.plants.articulated.machine import load_machine

    machine, kind, seed = job
    base = load_scenario(f"{machine}_mujoco")
    m = load_machine(ROOT / "models" / f"{machine}.xml")
    rng = np.random.default_rng(seed)
    q0 = np.zeros(m.nv)
    for j in m.poles:
        q0[j] = rng.uniform(-TILT, TILT)
    v = m.view_joint
    scn = override(base, **{"run.duration": DURATION, "plant.q0": tuple(q0),
                            "plant.x0": (float(q0[v]), 0.0)})
    why = unsupported(scn, kind)
    if why is not None:
        return {"machine": machine, "kind": kind, "seed": seed, "refused": why.split(": ", 2)[-1]}
    try:
        r = run(scn, controller=kind, keep_history=False)
    except ScenarioError as exc:
        return {"machine": machine, "kind": kind, "seed": seed, "refused": str(exc).split(": ", 1)[-1]}
    s = r.plant.full_state()
    final = max((abs(float(s[j])) for j in m.poles), default=0.0)
    ok = r.status == "completed" and final <= UPRIGHT
    return {"machine": machine, "kind": kind, "seed": seed, "status": r.status, "balanced": ok,
            "rmse": float(r.metrics.get("rmse", math.nan))}


def table(rows: list[dict], seeds: int) -> str:
    lines = [f"| machine | " + " | ".join(f"`{k}`" for k in KINDS) + " |",
             "|---|" + "---|" * len(KINDS)]
    for machine in MACHINES:
        cells = []
        for kind in KINDS:
            mine = [r for r in rows if r["machine"] == machine and r["kind"] == kind]
            if mine and "refused" in mine[0]:
                cells.append("refused")
                continue
            n = sum(r["balanced"] for r in mine)
            rmse = np.array([r["rmse"] for r in mine if r["balanced"]])
            cell = f"{n}/{len(mine)}"
            if rmse.size:
                cell += f" ({np.median(rmse):.2g} rad)"
            cells.append(cell)
        lines.append(f"| {machine} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="0:20")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--write", action="store_true", help="write the table into docs/controllers.md")
    args = ap.parse_args()
    a, b = (int(v) for v in args.seeds.split(":"))
    jobs = [(m, k, s) for m in MACHINES for k in KINDS for s in range(a, b)]
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = list(pool.map(one, jobs, chunksize=4))
    text = table(rows, b - a)
    reasons = sorted({(r["kind"], r["refused"]) for r in rows if "refused" in r})
    notes = "\n".join(f"- `{k}` refused: {why}" for k, why in reasons)
    statuses: dict[tuple[str, str], dict[str, int]] = {}
    for r in rows:
        if "status" in r:
            d = statuses.setdefault((r["machine"], r["kind"]), {})
            d[r["status"]] = d.get(r["status"], 0) + 1
    block = (f"{text}\n\nBalanced runs of {b - a} seeds (median rmse of the tracked pole over the "
             f"balanced ones); start: every pole tilted uniformly in [-{TILT}, {TILT}] rad; "
             f"{DURATION:g} s on MuJoCo; balanced = `completed` and every pole within {UPRIGHT} rad "
             f"at the end.\n\n{notes}")
    print(block)
    print("\nstatuses:", {f"{m}/{k}": v for (m, k), v in statuses.items()})
    if args.write:
        path = ROOT / "docs" / "controllers.md"
        doc = path.read_text()
        if BEGIN in doc:
            doc = re.sub(re.escape(BEGIN) + ".*?" + re.escape(END), BEGIN + "\n" + block + "\n" + END,
                         doc, flags=re.S)
        else:
            doc += f"\n## Every machine of the articulated domain\n\n{BEGIN}\n{block}\n{END}\n"
        path.write_text(doc)


if __name__ == "__main__":
    main()
