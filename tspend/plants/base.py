"""The plant protocol: what the closed-loop runner needs from any plant.

A plant is the system (6) of the paper: ``x_1' = x_2, ..., x_n' = f(x, u) + d_d``.
Analytic plants integrate their ODE; the MuJoCo plant steps a physics model.  The
runner only sees this protocol, so backends are interchangeable.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Plant(Protocol):
    """A plant of order ``n`` driven by a scalar control ``u`` and disturbance ``d_d``."""

    #: plant order n: the controller sees x = [x_1 .. x_n]
    order: int

    def reset(self, x0: np.ndarray) -> None:
        """Set the state to ``x0`` (shape (n,)) and the plant's clock to zero."""

    def state(self) -> np.ndarray:
        """The current state x (shape (n,)); a copy the caller may keep."""

    def step(self, u: float, d: float, dt: float) -> None:
        """Advance by ``dt`` with ``u`` and ``d`` held constant (zero-order hold)."""

    def extras(self) -> dict[str, float]:
        """Quantities outside x worth recording (cart position, ...); may be empty."""
