"""Every controller kind on each paper case and on the MuJoCo pendulum: the README table.

    python benchmarks/controller_table.py [--duration 20] [--seeds 1]

Each scenario runs as shipped (plant, reference, disturbance, 20 s at 1 ms, its seed)
under every kind of ``tspend.controllers.KINDS``, the baselines with the scenario's
``[controllers.KIND]`` tables or their defaults.  ``rmse_ss`` and ``max_abs_e_ss`` are
over the last half of the run, ``control_energy`` is ``int u^2 dt``, ``tv_u_per_s`` the
chattering, ``wall_s`` the loop's wall time.  A run that diverges is listed with the
runner's reason.  The baselines draw nothing from the seed (their runs are identical for
every seed); ``--seeds N`` reports the paper controller's median over seeds 1..N, with
the range over the seeds after its ``rmse_ss``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tspend import load_scenario, override, run  # noqa: E402
from tspend.controllers import KINDS  # noqa: E402
from tspend.runtime.errors import ScenarioError  # noqa: E402
from short_mode import short_defaults

SCENARIOS = ("ex1_nonaffine_case1", "ex1_nonaffine_case2", "ex2_duffing", "ex3_pendulum_ode",
             "pendulum_mujoco")
COLUMNS = ("rmse_ss", "max_abs_e_ss", "control_energy", "max_abs_u", "tv_u_per_s", "wall_s")
SEEDED = ("second_type", "first_type")


def fmt(v) -> str:
    return "n/a" if v is None else f"{v:.3g}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--duration", type=float, default=None, help="override run.duration")
    ap.add_argument("--seeds", type=int, default=1, help="seeds for the seeded kinds")
    short_defaults(ap, duration=1.0)
    a = ap.parse_args()
    print("| scenario | kind | status | " + " | ".join(COLUMNS) + " |")
    print("|---|---|---|" + "---|" * len(COLUMNS))
    for name in SCENARIOS:
        base = load_scenario(name)
        if a.duration is not None:
            base = override(base, **{"run.duration": a.duration})
        for kind in KINDS:
            seeds = range(1, a.seeds + 1) if kind in SEEDED else (base.run.seed,)
            try:
                results = [run(override(base, **{"run.seed": s}) if a.seeds > 1 else base,
                               controller=kind, keep_history=False) for s in seeds]
            except ScenarioError as exc:
                # a kind that cannot run on this plant (a full-state or swing-up kind on
                # a paper ODE; a policy without its file) says why, as tspend run does
                why = str(exc).split(": ", 1)[-1][:120]
                print(f"| {name} | {kind} | refused ({why}) |" + " |" * len(COLUMNS),
                      flush=True)
                continue
            status = ", ".join(sorted({r.status for r in results}))
            note = "; ".join(sorted({r.end.message for r in results if r.end.message}))
            cells = []
            for c in COLUMNS:
                vals = [r.metrics[c] for r in results if r.metrics.get(c) is not None]
                cell = fmt(statistics.median(vals)) if vals else "n/a"
                if c == "rmse_ss" and len(vals) > 1:
                    cell += f" [{fmt(min(vals))}, {fmt(max(vals))}]"
                cells.append(cell)
            status = f"{status} ({note})" if note else status
            print(f"| {name} | {kind} | {status} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
