"""A closed loop built by hand around a test's controller: the sampled-control (ZOH and
delay) tests of the generic and the compiled loops share it and its hand-worked cases."""

from __future__ import annotations

import numpy as np

from tspend import load_scenario, override
from tspend.loop.runner import ClosedLoop, LoopSettings
from tspend.loop.simulation import History, prepare
from tspend.loop.sinks import RunEnd, RunInfo

#: (every, delay, u over 10 steps) for a controller returning 1, 2, 3, ... per evaluation:
#: the k-th evaluation (k = 1, 2, ..) happens at step (k - 1) every and is applied from
#: step (k - 1) every + delay on; 0 before the first arrives
ZOH_CASES = [
    (1, 0, [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]),
    (3, 0, [1, 1, 1, 2, 2, 2, 3, 3, 3, 4]),
    (3, 2, [0, 0, 1, 1, 1, 2, 2, 2, 3, 3]),
    (1, 1, [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]),
    (2, 5, [0, 0, 0, 0, 0, 1, 1, 2, 2, 3]),   # three u in flight at once
]


def sampled_run(name: str, ctrl, every: int, delay: int) -> tuple[ClosedLoop, History, RunEnd]:
    """Ten steps of scenario ``name`` with ``ctrl`` evaluated every ``every`` steps, its
    output applied ``delay`` steps later."""
    s = override(load_scenario(name), **{"run.duration": 0.01})
    p = prepare(s)
    hist = History()
    loop = ClosedLoop(p.plant, ctrl, s.reference, s.disturbance,
                      LoopSettings(dt=s.run.dt, steps=10, block_size=4, control_every=every,
                                   control_delay=delay), task=p.task)
    p.plant.reset(np.asarray(s.plant.x0, dtype=float))
    end = loop.run(RunInfo("t", "", "", 1, "", "duffing", 2, s.run.dt, 0.01, 10), [hist])
    return loop, hist, end
