"""The test oracle of the cart-pole: the paper's ODE integrated by ``solve_ivp``.

Written out independently of tspend's own equations (tspend/plants/cartpole.py) and RK4:
DOP853 at tight tolerances, restarted over each held sample.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

from tspend.plants.analytic import AnalyticPlant
from tspend.plants.base import InputInfo, JointInfo, TaskDefaults
from tspend.plants.mjcf import CartPoleParams
from tspend.studies.cartpole_greybox import accelerations, gain_sign, machine_of


class ReferenceCartPole:
    """The cart-pole ODE integrated by ``solve_ivp`` over each held sample: the oracle.

    State ``[theta, theta', cart_pos, cart_vel]``; implements the Plant protocol with
    ``order = 2`` and the cart in ``extras()``, like the analytic plant.
    """

    order: int = 2
    name: str = "cartpole_reference"
    state_names = ("slider", "hinge", "slider_dot", "hinge_dot")

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

    def full_state(self) -> np.ndarray:
        return self.s[[2, 0, 3, 1]].copy()

    def step(self, u: float, d: float, dt: float) -> None:
        sol = solve_ivp(self._rhs, (self.t, self.t + dt), self.s, method=self.method,
                        rtol=self.rtol, atol=self.atol, args=(u, d))
        if not sol.success:
            raise RuntimeError(f"{self.name}: solve_ivp failed at t={self.t}: {sol.message}")
        self.s = sol.y[:, -1]
        self.t += dt

    def extras(self) -> dict[str, float]:
        return {"cart_pos": float(self.s[2]), "cart_vel": float(self.s[3])}




class HandWrittenCartPole(AnalyticPlant):
    """The hand-written (C1)-(C2) (:mod:`tspend.studies.cartpole_greybox`) as a plant: the
    oracle the derived and the MuJoCo cart-poles are compared with (no run uses it).

    Integrated by tspend's RK4 as ``s = [theta, theta', x_c, x_c']``; its full state is the
    MJCF's order, ``(slider, hinge, slider_dot, hinge_dot)``."""

    def __init__(self, params: CartPoleParams = CartPoleParams()) -> None:
        super().__init__(lambda t, s, u, d: accelerations(self._machine, s[0], s[1], s[3], u, d, s[2])[0],
                         2, "cartpole_ode", hidden_names=("cart_pos", "cart_vel"),
                         domain="cartpole", state_names=("slider", "hinge", "slider_dot", "hinge_dot"),
                         state_units=("m", "rad", "m/s", "rad/s"), full_order=(2, 0, 3, 1))
        self.set_params(params)

    @property
    def joints(self) -> tuple[JointInfo, ...]:
        return (JointInfo("slider", "slide", "m", None), JointInfo("hinge", "hinge", "rad", None))

    @property
    def inputs(self) -> tuple[InputInfo, ...]:
        return (InputInfo("force", "N", float(self.params.ctrl_min), float(self.params.ctrl_max)),)

    def default_task(self) -> TaskDefaults:
        return TaskDefaults(view=("hinge", "hinge_dot"), fall_angle=math.pi / 2, pole="hinge")

    @property
    def gain_sign(self) -> int:
        return int(gain_sign(self.params))

    def set_params(self, params: CartPoleParams) -> None:
        self.params = params
        self._machine = machine_of(params)

    def parameters(self) -> dict[str, float]:
        return self.params.finite()

    def _rhs_params(self):
        return self._machine


def cartpole_ode_plant(params: CartPoleParams = CartPoleParams()) -> HandWrittenCartPole:
    return HandWrittenCartPole(params)
