"""Open-loop cross-check of cart-pole backends (docs/paper-notes.md section 7, the paper's Example 3).

Before trusting closed-loop results on the MuJoCo cart-pole, drive it and the analytic
ODE with the same zero-order-hold force and disturbance and compare the trajectories.
Both are exact rigid-body models of the same machine, so they must agree at any angle,
fallen pole included; MuJoCo's RK4 at 1 ms should match a tight reference solution to
~1e-10 rad, which is what makes the cross-check strict.

:class:`ReferenceCartPole` is that reference: the ODE integrated by
``scipy.integrate.solve_ivp`` (DOP853, tight tolerances), restarted over each sample
with u and d held, written out independently of tspend's own RK4 plant.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.integrate import solve_ivp

from tspend.plants.analytic import CartPoleParams
from tspend.plants.base import Plant

TimeFn = Callable[[float], float]


def chirp_force(t: float, amplitude: float, f0: float, f1: float, duration: float) -> float:
    """Linear chirp ``A sin(2 pi (f0 t + (f1 - f0) t^2 / (2 T)))`` sweeping f0 -> f1 Hz over T s."""
    return amplitude * math.sin(2.0 * math.pi * (f0 * t + 0.5 * (f1 - f0) * t * t / duration))


class ReferenceCartPole:
    """The cart-pole ODE integrated by ``solve_ivp`` over each held sample: the oracle.

    State ``[theta, theta', cart_pos, cart_vel]``; implements the Plant protocol with
    ``order = 2`` and the cart in ``extras()``, like the analytic plant.
    """

    order: int = 2
    name: str = "cartpole_reference"

    def __init__(self, params: CartPoleParams = CartPoleParams(), rtol: float = 1e-12,
                 atol: float = 1e-13, method: str = "DOP853") -> None:
        self.params = params
        self.rtol, self.atol, self.method = rtol, atol, method
        self.t = 0.0
        self.s = np.zeros(4)

    def _rhs(self, t: float, s: np.ndarray, u: float, d: float) -> list[float]:
        # theta'' = (m l w^2 sin cos - (M+m) g sin - u cos + d) / (m l cos^2 - 4/3 l (M+m))
        # cart''  = (u + m l (cos theta'' - sin w^2)) / (M + m)
        p = self.params
        th, w, vc = s[0], s[1], s[3]
        sn, cs = math.sin(th), math.cos(th)
        ml, mm = p.m * p.l, p.M + p.m
        a = (ml * w * w * sn * cs - mm * p.g * sn - u * cs + d) / (ml * cs * cs - 4.0 / 3.0 * p.l * mm)
        return [w, a, vc, (u + ml * (cs * a - sn * w * w)) / mm]

    def reset(self, x0: np.ndarray) -> None:
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (2,):
            raise ValueError(f"{self.name}: initial state must have 2 entries, got {x0.shape}")
        self.s = np.array([x0[0], x0[1], 0.0, 0.0])
        self.t = 0.0

    def state(self) -> np.ndarray:
        return self.s[:2].copy()

    def step(self, u: float, d: float, dt: float) -> None:
        sol = solve_ivp(self._rhs, (self.t, self.t + dt), self.s, method=self.method,
                        rtol=self.rtol, atol=self.atol, args=(u, d))
        if not sol.success:
            raise RuntimeError(f"{self.name}: solve_ivp failed at t={self.t}: {sol.message}")
        self.s = sol.y[:, -1]
        self.t += dt

    def extras(self) -> dict[str, float]:
        return {"cart_pos": float(self.s[2]), "cart_vel": float(self.s[3])}


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
