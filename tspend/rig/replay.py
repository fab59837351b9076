"""``tspend replay``: a rig run's recorded sensor frames through the velocity estimator and
the same controller, offline, every command compared bit for bit with the recorded one."""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass

import numpy as np

from tspend.runtime.errors import ScenarioError
from tspend.rig.closed_loop import RIG_ENTITY


@dataclass(frozen=True)
class ReplayResult:
    cycles: int
    equal: int
    first_difference: int | None = None
    recorded: float | None = None
    replayed: float | None = None


def session_notes(path) -> dict:
    """The rig run's session document (scenario, controller, estimator, hello)."""
    from rerun.chunk import RrdReader

    target = f"/{RIG_ENTITY}/session"
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*no footer.*")
        chunks = RrdReader(str(path)).stream().filter(content=target, is_static=True).to_chunks()
    for chunk in chunks:
        if chunk.entity_path != target:
            continue
        batch = chunk.to_record_batch()
        for i, name in enumerate(batch.schema.names):
            if name.endswith(":text"):
                return json.loads(batch.column(i).to_pylist()[0][0])
    raise ScenarioError(f"{path}: not a recording of a rig run (no {target})")


def _series(path, name: str) -> np.ndarray:
    from tspend.recorder.readback import read_scalar_series

    return read_scalar_series(path, f"{RIG_ENTITY}/{name}")[1]


def replay(path) -> ReplayResult:
    """Every recorded command of the rig run at ``path`` recomputed from its sensor frames."""
    from tspend.controllers.base import Observation
    from tspend.loop.simulation import prepare
    from tspend.rig.estimator import VelocityEstimator, sensor_state
    from tspend.rig.runner import model_not_stepped
    from tspend.scenario import parse_scenario

    try:
        notes = session_notes(path)
    except (OSError, ValueError) as exc:
        raise ScenarioError(f"{path}: cannot be read as a recording ({exc})") from None
    scenario = parse_scenario(notes["scenario_toml"], path=str(path))
    with model_not_stepped():
        prepared = prepare(scenario, controller=notes["controller"])
    plant, ctrl, task = prepared.plant, prepared.controller, prepared.task
    counts = _series(path, "counts").reshape(len(_series(path, "fresh")), -1)
    rig_time_us, fresh = _series(path, "rig_time_us"), _series(path, "fresh")
    ref, recorded_u = _series(path, "ref"), _series(path, "u")
    ref = ref.reshape(len(recorded_u), -1)
    sensors = sensor_state(plant, notes["counts_per_unit"],
                           VelocityEstimator(notes["timing_notes"]["velocity_tau_s"]))
    dt, view = scenario.run.dt, task.view_index
    checked = notes["timing_notes"].get("start_check", {})
    if checked.get("before_start") and len(recorded_u):
        # the start checked before START from the state read then (the filter's admission)
        start = np.array([checked["state"][n] for n in task.names])
        ctrl.before_start(Observation(0.0, start, start[view], ref[0], task.names,
                                      task.constraints))
    equal, first, first_replayed = 0, None, None
    for k in range(len(recorded_u)):
        if fresh[k]:
            sensors.fresh(counts[k].astype(np.int64), int(rig_time_us[k]))
        full = sensors.state.copy()
        replayed_u = float(ctrl.step(Observation(k * dt, full, full[view], ref[k], task.names,
                                                 task.constraints), dt))
        same = replayed_u == recorded_u[k] or (np.isnan(replayed_u) and np.isnan(recorded_u[k]))
        if same:
            equal += 1
        elif first is None:
            first, first_replayed = k, replayed_u
    return ReplayResult(len(recorded_u), equal, first,
                        None if first is None else float(recorded_u[first]),
                        first_replayed)


def twin(path, out) -> dict:
    """The simulated twin of the rig run at ``path`` (:func:`tspend.rig.twin.twin_of_run`:
    the same scenario, controller, encoders and velocity estimator), both trajectories
    written to the recording ``out`` (``sim_vs_rig/<state>/rig`` and ``.../twin``); the
    ``twin_gap`` block."""
    import rerun as rr

    from tspend.loop.simulation import prepare
    from tspend.recorder.arrow import time_column
    from tspend.recorder.stream import close_recording, open_recording
    from tspend.rig.runner import model_not_stepped
    from tspend.rig.twin import twin_of_run
    from tspend.scenario import parse_scenario

    notes = session_notes(path)
    scenario = parse_scenario(notes["scenario_toml"], path=str(path))
    rig_u = _series(path, "u")
    rig_state = _series(path, "state").reshape(len(rig_u), -1)
    with model_not_stepped():
        prepared = prepare(scenario, controller=notes["controller"])
    gap, result = twin_of_run(prepared, {"state": rig_state, "u": rig_u},
                              notes["counts_per_unit"], notes["timing_notes"]["velocity_tau_s"],
                              notes["controller"])
    if result is None:
        return gap
    steps = gap["samples"]
    rec = open_recording("tspend_sim_vs_rig", mode="save", path=out)
    times = time_column(result.history["t"][:steps])
    pairs = [(name, rig_state[:steps, i], result.history["state"][:steps, i])
             for i, name in enumerate(result.info.state_names)]
    for name, rig_values, twin_values in pairs + [("u", rig_u[:steps], result.history["u"][:steps])]:
        for who, values in (("rig", rig_values), ("twin", twin_values)):
            rec.send_columns(f"sim_vs_rig/{name}/{who}", indexes=[times],
                             columns=rr.Scalars.columns(scalars=values))
    problem = close_recording(rec, out)
    if problem:
        raise ScenarioError(f"{out}: {problem}")
    return gap
