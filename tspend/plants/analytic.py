"""Analytic plants of section 4 of the paper, integrated with RK4 under zero-order hold.

Every plant is a chain of integrators (6): ``x_i' = x_{i+1}`` for i < n and
``x_n' = accel(t, x, u, d)``.  ``u`` and the disturbance ``d`` are held over each
controller sample, as a digital controller would hold them; time-varying terms of the
plant itself (Duffing's forcing) are evaluated at each RK4 stage.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from . import cartpole
from .cartpole import CartPoleParams

Accel = Callable[[float, np.ndarray, float, float], float]


def nonaffine_accel(t: float, x: np.ndarray, u: float, d: float) -> float:
    """Example 1: ``x2' = 0.2 (1 + e^{x1 x2}) (2 + sin x2) (u + e^u - 1) + d_d``."""
    x1, x2 = x[0], x[1]
    return 0.2 * (1.0 + math.exp(x1 * x2)) * (2.0 + math.sin(x2)) * (u + math.exp(u) - 1.0) + d


def duffing_accel(t: float, x: np.ndarray, u: float, d: float) -> float:
    """Example 2: ``x2' = -0.1 x2 - x1^3 + 12 cos t + u + d_d``."""
    x1, x2 = x[0], x[1]
    return -0.1 * x2 - x1**3 + 12.0 * math.cos(t) + u + d


def third_order_accel(t: float, x: np.ndarray, u: float, d: float) -> float:
    """A nonaffine third-order plant (not in the paper) to exercise n = 3.

    ``x3' = -x1 - 2 x2 - 1.5 x3 + 0.5 sin(x1) x2 + (1.5 + cos x1) (u + 0.2 tanh u) + d_d``;
    ``df/du = (1.5 + cos x1)(1 + 0.2 sech^2 u) >= 0.5``, so Assumption 5 holds with a
    positive gain, as in the paper's examples.
    """
    x1, x2, x3 = x[0], x[1], x[2]
    return (-x1 - 2.0 * x2 - 1.5 * x3 + 0.5 * math.sin(x1) * x2
            + (1.5 + math.cos(x1)) * (u + 0.2 * math.tanh(u)) + d)


def cartpole_accel_fn(p: CartPoleParams) -> Accel:
    """theta'' of the cart-pole (C1)-(C2) (:mod:`tspend.plants.cartpole`) as ``f(t, x, u, d)``,
    with the cart at rest (its velocity enters only through cart damping)."""

    def accel(t: float, x: np.ndarray, u: float, d: float) -> float:
        return cartpole.accelerations(p, x[0], x[1], 0.0, u, d)[0]

    return accel


class AnalyticPlant:
    """A plant of the form (6), stepped by classical RK4 with u and d held constant.

    ``hidden`` extra states may ride along (the cart of the cart-pole ODE); the
    controller sees only the first ``order`` entries, ``extras`` reports the rest.
    """

    def __init__(self, accel: Accel, order: int, name: str = "analytic",
                 hidden_rhs: Callable[[float, np.ndarray, float, float, float], np.ndarray] | None = None,
                 hidden_names: tuple[str, ...] = ()) -> None:
        self.accel = accel
        self.order = int(order)
        self.name = name
        self.hidden_rhs = hidden_rhs
        self.hidden_names = hidden_names
        self.t = 0.0
        self.s = np.zeros(self.order + len(hidden_names))

    def reset(self, x0: np.ndarray) -> None:
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (self.order,):
            raise ValueError(f"{self.name}: initial state must have {self.order} entries, got {x0.shape}")
        self.s = np.zeros(self.order + len(self.hidden_names))
        self.s[: self.order] = x0
        self.t = 0.0

    def state(self) -> np.ndarray:
        return self.s[: self.order].copy()

    def rhs(self, t: float, s: np.ndarray, u: float, d: float) -> np.ndarray:
        """Full derivative: the chain of integrators, accel last, then hidden states."""
        n = self.order
        sdot = np.empty_like(s)
        sdot[: n - 1] = s[1:n]
        a = self.accel(t, s, u, d)
        sdot[n - 1] = a
        if self.hidden_rhs is not None:
            sdot[n:] = self.hidden_rhs(t, s, u, d, a)
        return sdot

    def step(self, u: float, d: float, dt: float) -> None:
        t, s = self.t, self.s
        h2 = 0.5 * dt
        k1 = self.rhs(t, s, u, d)
        k2 = self.rhs(t + h2, s + h2 * k1, u, d)
        k3 = self.rhs(t + h2, s + h2 * k2, u, d)
        k4 = self.rhs(t + dt, s + dt * k3, u, d)
        self.s = s + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        self.t = t + dt

    def extras(self) -> dict[str, float]:
        return {name: float(v) for name, v in zip(self.hidden_names, self.s[self.order:])}


class CartPoleODE(AnalyticPlant):
    """The cart-pole ODE (C1)-(C2) of :mod:`tspend.plants.cartpole`, with the cart as
    hidden states, so the ODE backend can draw the cart and meet a finite rail too."""

    def __init__(self, params: CartPoleParams = CartPoleParams()) -> None:
        super().__init__(lambda t, s, u, d: cartpole.accelerations(params, s[0], s[1], s[3], u, d)[0],
                         2, "cartpole_ode", hidden_names=("cart_pos", "cart_vel"))
        self.params = params

    @property
    def gain_sign(self) -> int:
        return int(cartpole.gain_sign(self.params))

    def set_params(self, params: CartPoleParams) -> None:
        """Change the machine while it runs (a payload picked up); the state is kept."""
        self.params = params

    def rhs(self, t: float, s: np.ndarray, u: float, d: float) -> np.ndarray:
        return cartpole.rhs(self.params, s, u, d)


def nonaffine_plant() -> AnalyticPlant:
    return AnalyticPlant(nonaffine_accel, 2, "nonaffine")


def duffing_plant() -> AnalyticPlant:
    return AnalyticPlant(duffing_accel, 2, "duffing")


def third_order_plant() -> AnalyticPlant:
    return AnalyticPlant(third_order_accel, 3, "third_order")


def cartpole_ode_plant(params: CartPoleParams = CartPoleParams()) -> CartPoleODE:
    return CartPoleODE(params)
