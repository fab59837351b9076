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
from typing import Any

from tspend.loop.sinks import Block, InnerSnapshot, RunEnd, RunInfo

__all__ = ["METRIC_KEYS", "MACHINE_PREFIXES", "FoldSettings", "MachineInfo", "MetricsAccumulator",
           "flatten", "fold_samples", "is_machine_column", "start_figures"]

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


@dataclass(frozen=True)
class FoldSettings:
    """What :func:`fold_samples` needs to know of a run besides its samples: the steady
    window's start (s; half a step early, so round-off in t does not drop its first
    sample), the actuator's range, the goal's angle (0: none), each joint's index in the
    full state, the task's constraints (None: none) and what runs on the metrics' numbers:
    numbers may be arrays (one per env) under ``jax.vmap``."""

    ss_from: Any = 0.0
    u_lo: Any = -math.inf
    u_hi: Any = math.inf
    goal_angle: float = 0.0
    joint_index: tuple[int, ...] = ()
    constraints: Any = None

    @classmethod
    def of(cls, dt: float, ss_start: float, machine: "MachineInfo | None") -> "FoldSettings":
        m = machine
        if m is None:
            return cls(ss_from=ss_start - 0.5 * dt)
        cons = m.constraints if m.constraints is not None and len(m.constraints) else None
        return cls(ss_from=ss_start - 0.5 * dt, u_lo=m.u_lo, u_hi=m.u_hi,
                   goal_angle=m.goal_angle, joint_index=tuple(j for _, j in m.joints),
                   constraints=cons)


def start_figures(xp: Any, settings: FoldSettings, dtype: Any = float) -> dict:
    """The running figures of a run before its first sample (:func:`fold_samples`)."""
    zero = xp.zeros((), dtype=dtype)
    C = len(settings.constraints) if settings.constraints is not None else 0
    J = len(settings.joint_index)
    return {"steps": xp.zeros((), dtype=np.int64 if xp is np else int),
            **{k: zero for k in ("sum_e2", "sum_abs_e", "sum_t_abs_e", "sum_u2",
                                 "sum_u2_applied", "max_abs_e", "max_abs_u",
                                 "max_abs_u_applied", "ss_sum_e2", "ss_max_abs_e", "tv_u",
                                 "u_last")},
            "ss_steps": xp.zeros((), dtype=np.int64 if xp is np else int),
            "saturated": xp.zeros((), dtype=np.int64 if xp is np else int),
            "saturated_at_end": xp.zeros((), dtype=np.int64 if xp is np else int),
            # the last sample's time outside the goal; -inf: never
            "last_outside": xp.full((), -xp.inf, dtype=dtype),
            "joint_max": xp.zeros(J, dtype=dtype), "joint_final": xp.full(J, xp.nan, dtype=dtype),
            "c_outside": xp.zeros(C, dtype=np.int64 if xp is np else int),
            "any_outside": xp.zeros((), dtype=np.int64 if xp is np else int),
            "c_depth": xp.zeros(C, dtype=dtype), "c_margin": xp.full(C, xp.inf, dtype=dtype)}


def fold_samples(xp: Any, fig: dict, t: Any, e1: Any, u: Any, state: Any, keep: Any,
                 s: FoldSettings) -> dict:
    """The running figures ``fig`` after k more samples (times ``t``, output error ``e1``,
    command ``u``, full ``state`` (k, N)) of which the first ``keep.sum()`` belong to the
    run (``keep``: a prefix; the rest is ignored).  One text for the CPU's
    :class:`MetricsAccumulator` (numpy) and the accelerator's closed loops (jax.numpy,
    :mod:`tspend.mjx.sweep`); the module docstring defines each figure."""
    where = xp.where
    n = xp.sum(keep)
    abs_e = where(keep, xp.abs(e1), 0.0)
    e_k, u_k = where(keep, e1, 0.0), where(keep, u, 0.0)
    applied = where(keep, xp.clip(u, s.u_lo, s.u_hi), 0.0)
    steady = keep & (t >= s.ss_from)
    e_ss = where(steady, e1, 0.0)
    last = xp.maximum(n - 1, 0)
    before = fig["steps"] > 0
    pairs = keep[1:] & keep[:-1]
    tv = xp.sum(where(pairs, xp.abs(u[1:] - u[:-1]), 0.0)) + where(
        before & keep[0], xp.abs(u[0] - fig["u_last"]), 0.0)
    clipped = keep & ((u < s.u_lo) | (u > s.u_hi))
    inside = xp.max(where(keep & ~clipped, xp.arange(keep.shape[0]), -1))
    out = {"steps": fig["steps"] + n,
           "sum_e2": fig["sum_e2"] + xp.sum(e_k * e_k),
           "sum_abs_e": fig["sum_abs_e"] + xp.sum(abs_e),
           "sum_t_abs_e": fig["sum_t_abs_e"] + xp.sum(t * abs_e),
           "sum_u2": fig["sum_u2"] + xp.sum(u_k * u_k),
           "sum_u2_applied": fig["sum_u2_applied"] + xp.sum(applied * applied),
           "max_abs_e": xp.fmax(fig["max_abs_e"], xp.max(abs_e)),
           "max_abs_u": xp.fmax(fig["max_abs_u"], xp.max(xp.abs(u_k))),
           "max_abs_u_applied": xp.fmax(fig["max_abs_u_applied"], xp.max(xp.abs(applied))),
           "ss_steps": fig["ss_steps"] + xp.sum(steady),
           "ss_sum_e2": fig["ss_sum_e2"] + xp.sum(e_ss * e_ss),
           "ss_max_abs_e": xp.fmax(fig["ss_max_abs_e"], xp.max(xp.abs(e_ss))),
           "tv_u": fig["tv_u"] + tv,
           "u_last": where(n > 0, u[last], fig["u_last"]),
           "saturated": fig["saturated"] + xp.sum(clipped),
           "saturated_at_end": where(inside >= 0, n - 1 - inside, fig["saturated_at_end"] + n),
           "last_outside": fig["last_outside"]}
    if s.goal_angle > 0.0:
        outside = keep & ~(xp.abs(e1) <= s.goal_angle)
        out["last_outside"] = xp.maximum(fig["last_outside"], xp.max(where(outside, t, -xp.inf)))
    if s.joint_index:
        col = state[:, np.asarray(s.joint_index)]
        out["joint_max"] = xp.fmax(fig["joint_max"],
                                   xp.max(where(keep[:, None], xp.abs(col), 0.0), axis=0))
        out["joint_final"] = where(n > 0, col[last], fig["joint_final"])
    else:
        out["joint_max"], out["joint_final"] = fig["joint_max"], fig["joint_final"]
    out.update(_fold_constraints(xp, fig, state, u, keep, s.constraints))
    return out


def _fold_constraints(xp: Any, fig: dict, state: Any, u: Any, keep: Any, cons: Any) -> dict:
    """The constraints' figures after the samples (module docstring: a NaN margin is
    neither inside nor outside; a margin within the tolerance below 0 is round-off)."""
    if cons is None:
        return {k: fig[k] for k in ("c_outside", "any_outside", "c_depth", "c_margin")}
    margin = xp.where(keep[:, None], cons.margins(state, u, xp), xp.inf)      # (k, C)
    outside = margin < -xp.asarray(cons.tolerances)
    depth = xp.where(outside, -margin, 0.0)
    return {"c_outside": fig["c_outside"] + xp.sum(outside, axis=0),
            "any_outside": fig["any_outside"] + xp.sum(xp.any(outside, axis=1)),
            "c_depth": xp.fmax(fig["c_depth"], xp.max(xp.where(xp.isnan(depth), -xp.inf, depth),
                                                      axis=0, initial=-xp.inf)),
            "c_margin": xp.fmin(fig["c_margin"], xp.min(xp.where(xp.isnan(margin), xp.inf,
                                                                  margin), axis=0,
                                                         initial=xp.inf))}


class MetricsAccumulator:
    """A sink that folds each block into running sums; :meth:`result` gives the metrics."""

    def __init__(self, dt: float, ss_start: float, seed: int = 0,
                 machine: MachineInfo | None = None) -> None:
        self.machine = machine
        self.time_hist = np.zeros(_TIME_BINS.size + 1, dtype=np.int64)
        self.time_max = 0.0
        self.timed = 0
        self.counters: dict[str, float] = {}
        self.counter_names: tuple[str, ...] = ()
        self.dt = dt
        self.ss_start = ss_start
        self.seed = seed
        #: what folds the samples (:func:`fold_samples`) and its running figures
        self.fold = FoldSettings.of(dt, ss_start, machine)
        self.figures = start_figures(np, self.fold)

    def __getattr__(self, name: str) -> Any:
        # the running figures read as attributes (acc.steps, acc.sum_e2, ...)
        figures = self.__dict__.get("figures")
        if figures is not None and name in figures:
            v = np.asarray(figures[name])
            return v.item() if v.ndim == 0 else v
        raise AttributeError(name)

    @property
    def joint_max(self) -> dict[str, float]:
        names = [name for name, _ in self.machine.joints] if self.machine else []
        return {name: float(v) for name, v in zip(names, self.figures["joint_max"])}

    @property
    def joint_final(self) -> dict[str, float]:
        if not self.figures["steps"] or self.machine is None:
            return {}
        return {name: float(v) for (name, _), v in zip(self.machine.joints,
                                                        self.figures["joint_final"])}

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
        state = block.data.get("state")
        if state is None or not state.shape[1]:
            state = np.zeros((t.size, 0))
        keep = np.ones(t.size, dtype=bool)
        self.figures = fold_samples(np, self.figures, t, block.data["e"][:, 0], block.data["u"],
                                    state, keep, self.fold)
        data = block.data
        for name in self.counter_names:
            if name in data and len(data[name]):
                last = np.asarray(data[name]).reshape(len(data[name]), -1)[-1, 0]
                self.counters[name] = float(last)

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
        elif self.last_outside == -math.inf:   # never outside
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
