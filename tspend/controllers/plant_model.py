"""What the model-based controller kinds know of the plant, taken from the plant's own equations.

A plant of the form (6) has ``x_n' = f(t, x, u) + d_d``.  The baselines that use a model
(``pd``'s nominal gain, ``lqr``, ``sliding_mode``'s nominal model, the
``feedback_linearization`` oracle, ``wang_indirect``'s initial gain) read ``f`` from
:mod:`tspend.plants.analytic` with ``d_d = 0``: the dynamics are written once, there,
and imported here.  Nothing in this module knows the disturbance.

Derived quantities, each computed numerically from ``f`` and documented as such:

* ``df/du`` by a central difference with step ``h_u = 1e-6 (1 + |u|)``: the truncation
  error is O(h^2 f''') ~ 1e-12 relative on the paper's plants, far below anything the
  closed loop resolves;
* the linearisation at the operating point ``(x*, u*)`` (the upright ``theta = 0`` for
  the cart-pole, the origin for the others; ``u* = 0`` everywhere, which makes ``x*`` an
  equilibrium of every unforced plant here):

      x_n' ~ a^T (x - x*) + b (u - u*),   a_i = df/dx_i,  b = df/du  at (t = 0, x*, u*),

  by central differences with ``h = 1e-6 (1 + |x_i*|)``.  Duffing's forcing
  ``12 cos t`` is additive, so it changes no derivative; it is outside the linear
  model and a linear design sees it as a disturbance.

The MuJoCo cart-pole is described by the cart-pole ODE of the compiled model
(:func:`cartpole_params_of`, the one place that lookup lives), which the project's
cross-check shows MuJoCo integrates to 1e-14 rad (README, "MuJoCo against the ODE").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from tspend.plants.analytic import (Accel, CartPoleParams, cartpole_accel_fn, duffing_accel,
    nonaffine_accel, third_order_accel)

if TYPE_CHECKING:
    from tspend.config import Scenario

#: relative step of the central differences (see the module docstring)
FD_STEP = 1e-6


@dataclass(frozen=True)
class PlantModel:
    """The true ``f(t, x, u)`` of a plant (``d_d = 0``), its operating point, and whether
    ``f`` is affine in ``u`` (then ``f = f(t, x, 0) + u (f(t, x, 1) - f(t, x, 0))``
    exactly, and the oracle needs no iteration)."""

    name: str
    order: int
    accel: Accel
    affine_in_u: bool
    x_op: tuple[float, ...]
    u_op: float = 0.0

    def f(self, t: float, x: np.ndarray, u: float) -> float:
        return self.accel(t, x, u, 0.0)

    def df_du(self, t: float, x: np.ndarray, u: float) -> float:
        h = FD_STEP * (1.0 + abs(u))
        return (self.accel(t, x, u + h, 0.0) - self.accel(t, x, u - h, 0.0)) / (2.0 * h)

    def linearisation(self) -> tuple[np.ndarray, float]:
        """``(a, b)``: ``df/dx`` (n,) and ``df/du`` at ``(t = 0, x*, u*)``."""
        x0 = np.asarray(self.x_op, dtype=float)
        a = np.empty(self.order)
        for i in range(self.order):
            h = FD_STEP * (1.0 + abs(x0[i]))
            xp, xm = x0.copy(), x0.copy()
            xp[i] += h
            xm[i] -= h
            a[i] = (self.accel(0.0, xp, self.u_op, 0.0) - self.accel(0.0, xm, self.u_op, 0.0)) / (2 * h)
        return a, self.df_du(0.0, x0, self.u_op)

    def state_space(self) -> tuple[np.ndarray, np.ndarray]:
        """``(A, B)`` of the linearised chain of integrators: ``A`` has ones above the
        diagonal and last row ``a``; ``B = b e_n``."""
        a, b = self.linearisation()
        n = self.order
        A = np.eye(n, k=1)
        A[-1, :] = a
        B = np.zeros((n, 1))
        B[-1, 0] = b
        return A, B


def cartpole_params_of(scenario: "Scenario") -> CartPoleParams:
    """The cart-pole a model-based controller assumes: the machine the plant is.

    For ``cartpole_ode`` that is the scenario's parameters; for ``cartpole_mujoco`` it is
    read back from the compiled model (masses, COM distance, pole inertia, damping,
    gear and the hinge axis' sign), so a baseline on a third-party MJCF assumes the
    machine MuJoCo actually simulates.  The plant's friction terms are left out: a
    nominal model knows the rigid body, not what a rig adds to it.
    """
    from dataclasses import replace

    from tspend.plants import registry

    params = registry.build(scenario).params  # type: ignore[attr-defined]
    return replace(params, cart_damping=0.0, hinge_damping=0.0, cart_friction=0.0,
                   hinge_friction=0.0)


def plant_model(scenario: "Scenario") -> PlantModel:
    """The model of the scenario's plant (every kind the scenario loader accepts)."""
    kind = scenario.plant.kind
    if kind == "nonaffine":
        return PlantModel(kind, 2, nonaffine_accel, affine_in_u=False, x_op=(0.0, 0.0))
    if kind == "duffing":
        return PlantModel(kind, 2, duffing_accel, affine_in_u=True, x_op=(0.0, 0.0))
    if kind == "third_order":
        return PlantModel(kind, 3, third_order_accel, affine_in_u=False, x_op=(0.0, 0.0, 0.0))
    if kind in ("cartpole_ode", "cartpole_mujoco"):
        return PlantModel(kind, 2, cartpole_accel_fn(cartpole_params_of(scenario)),
                          affine_in_u=True, x_op=(0.0, 0.0))
    raise ValueError(f"no model of plant kind {kind!r}")
