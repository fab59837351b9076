"""The simulated twin of a rig run and the gap between them.

The twin is the rig run's scenario (at the rig's period) and controller on the model
machine, from the rig's first measured state, its controller fed through the same encoders
and velocity estimator the rig run used (:class:`~tspend.rig.estimator.SensedPlant`): the
one difference left is the machine itself.  ``tspend run --rig ... --twin`` streams it into
the rig run's own recording under ``twin/`` (every time-series view draws both) and writes
the gap into the metrics' ``twin_gap`` block; ``tspend replay RUN.rrd --twin OUT.rrd`` makes
it afterwards from a recording.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

#: the recording's prefix of the twin's run (beside the rig run's own entities)
TWIN_PREFIX = "twin/"


def simulate_twin(scenario, controller: str | None, start_view: np.ndarray, samples: int,
                  counts_per_unit, tau_s: float, sinks: Sequence = ()):
    """The twin's run, with its history: ``samples`` samples of ``scenario`` (already at the
    rig's period) from ``start_view`` (the task's view of the rig's first state)."""
    from tspend.loop.simulation import prepare, run
    from tspend.rig.estimator import SensedPlant, VelocityEstimator
    from tspend.rig.runner import model_not_stepped
    from tspend.scenario import override

    twin_scn = override(scenario, **{"plant.x0": [float(v) for v in start_view],
                                     "run.duration": samples * scenario.run.dt})
    with model_not_stepped():
        prepared = prepare(twin_scn, controller=controller)
    sensed = SensedPlant(prepared.plant, tuple(counts_per_unit), VelocityEstimator(tau_s))
    return run(prepared.scenario, sinks=sinks, keep_history=True,
               prepared=replace(prepared, plant=sensed))


def twin_gap(rig_state: np.ndarray, rig_u: np.ndarray, twin, state_units: Sequence[str],
             u_unit: str) -> dict:
    """The metrics' ``twin_gap`` block: per state entry and for the command, the rms and the
    largest |twin - rig| over the samples both have, in the entry's unit."""
    names = twin.info.state_names
    steps = min(len(twin.history.get("u", ())), len(rig_u))
    block = {"samples": steps, "twin_status": twin.status, "states": {}}
    if steps == 0:
        return block
    gap = twin.history["state"][:steps] - rig_state[:steps]
    for i, name in enumerate(names):
        block["states"][name] = _stats(gap[:, i], state_units[i])
    block["u"] = _stats(twin.history["u"][:steps] - rig_u[:steps], u_unit)
    return block


def _stats(gap: np.ndarray, unit: str) -> dict:
    return {"unit": unit, "rms": float(np.sqrt(np.mean(gap ** 2))),
            "max_abs": float(np.abs(gap).max())}


def twin_start(plant, scenario_x0, rig_first_state: np.ndarray, view: np.ndarray,
               counts_per_unit) -> tuple[np.ndarray, str]:
    """Where the twin starts, and which: the scenario's x0 when it reads as the rig's first
    frame's counts (the rig was set there, and its encoders cannot tell the two apart: x0
    is the better estimate inside the count), else the rig's first measured state (the
    task's view of it; velocities as the estimator had them, 0)."""
    from tspend.rig.estimator import VelocityEstimator, sensor_state

    sensors = sensor_state(plant, counts_per_unit, VelocityEstimator())
    plant.reset(np.asarray(scenario_x0, dtype=float))
    at_x0 = np.round(plant.full_state()[sensors.position_index] * sensors.counts_per_unit)
    measured = np.round(rig_first_state[sensors.position_index] * sensors.counts_per_unit)
    if np.array_equal(at_x0, measured):
        return np.asarray(scenario_x0, dtype=float), "x0"
    return rig_first_state[view], "measured"


def twin_of_run(prepared, rig_history: dict, counts_per_unit, tau_s: float,
                controller: str | None, sinks: Sequence = ()) -> tuple[dict, object]:
    """The twin of a rig run (``rig_history``: its samples, ``state`` and ``u``), streamed
    into ``sinks``: the ``twin_gap`` block and the twin's run (None when not run)."""
    rig_state, rig_u = rig_history.get("state"), rig_history.get("u")
    if rig_state is None or len(rig_u) == 0:
        return {"samples": 0, "twin_status": "not run: the rig run recorded no sample"}, None
    plant, scenario = prepared.plant, prepared.scenario
    start, which = twin_start(plant, scenario.plant.x0, rig_state[0], prepared.task.view_index,
                              counts_per_unit)
    twin = simulate_twin(scenario, controller, start, len(rig_u), counts_per_unit, tau_s, sinks)
    gap = twin_gap(rig_state, rig_u, twin, plant.state_units, plant.inputs[0].unit)
    return {**gap, "start": which}, twin
