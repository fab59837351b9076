"""Open-loop cross-check of two backends of one plant domain (docs/paper-notes.md section 7).

Before trusting closed-loop results on the MuJoCo cart-pole, drive it and the analytic
ODE with the same zero-order-hold force and disturbance and compare the trajectories.
Both are exact rigid-body models of the same machine, so they must agree at any angle,
fallen pole included; MuJoCo's RK4 at 1 ms should match a tight reference solution to
~1e-10 rad, which is what makes the cross-check strict.

The reference itself, the ODE integrated by ``scipy.integrate.solve_ivp``, is a test
oracle and lives in ``tests/cartpole_oracle.py``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from tspend.plants.base import Plant

TimeFn = Callable[[float], float]


def chirp_force(t: float, amplitude: float, f0: float, f1: float, duration: float) -> float:
    """Linear chirp ``A sin(2 pi (f0 t + (f1 - f0) t^2 / (2 T)))`` sweeping f0 -> f1 Hz over T s."""
    return amplitude * math.sin(2.0 * math.pi * (f0 * t + 0.5 * (f1 - f0) * t * t / duration))


@dataclass(frozen=True)
class OpenLoopComparison:
    """How far two backends drifted apart under the same open-loop inputs."""

    names: tuple[str, ...]  #: the full state's names (both plants name it alike)
    max_diff: np.ndarray  #: max |a - b| of each state over the run
    t: np.ndarray  #: sample times, s, including t = 0
    state_a: np.ndarray  #: (N + 1, S) full state of the first plant at each sample
    state_b: np.ndarray  #: (N + 1, S) full state of the second plant at each sample
    #: what ended the comparison early ("" = it ran its whole length): a constraint the
    #: first plant applies (a joint limit, a contact), which the second does not model
    stopped_by: str = ""

    @property
    def compared_until(self) -> float:
        """The last compared sample's time, s."""
        return float(self.t[-1])

    def max_of(self, name: str) -> float:
        """max |a - b| of state ``name``."""
        return float(self.max_diff[self.names.index(name)])

    def of_a(self, name: str) -> np.ndarray:
        """State ``name`` of the first plant at each sample."""
        return self.state_a[:, self.names.index(name)]

    def of_b(self, name: str) -> np.ndarray:
        """State ``name`` of the second plant at each sample."""
        return self.state_b[:, self.names.index(name)]


def open_loop_compare(plant_a: Plant, plant_b: Plant, x0: np.ndarray,
                      force_fn: TimeFn, disturbance_fn: TimeFn, duration: float,
                      dt: float) -> OpenLoopComparison:
    """Run both plants from ``x0`` for ``duration`` under ``u = force_fn(t_k)``,
    ``d = disturbance_fn(t_k)`` held over each sample ``[t_k, t_k + dt)``, comparing their
    full states (ValueError when the plants name their states differently).

    The comparison stops before the first sample at which ``plant_a`` applies a
    constraint (:meth:`Plant.constraint_active`: a joint at its limit, a contact), since
    the step into it already felt the constraint; ``stopped_by`` then says which, and
    when.  Any two Plant objects of one domain work (MuJoCo vs ODE, either vs a reference).
    """
    if tuple(plant_a.state_names) != tuple(plant_b.state_names):
        raise ValueError(f"the plants name their states differently: {plant_a.state_names} "
                         f"and {plant_b.state_names}")
    n = int(round(duration / dt))
    t = np.arange(n + 1) * dt
    plant_a.reset(x0)
    plant_b.reset(x0)
    size = len(plant_a.state_names)
    sa, sb = np.empty((n + 1, size)), np.empty((n + 1, size))
    sa[0], sb[0] = plant_a.full_state(), plant_b.full_state()
    stopped_by, last = "", n
    active = plant_a.constraint_active()
    if active:
        stopped_by, last = f"{active} at t = 0 s: nothing compared", 0
    for k in range(n if not active else 0):
        u, d = force_fn(float(t[k])), disturbance_fn(float(t[k]))
        plant_a.step(u, d, dt)
        plant_b.step(u, d, dt)
        sa[k + 1], sb[k + 1] = plant_a.full_state(), plant_b.full_state()
        active = plant_a.constraint_active()
        if active:
            stopped_by, last = f"{active} at t = {t[k + 1]:.6g} s", k
            break
    sa, sb, t = sa[:last + 1], sb[:last + 1], t[:last + 1]
    return OpenLoopComparison(names=tuple(plant_a.state_names),
                              max_diff=np.max(np.abs(sa - sb), axis=0), t=t, state_a=sa,
                              state_b=sb, stopped_by=stopped_by)
