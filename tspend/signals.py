"""References with analytic derivatives, and disturbances.

A reference gives ``r, r', .., r^(n)`` (the controller needs ``r^(n)`` in (19)); a
disturbance gives ``d_d(t)``.  Both are evaluated on a whole block of sample times at
once (vectorised), so nothing here runs per step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np


class Reference(Protocol):
    def derivatives(self, t: np.ndarray, n: int) -> np.ndarray:
        """``r^(k)(t)`` for k = 0..n at the times ``t``: shape (len(t), n + 1)."""


class Disturbance(Protocol):
    def __call__(self, t: np.ndarray) -> np.ndarray:
        """``d_d(t)`` at the times ``t``: shape (len(t),)."""


def _sine_derivatives(t: np.ndarray, n: int, amplitude: float, omega: float,
                      phase: float) -> np.ndarray:
    """k-th derivative of ``A sin(w t + phi)`` is ``A w^k sin(w t + phi + k pi/2)``."""
    k = np.arange(n + 1)
    return amplitude * omega**k * np.sin(omega * np.asarray(t)[:, None] + phase + k * (math.pi / 2))


@dataclass(frozen=True)
class Constant:
    value: float = 0.0

    def derivatives(self, t: np.ndarray, n: int) -> np.ndarray:
        out = np.zeros((np.size(t), n + 1))
        out[:, 0] = self.value
        return out


@dataclass(frozen=True)
class Sine:
    """``r = offset + amplitude sin(omega t + phase)`` (Example 2: sin t; Example 3: pi/30 sin t)."""

    amplitude: float = 1.0
    omega: float = 1.0
    phase: float = 0.0
    offset: float = 0.0

    def derivatives(self, t: np.ndarray, n: int) -> np.ndarray:
        out = _sine_derivatives(t, n, self.amplitude, self.omega, self.phase)
        out[:, 0] += self.offset
        return out


@dataclass(frozen=True)
class SumOfSines:
    """``r = offset + sum_j a_j sin(w_j t + phi_j)``; Example 1 case 2 is
    ``sin(0.5 t) + cos t`` = terms (1, 0.5, 0) and (1, 1, pi/2)."""

    amplitudes: tuple[float, ...]
    omegas: tuple[float, ...]
    phases: tuple[float, ...]
    offset: float = 0.0

    def derivatives(self, t: np.ndarray, n: int) -> np.ndarray:
        out = sum(_sine_derivatives(t, n, a, w, p)
                  for a, w, p in zip(self.amplitudes, self.omegas, self.phases))
        out = np.array(out, dtype=float).reshape(np.size(t), n + 1)
        out[:, 0] += self.offset
        return out


@dataclass(frozen=True)
class ExpApproach:
    """``r = final - gap e^{-rate t}``; Example 1 case 1 is ``1.5 - e^{-0.5 t}``."""

    final: float = 1.5
    gap: float = 1.0
    rate: float = 0.5

    def derivatives(self, t: np.ndarray, n: int) -> np.ndarray:
        k = np.arange(n + 1)
        decay = np.exp(-self.rate * np.asarray(t))[:, None]
        out = -self.gap * (-self.rate) ** k * decay
        out[:, 0] += self.final
        return out


@dataclass(frozen=True)
class NoDisturbance:
    def __call__(self, t: np.ndarray) -> np.ndarray:
        return np.zeros(np.size(t))


@dataclass(frozen=True)
class SquareWave:
    """The paper's disturbance: ``+amplitude`` for the first half of each period, then
    ``-amplitude`` (period 2 pi in all three examples)."""

    amplitude: float = 0.1
    period: float = 2.0 * math.pi
    delay: float = 0.0

    def __call__(self, t: np.ndarray) -> np.ndarray:
        phase = np.mod(np.asarray(t, dtype=float) - self.delay, self.period)
        return np.where(phase < 0.5 * self.period, self.amplitude, -self.amplitude)


@dataclass(frozen=True)
class SineDisturbance:
    amplitude: float = 0.1
    omega: float = 1.0
    phase: float = 0.0

    def __call__(self, t: np.ndarray) -> np.ndarray:
        return self.amplitude * np.sin(self.omega * np.asarray(t, dtype=float) + self.phase)
