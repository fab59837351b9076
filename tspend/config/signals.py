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


# -- references a rig needs: set-points through a reference model, recorded signals ----
def _reference_model_step(tau: np.ndarray, n: int, omega: float) -> np.ndarray:
    """Unit-step response of the reference model ``omega^n / (s + omega)^n`` and its
    derivatives up to order n, at times ``tau`` after the step (0 before it).

    ``r = 1 - e^{-w tau} sum_{k<n} (w tau)^k / k!``; ``r' = w^n tau^{n-1} e^{-w tau} / (n-1)!``
    and, by Leibniz, ``r^(j+1) = w^n / (n-1)! sum_i C(j, i) (n-1)!/(n-1-i)! tau^{n-1-i}
    (-w)^{j-i} e^{-w tau}``: r .. r^(n-1) are continuous, r^(n) is bounded.
    """
    tau = np.asarray(tau, dtype=float)
    after = tau >= 0.0
    s = np.where(after, tau, 0.0)
    decay = np.exp(-omega * s)
    out = np.zeros((s.size, n + 1))
    partial = sum((omega * s) ** k / math.factorial(k) for k in range(n))
    out[:, 0] = 1.0 - decay * partial
    for j in range(n):
        acc = np.zeros_like(s)
        for i in range(min(j, n - 1) + 1):
            acc += (math.comb(j, i) * math.factorial(n - 1) / math.factorial(n - 1 - i)
                    * s ** (n - 1 - i) * (-omega) ** (j - i))
        out[:, j + 1] = omega ** n / math.factorial(n - 1) * acc * decay
    return out * after[:, None]


@dataclass(frozen=True)
class StepSequence:
    """Set-points ``values[i]`` from ``times[i]`` on (``initial`` before), each step passed
    through the reference model ``omega^n / (s + omega)^n`` of the plant's order n, so
    r .. r^(n-1) are continuous and r^(n) exists (docs/testbed.md)."""

    times: tuple[float, ...]
    values: tuple[float, ...]
    initial: float = 0.0
    omega: float = 2.0

    @staticmethod
    def validate(values: dict, path: str) -> tuple[str, str] | None:
        times, levels = values.get("times", ()), values.get("values", ())
        if len(times) != len(levels) or not times:
            return "times", "times and values must be non-empty lists of the same length"
        if any(b <= a for a, b in zip(times, times[1:])) or times[0] < 0.0:
            return "times", "must be >= 0 and strictly increasing"
        if values.get("omega", 2.0) <= 0.0:
            return "omega", "must be > 0"
        return None

    def derivatives(self, t: np.ndarray, n: int) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        out = np.zeros((t.size, n + 1))
        out[:, 0] = self.initial
        level = self.initial
        for at, value in zip(self.times, self.values):
            out += (value - level) * _reference_model_step(t - at, n, self.omega)
            level = value
        return out


@dataclass(frozen=True)
class CsvReference:
    """A recorded reference: columns ``time`` and ``value`` of a CSV file, linearly
    interpolated (held after the last row), passed through the reference model
    ``omega^n / (s + omega)^n`` whose states are r .. r^(n-1) and whose input gives
    r^(n) (docs/testbed.md).  The filter is integrated exactly for the piecewise-linear
    input on a grid of ``step`` seconds, and read between grid points linearly."""

    path: str
    omega: float = 10.0
    step: float = 1e-3
    time_column: str = "time"
    value_column: str = "value"

    @staticmethod
    def validate(values: dict, path: str) -> tuple[str, str] | None:
        try:
            CsvReference(**values)._table()
        except (OSError, ValueError, KeyError) as exc:
            return "path", f"cannot use {values.get('path')!r}: {exc}"
        if values.get("omega", 10.0) <= 0.0 or values.get("step", 1e-3) <= 0.0:
            return "omega", "omega and step must be > 0"
        return None

    def _table(self) -> tuple[np.ndarray, np.ndarray]:
        import csv

        with open(self.path, newline="") as fh:
            rows = list(csv.DictReader(fh))
        if not rows:
            raise ValueError("no rows")
        t = np.array([float(r[self.time_column]) for r in rows])
        v = np.array([float(r[self.value_column]) for r in rows])
        if np.any(np.diff(t) <= 0.0) or not np.all(np.isfinite(v)):
            raise ValueError("time must increase strictly and values be finite")
        return t, v

    def __post_init__(self) -> None:
        # the filtered table per order n, computed once per reference (not per block)
        object.__setattr__(self, "_filtered", {})

    def derivatives(self, t: np.ndarray, n: int) -> np.ndarray:
        if n not in self._filtered:  # type: ignore[attr-defined]
            self._filtered[n] = _filtered_csv(self, n)  # type: ignore[attr-defined]
        grid, states = self._filtered[n]  # type: ignore[attr-defined]
        t = np.asarray(t, dtype=float)
        out = np.empty((t.size, n + 1))
        for k in range(n + 1):
            out[:, k] = np.interp(t, grid, states[:, k])
        return out


def _filtered_csv(ref: CsvReference, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The filter's states r .. r^(n-1) and r^(n) on the grid."""
    from scipy.linalg import expm

    t_in, v_in = ref._table()
    grid = np.arange(0.0, t_in[-1] + ref.step, ref.step)
    v = np.interp(grid, t_in, v_in)
    w, h = ref.omega, ref.step
    # companion form of (s + w)^n: z' = A z + b w^n v, z = [r, r', .., r^(n-1)]
    coeffs = [math.comb(n, k) * w ** (n - k) for k in range(n)]  # of s^k
    A = np.zeros((n, n))
    A[:-1, 1:] = np.eye(n - 1)
    A[-1, :] = -np.array(coeffs)
    b = np.zeros(n)
    b[-1] = w ** n
    # exact discretisation for an input linear over each step (first-order hold)
    big = np.zeros((n + 2, n + 2))
    big[:n, :n], big[:n, n], big[n, n + 1] = A * h, b * h, 1.0
    E = expm(big)
    Phi, G0, G1 = E[:n, :n], E[:n, n], E[:n, n + 1]
    z = np.zeros((grid.size, n))
    z[0, 0] = v[0]                      # start at rest on the first value
    for k in range(grid.size - 1):
        z[k + 1] = Phi @ z[k] + G0 * v[k] + G1 * (v[k + 1] - v[k])
    top = (z @ A[-1]) + w ** n * v
    states = np.column_stack([z, top])
    return grid, states
