"""The velocity estimator of a rig that sends positions only, and the sensor frame turned
into the plant's full state: one text, used by the runner, by ``tspend replay``, by the
simulated twin and by a simulation asked to sense as a rig does (:class:`SensedPlant`), so
all of them see the same numbers."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tspend.plants.base import Plant, velocity_name

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


def default_counts_per_unit(joints) -> tuple[float, ...]:
    """The simulated rig's encoders (``tspend rig serve``'s default): 10 um on a slide
    (100,000 counts per metre), 20,000 counts per revolution on a hinge."""
    return tuple(1e5 if j.kind == "slide" else 2e4 / (2 * math.pi) for j in joints)


def sensor_state(machine: Plant, counts_per_unit, estimator: VelocityEstimator) -> SensorState:
    """The sensors of ``machine``'s joints: one encoder each (``counts_per_unit`` in the
    joints' order), velocities from ``estimator``."""
    names = machine.state_names
    return SensorState(np.asarray(counts_per_unit, dtype=float),
                       np.array([names.index(j.name) for j in machine.joints]),
                       np.array([names.index(velocity_name(j.name)) for j in machine.joints]),
                       len(names), estimator)


class ModelFacade(Plant):
    """A plant whose names, units, joints, inputs and task defaults are its model
    machine's (``self.machine``): what a rig or a sensed simulation does not restate."""

    machine: Plant

    @property
    def state_names(self):
        return self.machine.state_names

    @property
    def state_units(self):
        return self.machine.state_units

    @property
    def joints(self):
        return self.machine.joints

    @property
    def inputs(self):
        return self.machine.inputs

    def parameters(self) -> dict[str, float]:
        return self.machine.parameters()

    def default_task(self):
        return self.machine.default_task()

    @property
    def gain_sign(self) -> int:
        return self.machine.gain_sign

    def extras(self) -> dict[str, float]:
        return {}

    def underlying(self) -> Plant:
        return self.machine.underlying()


class SensedPlant(ModelFacade):
    """A simulated machine seen as a rig sees it (``tspend run --estimator``): each
    sample's positions rounded to whole encoder counts, velocities from the same
    :class:`VelocityEstimator` the real-time runner uses, over timestamps in whole
    microseconds as a rig stamps them.  So a simulated run and a rig run feed their
    controller on equal terms; the recorded state is the sensed one, as on a rig."""

    def __init__(self, machine: Plant, counts_per_unit, estimator: VelocityEstimator) -> None:
        self.machine, self.counts_per_unit, self.estimator = machine, counts_per_unit, estimator
        self.order, self.domain, self.name = machine.order, machine.domain, machine.name
        self.sensors = sensor_state(machine, counts_per_unit, estimator)
        self._time_us, self._read_at_us = 0, -1

    def reset(self, x0: np.ndarray) -> None:
        self.machine.reset(x0)
        self.sensors = sensor_state(self.machine, self.counts_per_unit, self.estimator)
        self._time_us, self._read_at_us = 0, -1

    def full_state(self) -> np.ndarray:
        if self._read_at_us != self._time_us:
            sensors = self.sensors
            true = self.machine.full_state()[sensors.position_index]
            # the simulated rig's rounding (tspend.rig.double), half to even
            sensors.fresh(np.round(true * sensors.counts_per_unit).astype(np.int64),
                          self._time_us)
            self._read_at_us = self._time_us
        return self.sensors.state.copy()

    def step(self, u: float, d: float, dt: float) -> None:
        self.machine.step(u, d, dt)
        self._time_us += round(dt * 1e6)
