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
    """The simulated twin of the rig run at ``path``: the same scenario and controller at
    the rig's period, from the rig's first measured state, simulated; both trajectories
    written to the recording ``out`` (``sim_vs_rig/<state>/rig`` and ``.../twin``) and the
    gap returned as metrics (per state: rms and largest |twin - rig|; the commands' rms gap)."""
    import rerun as rr

    from tspend.loop.simulation import run
    from tspend.recorder.arrow import time_column
    from tspend.recorder.stream import close_recording, open_recording
    from tspend.rig.runner import model_not_stepped
    from tspend.scenario import override, parse_scenario

    notes = session_notes(path)
    scenario = parse_scenario(notes["scenario_toml"], path=str(path))
    rig_u = _series(path, "u")
    rig_state = _series(path, "state").reshape(len(rig_u), -1)
    with model_not_stepped():
        prepared_view = _view_of(scenario, notes["controller"])
        start = rig_state[0][prepared_view]
        twin_scn = override(scenario, **{"plant.x0": [float(v) for v in start],
                                         "run.duration": len(rig_u) * scenario.run.dt})
        result = run(twin_scn, controller=notes["controller"])
    names = result.info.state_names
    steps = min(len(result.history["u"]), len(rig_u))
    sim_state, t = result.history["state"][:steps], result.history["t"][:steps]
    gap = sim_state - rig_state[:steps]
    rec = open_recording("tspend_sim_vs_rig", mode="save", path=out)
    times = time_column(t)
    for i, name in enumerate(names):
        for who, values in (("rig", rig_state[:steps, i]), ("twin", sim_state[:, i])):
            rec.send_columns(f"sim_vs_rig/{name}/{who}", indexes=[times],
                             columns=rr.Scalars.columns(scalars=values))
    for who, values in (("rig", rig_u[:steps]), ("twin", result.history["u"][:steps])):
        rec.send_columns(f"sim_vs_rig/u/{who}", indexes=[times],
                         columns=rr.Scalars.columns(scalars=values))
    problem = close_recording(rec, out)
    if problem:
        raise ScenarioError(f"{out}: {problem}")
    return {"samples": steps, "twin_status": result.status,
            "rms_gap": {n: float(np.sqrt(np.mean(gap[:, i] ** 2))) for i, n in enumerate(names)},
            "max_abs_gap": {n: float(np.abs(gap[:, i]).max()) for i, n in enumerate(names)},
            "u_rms_gap": float(np.sqrt(np.mean((result.history["u"][:steps] - rig_u[:steps]) ** 2)))}


def _view_of(scenario, controller) -> np.ndarray:
    """Where the task's view sits in the full state (the twin starts from the view)."""
    from tspend.loop.simulation import prepare

    return prepare(scenario, controller=controller).task.view_index
