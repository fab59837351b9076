"""The QUBE Furuta pendulum linearised (docs/furuta.md, "Linearisation"): A and B upright,
the eigenvalues upright and hanging, and the LQR gain for Q = diag(5, 1, 0.05, 0.05), R = 1,
written to benchmarks/results/furuta_linearization.json for tools/check_claims.py.

Run: ``python benchmarks/furuta_linearization.py [--out PATH]`` (about a second).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import control
import numpy as np

import tspend

OUT = Path(__file__).resolve().parent / "results" / "furuta_linearization.json"
Q, R = np.diag([5.0, 1.0, 0.05, 0.05]), np.eye(1)


def measure(scenario: str = "furuta_ode") -> dict:
    up = tspend.linearize(scenario)
    pendulum = [n for n in up.state_labels if "pendulum" in n and "dot" not in n][0]
    down = tspend.linearize(scenario, at={pendulum: math.pi})

    def eig(A: np.ndarray) -> list[list[float]]:
        ev = sorted(np.linalg.eigvals(A), key=lambda z: (-z.real, z.imag))
        return [[float(z.real), float(z.imag)] for z in ev]

    K, _, _ = control.lqr(up.A, up.B, Q, R)
    return {"scenario": scenario, "states": list(up.state_labels),
            "A": np.asarray(up.A).tolist(), "B": np.asarray(up.B).ravel().tolist(),
            "eig_upright": eig(np.asarray(up.A)), "eig_hanging": eig(np.asarray(down.A)),
            "lqr_Q_diag": [5.0, 1.0, 0.05, 0.05], "lqr_R": 1.0,
            "K": np.asarray(K).ravel().tolist()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=OUT, help=f"the JSON written (default {OUT})")
    args = ap.parse_args()
    data = measure()
    args.out.write_text(json.dumps(data, indent=1) + "\n")
    print(json.dumps(data, indent=1))


if __name__ == "__main__":
    main()
