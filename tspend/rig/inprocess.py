"""A rig in the runner's own process: the default scenario's MuJoCo cart-pole stepped when a
sensor frame is due.  It is the in-process loop of ``benchmarks/rig_timing.py`` (no link
at all: the floor a link adds to) and a worked example of the plug-in class a lab writes
for its own hardware::

    tspend run pendulum_mujoco --controller lqr --rig tspend.rig.inprocess:InProcessCartPole
"""

from __future__ import annotations

import time

import numpy as np

from tspend.rig.links import RigLink
from tspend.rig.protocol import NO_COMMAND, Command, Hello, Sensor

#: encoders of the simulated machine: 10 um on the slider, 20,000 counts per revolution
COUNTS_PER_UNIT = (1e5, 2e4 / (2 * np.pi))


class InProcessCartPole(RigLink):
    """pendulum_mujoco's machine, quantised like the double's encoders, no latency."""

    def __init__(self) -> None:
        self.plant = None
        self._u = 0.0

    def hello(self) -> Hello:
        from tspend.loop.simulation import build_plant
        from tspend.rig.runner import machine_id
        from tspend.scenario import load_scenario

        self.scenario = load_scenario("pendulum_mujoco")
        self.plant = build_plant(self.scenario)
        return Hello(machine_id(self.plant), COUNTS_PER_UNIT, 0.001, 0.02, 0.05, 2000.0)

    def query(self) -> Sensor:
        """The machine at rest before the start (optional: a link without it returns None
        and the runner checks its start at the first cycle)."""
        index = [self.plant.state_names.index(j.name) for j in self.plant.joints]
        return Sensor(0, round(time.perf_counter() * 1e6), NO_COMMAND, 0,
                      self._counts(self.plant.full_state()[index]))

    def _counts(self, positions) -> tuple[int, ...]:
        return tuple(int(round(v * c)) for v, c in zip(positions, COUNTS_PER_UNIT))

    def start(self, period_s: float) -> None:
        self.period_s, self._seq = period_s, 0
        self._steps = round(period_s / self.scenario.run.dt)
        self._t0 = time.perf_counter()
        self._index = np.array([self.plant.state_names.index(j.name) for j in self.plant.joints])

    def poll(self) -> list[Sensor]:
        if time.perf_counter() < self._t0 + self._seq * self.period_s:
            return []
        if self._seq:  # the period that just ended, under the last command
            for _ in range(self._steps):
                self.plant.step(self._u, 0.0, self.scenario.run.dt)
        state = self.plant.full_state()[self._index]
        frame = Sensor(self._seq, round(self._seq * self.period_s * 1e6), 0, 0,
                       self._counts(state))
        self._seq += 1
        return [frame]

    def send(self, command: Command) -> None:
        self._u = command.u

    def stop(self, reason: int) -> None:
        self._u = 0.0
