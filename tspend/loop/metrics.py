"""Tracking and control metrics, accumulated block by block so memory stays flat.

The paper gives figures only; these are the numbers a researcher can quote.  All
integrals are rectangle sums over the controller samples (the signals are piecewise
constant at the sample rate), on the tracking error of the output ``e_1 = x_1 - r``:

* ``rmse``, ``max_abs_e``: over the whole run; ``rmse_ss``, ``max_abs_e_ss``: over the
  steady-state window, the last half of the run (``t >= duration / 2``);
* ``iae`` = int |e1| dt, ``ise`` = int e1^2 dt, ``itae`` = int t |e1| dt;
* ``control_energy`` = int u^2 dt, ``max_abs_u``;
* ``tv_u_per_s``: chattering, the total variation of u per second of simulated time.
"""

from __future__ import annotations

import math

import numpy as np

from tspend.loop.sinks import Block, InnerSnapshot, RunEnd, RunInfo

#: keys every metrics dictionary has (the CLI writes them as JSON)
METRIC_KEYS = ("rmse", "rmse_ss", "max_abs_e", "max_abs_e_ss", "iae", "ise", "itae",
               "control_energy", "max_abs_u", "tv_u_per_s", "wall_s", "sim_s", "steps", "seed")


class MetricsAccumulator:
    """A sink that folds each block into running sums; :meth:`result` gives the metrics."""

    def __init__(self, dt: float, ss_start: float, seed: int = 0) -> None:
        self.dt = dt
        self.ss_start = ss_start
        self.seed = seed
        self.steps = 0
        self.sum_e2 = self.sum_abs_e = self.sum_t_abs_e = self.sum_u2 = 0.0
        self.max_abs_e = self.max_abs_u = 0.0
        self.ss_steps = 0
        self.ss_sum_e2 = 0.0
        self.ss_max_abs_e = 0.0
        self.tv_u = 0.0
        self.u_last: float | None = None

    # sink protocol ----------------------------------------------------------------------
    def start(self, info: RunInfo) -> None:
        pass

    def inner(self, snap: InnerSnapshot) -> None:
        pass

    def finish(self, end: RunEnd) -> None:
        pass

    def block(self, block: Block) -> None:
        t = block.data["t"]
        if t.size == 0:
            return
        e1 = block.data["e"][:, 0]
        u = block.data["u"]
        abs_e = np.abs(e1)
        self.steps += t.size
        self.sum_e2 += float(e1 @ e1)
        self.sum_abs_e += float(abs_e.sum())
        self.sum_t_abs_e += float(t @ abs_e)
        self.sum_u2 += float(u @ u)
        self.max_abs_e = max(self.max_abs_e, float(abs_e.max()))
        self.max_abs_u = max(self.max_abs_u, float(np.abs(u).max()))
        steady = t >= self.ss_start - 0.5 * self.dt
        if steady.any():
            e_ss = e1[steady]
            self.ss_steps += e_ss.size
            self.ss_sum_e2 += float(e_ss @ e_ss)
            self.ss_max_abs_e = max(self.ss_max_abs_e, float(np.abs(e_ss).max()))
        if self.u_last is not None:
            self.tv_u += abs(float(u[0]) - self.u_last)
        self.tv_u += float(np.abs(np.diff(u)).sum())
        self.u_last = float(u[-1])

    def result(self, wall_s: float = 0.0) -> dict:
        """The metrics so far; quantities over an empty window are None (JSON null)."""
        dt, n = self.dt, self.steps
        sim_s = n * dt

        def finite(v: float) -> float | None:
            return v if math.isfinite(v) else None

        return {
            "rmse": finite(math.sqrt(self.sum_e2 / n)) if n else None,
            "rmse_ss": finite(math.sqrt(self.ss_sum_e2 / self.ss_steps)) if self.ss_steps else None,
            "max_abs_e": finite(self.max_abs_e) if n else None,
            "max_abs_e_ss": finite(self.ss_max_abs_e) if self.ss_steps else None,
            "iae": finite(self.sum_abs_e * dt),
            "ise": finite(self.sum_e2 * dt),
            "itae": finite(self.sum_t_abs_e * dt),
            "control_energy": finite(self.sum_u2 * dt),
            "max_abs_u": finite(self.max_abs_u) if n else None,
            "tv_u_per_s": finite(self.tv_u / sim_s) if n else None,
            "wall_s": wall_s,
            "sim_s": sim_s,
            "steps": n,
            "seed": self.seed,
        }
