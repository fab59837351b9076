"""The velocity estimator of a rig that sends positions only, and the sensor frame turned
into the plant's full state: one text, used by the runner, by ``tspend replay`` and by
the simulated twin, so all three see the same numbers."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: the low-pass filter's time constant (s): the encoder's count steps over a 2 ms period
#: are 0.16 rad/s at 20,000 counts per revolution, smoothed over about 2.5 periods
DEFAULT_TAU_S = 0.005


@dataclass(frozen=True)
class VelocityEstimator:
    """Backward difference of the positions over the rig's own timestamps, through a
    first-order low-pass of time constant ``tau_s``:

        v_k = v_{k-1} + a (  (p_k - p_{k-1}) / dt_k  -  v_{k-1} ),   a = dt_k / (tau_s + dt_k)

    with ``dt_k`` from the rig's timestamps (not the host's clock), ``v_0 = 0`` (a run
    starts at rest), and the previous estimate held on a period without a fresh frame."""

    tau_s: float = DEFAULT_TAU_S

    def describe(self) -> str:
        return (f"backward difference of the positions over the rig's timestamps, "
                f"first-order low-pass with tau = {self.tau_s * 1e3:g} ms")

    def update(self, previous_position: np.ndarray, previous_velocity: np.ndarray,
               position: np.ndarray, dt_s: float) -> np.ndarray:
        if dt_s <= 0.0:
            return previous_velocity
        raw = (position - previous_position) / dt_s
        a = dt_s / (self.tau_s + dt_s)
        return previous_velocity + a * (raw - previous_velocity)


class SensorState:
    """Sensor frames in, the plant's full state out (positions then velocities in the
    order of ``position_index`` / ``velocity_index``)."""

    def __init__(self, counts_per_unit: np.ndarray, position_index: np.ndarray,
                 velocity_index: np.ndarray, size: int, estimator: VelocityEstimator) -> None:
        self.counts_per_unit = counts_per_unit
        self.position_index, self.velocity_index = position_index, velocity_index
        self.estimator = estimator
        self.state = np.zeros(size)
        self._position: np.ndarray | None = None
        self._velocity = np.zeros(len(counts_per_unit))
        self._rig_time_us = 0

    def fresh(self, counts: np.ndarray, rig_time_us: int) -> np.ndarray:
        """The full state after a new frame."""
        position = counts / self.counts_per_unit
        if self._position is not None:
            self._velocity = self.estimator.update(self._position, self._velocity, position,
                                                   (rig_time_us - self._rig_time_us) * 1e-6)
        self._position, self._rig_time_us = position, rig_time_us
        self.state[self.position_index] = position
        self.state[self.velocity_index] = self._velocity
        return self.state
