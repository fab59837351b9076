"""The paper's examples, second type against first type: the README's metrics table.

Runs every paper scenario (20 s, the scenario's seed) with ``adaptation = "second"``
(consequents and BMF control points adapt) and ``"first"`` (consequents only, the
paper's implicit baseline), and prints one markdown table:

    python benchmarks/paper_table.py
"""

from __future__ import annotations

from tspend import load_scenario, override, run

SCENARIOS = ("ex1_nonaffine_case1", "ex1_nonaffine_case2", "ex2_duffing", "ex3_pendulum_ode",
             "pendulum_mujoco", "ex1_nonaffine_case1_tuned", "ex1_nonaffine_case2_tuned",
             "third_order")
COLUMNS = ("rmse", "rmse_ss", "max_abs_e_ss", "iae", "ise", "itae", "control_energy",
           "max_abs_u", "tv_u_per_s")


def fmt(v) -> str:
    return "n/a" if v is None else f"{v:.3g}"


def main() -> None:
    print("| scenario | type | status | " + " | ".join(COLUMNS) + " |")
    print("|---|---|---|" + "---|" * len(COLUMNS))
    for name in SCENARIOS:
        for kind in ("second", "first"):
            scn = override(load_scenario(name), **{"controller.adaptation": kind})
            r = run(scn, keep_history=False)
            cells = " | ".join(fmt(r.metrics[c]) for c in COLUMNS)
            print(f"| {name} | {kind} | {r.status} | {cells} |", flush=True)


if __name__ == "__main__":
    main()
