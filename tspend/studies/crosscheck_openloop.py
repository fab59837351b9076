"""Open-loop cross-check of cart-pole backends (docs/paper-notes.md section 7, the paper's Example 3).

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

    max_dtheta: float  #: max |theta_a - theta_b| over the run, rad
    max_dthetadot: float  #: max |theta'_a - theta'_b|, rad/s
    max_dcart_pos: float  #: max |cart_a - cart_b|, m (nan if a plant has no cart_pos)
    t: np.ndarray  #: sample times, s, including t = 0
    theta_a: np.ndarray  #: theta of the first plant at each sample
    theta_b: np.ndarray  #: theta of the second plant at each sample


def open_loop_compare(mujoco_plant: Plant, ode_plant: Plant, x0: np.ndarray,
                      force_fn: TimeFn, disturbance_fn: TimeFn, duration: float,
                      dt: float) -> OpenLoopComparison:
    """Run both plants from ``x0`` for ``duration`` under ``u = force_fn(t_k)``,
    ``d = disturbance_fn(t_k)`` held over each sample ``[t_k, t_k + dt)``.

    Any two Plant objects work (MuJoCo vs ODE, MuJoCo vs reference, ODE vs reference).
    """
    n = int(round(duration / dt))
    t = np.arange(n + 1) * dt
    th_a, th_b = np.empty(n + 1), np.empty(n + 1)
    dthd = dcart = 0.0
    mujoco_plant.reset(x0)
    ode_plant.reset(x0)

    def record(k: int) -> None:
        nonlocal dthd, dcart
        xa, xb = mujoco_plant.state(), ode_plant.state()
        th_a[k], th_b[k] = xa[0], xb[0]
        dthd = max(dthd, abs(float(xa[1] - xb[1])))
        ca = mujoco_plant.extras().get("cart_pos", math.nan)
        cb = ode_plant.extras().get("cart_pos", math.nan)
        diff = abs(ca - cb)
        # a plant without a cart poisons the cart column rather than faking agreement
        dcart = math.nan if math.isnan(diff) or math.isnan(dcart) else max(dcart, diff)

    record(0)
    for k in range(n):
        u, d = force_fn(float(t[k])), disturbance_fn(float(t[k]))
        mujoco_plant.step(u, d, dt)
        ode_plant.step(u, d, dt)
        record(k + 1)
    return OpenLoopComparison(max_dtheta=float(np.max(np.abs(th_a - th_b))),
                              max_dthetadot=dthd, max_dcart_pos=dcart,
                              t=t, theta_a=th_a, theta_b=th_b)
