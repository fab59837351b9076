"""Tracking and control metrics, accumulated block by block so memory stays flat.

The paper gives figures only; these are the numbers a researcher can quote.  All
integrals are rectangle sums over the controller samples (the signals are piecewise
constant at the sample rate), on the tracking error of the output ``e_1 = x_1 - r``.
Each input metric says which u it uses: the *command* (what the controller asked) or the
*applied* input (the command clipped to the actuator's range ``[u_lo, u_hi]`` when the
accumulator knows it, :class:`MachineInfo`; without one the two are the same):

* ``rmse``, ``max_abs_e``: over the whole run; ``rmse_ss``, ``max_abs_e_ss``: over the
  steady-state window, the last half of the run (``t >= duration / 2``);
* ``iae`` = int |e1| dt, ``ise`` = int e1^2 dt, ``itae`` = int t |e1| dt;
* ``control_energy`` = int u^2 dt of the *applied* input (what the actuator delivered,
  so ``control_energy <= max_abs_u^2 * sim_s``), ``control_energy_command`` = int u^2 dt
  of the *command* (a saturating controller's command can be far larger);
* ``max_abs_u``: the largest input *applied*, ``max_abs_u_command``: the largest
  *command*;
* ``tv_u_per_s``: chattering, the total variation of the *command* per second of
  simulated time (what the controller does, clipped or not).

Of the whole machine (issue 20; when the accumulator is given a :class:`MachineInfo`):

* ``joints.<name>.max_abs``, ``joints.<name>.final``: every joint's position (m or rad)
  from the block's full ``state``;
* ``plant``: the plant's physical parameters as simulated (:meth:`Plant.parameters`);
* ``drawn``: what the scenario's ``[randomize]`` drew at the run's seed (``{}``: nothing;
  :mod:`tspend.plants.randomize`);
* ``saturated_fraction``: the fraction of samples whose u lay outside the actuator's
  range (the *command* the actuator clipped); ``saturated_at_end_s``: for how long, at the
  end of the run, every sample was (a run the task ended says so in its message);
* ``controller_ms.median``, ``controller_ms.max``: the controller's wall time per
  evaluation (generic loop only: a compiled loop does not time single samples; then
  null).  The median comes from a log-spaced histogram (1 ns .. 100 s, 2 % bins), so
  memory stays flat on long runs;
* ``counters.<name>``: the last value of every diagnostic on the ``counters`` panel
  (MPC's ``solve_failures``, ``solve_overruns``);
* ``constraints.<name>``: per constraint of the task (:mod:`tspend.task.constraints`, the
  margin ``min(b - A [s, u])`` of (C1) at every recorded sample, ``u`` the command):
  ``samples_outside`` (margin below ``-1e-9 (1 + max |b|)``, so that round-off is not a
  violation: :data:`tspend.task.constraints.OUTSIDE_TOLERANCE`), ``time_outside_s``,
  ``max_depth`` (the largest ``-margin``, 0 when never outside), ``min_margin``, ``hard``; ``violations`` (samples with any constraint
  outside) and ``max_violation`` (the largest depth of any) are comparable metrics like
  ``rmse`` (0: every constraint held; a run the task ended scores +inf in a comparison).

:func:`flatten` turns the nested keys into ``joints.slider.max_abs`` columns (sweep rows).
"""

from __future__ import annotations

import math

import numpy as np

from dataclasses import dataclass, field

from tspend.loop.sinks import Block, InnerSnapshot, RunEnd, RunInfo

__all__ = ["METRIC_KEYS", "MACHINE_PREFIXES", "MachineInfo", "MetricsAccumulator", "flatten",
           "is_machine_column"]

#: log-spaced bins of the controller's compute time (s): 1 ns .. 100 s, ~2 % wide
_TIME_BINS = np.logspace(-9, 2, 1281)


@dataclass(frozen=True)
class MachineInfo:
    """What the machine metrics need of the plant: each joint's name and index in the
    full state, the parameters as simulated, and the input's range."""

    joints: tuple[tuple[str, int], ...] = ()
    parameters: dict = field(default_factory=dict)
    u_lo: float = -math.inf
    u_hi: float = math.inf
    #: what the scenario's [randomize] drew (flat name -> value; empty: nothing)
    drawn: dict = field(default_factory=dict)
    #: the task's goal: |e1| <= goal_angle from goal_by s on (0: none; tspend.config.TaskConfig)
    goal_angle: float = 0.0
    goal_by: float = 0.0
    #: the task's constraints (tspend.task.constraints.ConstraintSet; None: none measured)
    constraints: object = None
    #: u's unit ("ctrl" for a geared motor's control), and where u is not the force the
    #: actuator applies, that force's unit and the force per unit of u at rest
    #: (:class:`tspend.plants.base.InputInfo`)
    u_unit: str = ""
    force_unit: str = ""
    force_per_unit: float = 1.0


#: the flattened machine metrics' columns start with one of these (sweep rows)
MACHINE_PREFIXES = ("joints.", "plant.", "counters.", "controller_ms.", "saturated_",
                    "drawn.", "goal.", "constraints.", "safety_filter.", "actuator.")


def is_machine_column(name: str) -> bool:
    """Whether a sweep row's column is a flattened machine metric."""
    return name.startswith(MACHINE_PREFIXES)


def flatten(metrics: dict, prefix: str = "") -> dict:
    """``{"joints": {"slider": {"max_abs": 1}}}`` -> ``{"joints.slider.max_abs": 1}``."""
    out = {}
    for k, v in metrics.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flatten(v, key + "."))
        else:
            out[key] = v
    return out

#: keys every metrics dictionary has (the CLI writes them as JSON)
METRIC_KEYS = ("rmse", "rmse_ss", "max_abs_e", "max_abs_e_ss", "iae", "ise", "itae",
               "control_energy", "control_energy_command", "max_abs_u", "max_abs_u_command",
               "tv_u_per_s", "wall_s",
               "sim_s", "steps", "seed", "violations", "max_violation")


class MetricsAccumulator:
    """A sink that folds each block into running sums; :meth:`result` gives the metrics."""

    def __init__(self, dt: float, ss_start: float, seed: int = 0,
                 machine: MachineInfo | None = None) -> None:
        self.machine = machine
        self.joint_max = {name: 0.0 for name, _ in machine.joints} if machine else {}
        self.joint_final: dict[str, float] = {}
        self.saturated = 0
        self.time_hist = np.zeros(_TIME_BINS.size + 1, dtype=np.int64)
        self.time_max = 0.0
        self.timed = 0
        self.counters: dict[str, float] = {}
        self.counter_names: tuple[str, ...] = ()
        self.dt = dt
        self.ss_start = ss_start
        self.seed = seed
        self.steps = 0
        self.sum_e2 = self.sum_abs_e = self.sum_t_abs_e = self.sum_u2 = 0.0
        self.sum_u2_applied = 0.0
        self.max_abs_e = self.max_abs_u = self.max_abs_u_applied = 0.0
        #: the last sample's time at which |e1| lay outside the goal (None: never)
        self.last_outside: float | None = None
        #: how many samples at the end of the run so far had u clipped by the actuator
        self.saturated_at_end = 0
        self.ss_steps = 0
        self.ss_sum_e2 = 0.0
        self.ss_max_abs_e = 0.0
        self.tv_u = 0.0
        self.u_last: float | None = None
        C = len(machine.constraints) if machine is not None and machine.constraints is not None else 0
        self.c_outside = np.zeros(C, dtype=np.int64)
        self.c_depth = np.zeros(C)
        self.c_margin = np.full(C, np.inf)
        self.any_outside = 0

    # sink protocol ----------------------------------------------------------------------
    def start(self, info: RunInfo) -> None:
        self.counter_names = tuple(d.name for d in info.diagnostics if d.panel == "counters")

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
        m = self.machine
        if m is not None and m.goal_angle > 0.0:
            outside = np.flatnonzero(~(abs_e <= m.goal_angle))
            if outside.size:
                self.last_outside = float(t[outside[-1]])
        applied = np.clip(u, m.u_lo, m.u_hi) if m is not None else u
        self.max_abs_u_applied = max(self.max_abs_u_applied, float(np.abs(applied).max()))
        self.sum_u2_applied += float(applied @ applied)
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
        self._machine_block(block.data, u)
        self._constraints_block(block.data, u)

    def _constraints_block(self, data: dict, u: np.ndarray) -> None:
        m = self.machine
        state = data.get("state")
        if m is None or m.constraints is None or not len(m.constraints) or state is None:
            return
        margin = m.constraints.margins(state, u)                     # (k, C)
        # NaN (a diverged sample) is neither inside nor outside: not counted; nor is a
        # margin within the stated tolerance below 0 (round-off: tspend.task.constraints)
        outside = margin < -m.constraints.tolerances
        self.c_outside += outside.sum(axis=0)
        self.any_outside += int(np.count_nonzero(outside.any(axis=1)))
        with np.errstate(invalid="ignore"):
            self.c_depth = np.fmax(self.c_depth, np.nanmax(np.where(outside, -margin, 0.0), axis=0))
            self.c_margin = np.fmin(self.c_margin, np.nanmin(np.where(np.isnan(margin), np.inf,
                                                                      margin), axis=0))

    def constraints_result(self) -> dict:
        """Per constraint: samples and time outside, largest depth, smallest margin."""
        m = self.machine
        if m is None or m.constraints is None:
            return {}
        out = {}
        for i, c in enumerate(m.constraints):
            out[c.name] = {"hard": c.hard, "unit": c.unit,
                           "samples_outside": int(self.c_outside[i]),
                           "time_outside_s": float(self.c_outside[i]) * self.dt,
                           "max_depth": float(self.c_depth[i]),
                           "min_margin": float(self.c_margin[i]) if self.steps and
                           math.isfinite(self.c_margin[i]) else None}
        return out

    def _machine_block(self, data: dict, u: np.ndarray) -> None:
        m = self.machine
        if m is not None:
            state = data.get("state")
            if state is not None and state.shape[1]:
                for name, j in m.joints:
                    col = state[:, j]
                    self.joint_max[name] = max(self.joint_max[name], float(np.abs(col).max()))
                    self.joint_final[name] = float(col[-1])
            clipped = (u < m.u_lo) | (u > m.u_hi)
            self.saturated += int(np.count_nonzero(clipped))
            inside = np.flatnonzero(~clipped)
            self.saturated_at_end = (clipped.size - 1 - int(inside[-1]) if inside.size
                                     else self.saturated_at_end + clipped.size)
        for name in self.counter_names:
            if name in data and len(data[name]):
                self.counters[name] = float(np.asarray(data[name]).reshape(len(data[name]), -1)[-1, 0])

    #: the runner hands this sink the controller's wall time per sample
    wants_compute_times = True

    def compute_times(self, compute: np.ndarray) -> None:
        """The controller's wall time (s) per sample of the last block (NaN: held)."""
        c = compute[np.isfinite(compute)]
        if c.size:
            self.time_hist += np.bincount(np.searchsorted(_TIME_BINS, c),
                                          minlength=self.time_hist.size)
            self.time_max = max(self.time_max, float(c.max()))
            self.timed += c.size

    def _median_ms(self) -> float | None:
        if not self.timed:
            return None
        k = int(np.searchsorted(np.cumsum(self.time_hist), (self.timed + 1) // 2))
        lo = _TIME_BINS[k - 1] if k > 0 else _TIME_BINS[0]
        hi = _TIME_BINS[min(k, _TIME_BINS.size - 1)]
        return 1e3 * math.sqrt(lo * hi)

    def goal_result(self) -> dict:
        """The goal (``angle_rad``, ``by_s``), when it was reached to stay
        (``reached_at_s``: the first sample after the last one outside; None: never), and
        whether it was met (reached by ``by_s``; None when the run ended before ``by_s``)."""
        m = self.machine
        if not self.steps:
            reached = None
        elif self.last_outside is None:
            reached = 0.0
        else:
            reached = self.last_outside + self.dt
            if reached > (self.steps - 1) * self.dt + 1e-12:
                reached = None  # outside at the last sample
        # a run that ended before the deadline cannot be judged on it (a shortened run):
        # met is None, never a claim either way
        judged = self.steps and (self.steps - 1) * self.dt >= m.goal_by - 1e-12
        met = (reached is not None and reached <= m.goal_by + 1e-12) if judged else None
        return {"angle_rad": m.goal_angle, "by_s": m.goal_by, "reached_at_s": reached, "met": met}

    def actuator_result(self) -> dict:
        """u's unit ("ctrl" for a geared motor's control), and where u is not the force:
        the force's unit, the force per unit of u at rest and the largest force applied
        and commanded (max_abs_u and max_abs_u_command times it)."""
        m = self.machine
        out: dict = {"u_unit": m.u_unit}
        if m.force_unit:
            n = self.steps
            k = m.force_per_unit
            out.update(force_unit=m.force_unit, force_per_u=k,
                       max_abs_force=abs(k) * self.max_abs_u_applied if n else None,
                       max_abs_force_command=abs(k) * self.max_abs_u if n else None)
        return out

    def machine_result(self) -> dict:
        """The whole machine's metrics (module docstring); empty without a MachineInfo."""
        out: dict = {}
        m = self.machine
        if m is not None:
            out["joints"] = {name: {"max_abs": self.joint_max[name] if self.steps else None,
                                    "final": self.joint_final.get(name)}
                             for name, _ in m.joints}
            out["plant"] = dict(m.parameters)
            out["saturated_fraction"] = self.saturated / self.steps if self.steps else None
            out["saturated_at_end_s"] = self.saturated_at_end * self.dt
            out["drawn"] = dict(m.drawn)
            out["actuator"] = self.actuator_result()
            if m.goal_angle > 0.0:
                out["goal"] = self.goal_result()
        out["controller_ms"] = {"median": self._median_ms(),
                                "max": 1e3 * self.time_max if self.timed else None}
        if self.counters:
            out["counters"] = dict(self.counters)
        return out

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
            "control_energy": finite(self.sum_u2_applied * dt),
            "control_energy_command": finite(self.sum_u2 * dt),
            "max_abs_u": finite(self.max_abs_u_applied) if n else None,
            "max_abs_u_command": finite(self.max_abs_u) if n else None,
            "tv_u_per_s": finite(self.tv_u / sim_s) if n else None,
            "wall_s": wall_s,
            "sim_s": sim_s,
            "steps": n,
            "seed": self.seed,
            "violations": int(self.any_outside) if n else None,
            "max_violation": float(self.c_depth.max(initial=0.0)) if n else None,
            **self.machine_result(),
            **({"constraints": self.constraints_result()} if self.c_outside.size else {}),
        }
