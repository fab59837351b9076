"""A scenario's closed loop run on a rig: :func:`run_on_rig`, the rig's counterpart of
:func:`tspend.loop.simulation.run` (same sinks, same metrics, same recording layout),
plus :class:`TimingSink`, which adds the timing panels and the ``timing`` block."""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Sequence

import numpy as np

from tspend.loop.sinks import Block, RunEnd, RunInfo, Sink
from tspend.rig import protocol
from tspend.rig.runner import RigPlant, RigSession

#: samples per block handed to the sinks: small, so the recording's work is spread over
#: the run instead of landing on one cycle every few seconds
BLOCK_SIZE = 100
#: the recording's entity of the rig's panels and of the exact per-cycle data replay reads
RIG_ENTITY = "rig"


#: samples held back from the sinks during a rig run; past it the held blocks are
#: delivered in the loop (that cycle is late, and counted so)
DEFER_SAMPLES = 60_000


class DeferredSinks:
    """The sinks out of the real-time loop: each block is copied and held, and handed on
    when the run ends (or when :data:`DEFER_SAMPLES` are held).  A recording's block costs
    5 ms and more (measured: docs/rig.md), longer than a period."""

    def __init__(self, sinks: Sequence[Sink], on_loop_end=None) -> None:
        self.sinks = list(sinks)
        #: called with the run's ending once the loop is over, before any held block is
        #: delivered (the rig's stop frame goes out then, not after the recording's work)
        self.on_loop_end = on_loop_end
        self._held: list[Block] = []
        self._samples = 0

    def start(self, info: RunInfo) -> None:
        for sink in self.sinks:
            sink.start(info)

    def block(self, block: Block) -> None:
        self._held.append(Block(start=block.start,
                                data={k: np.array(v, copy=True) for k, v in block.data.items()}))
        self._samples += len(block.data["t"])
        if self._samples >= DEFER_SAMPLES:
            self.deliver()

    def deliver(self) -> None:
        held, self._held, self._samples = self._held, [], 0
        for block in held:
            for sink in self.sinks:
                sink.block(block)

    def inner(self, snap) -> None:
        pass

    def ending(self, status: str) -> None:
        """The loop is over (the loop calls it just before :meth:`result`)."""
        if self.on_loop_end is not None:
            self.on_loop_end(status)

    def result(self, wall_s: float) -> dict:
        """The metrics of every block: the held ones delivered first."""
        self.deliver()
        metrics = {}
        for sink in self.sinks:
            if hasattr(sink, "result"):
                metrics = sink.result(wall_s=wall_s)
        return metrics

    def finish(self, end: RunEnd) -> None:
        self.deliver()
        for sink in self.sinks:
            sink.finish(end)


class TimingSink:
    """Per-cycle timing and frames into the recording (``rig/...``), and the metrics'
    ``timing`` block at the end (before the sinks after it see the metrics)."""

    def __init__(self, plant: RigPlant, session: RigSession, rec=None, notes: dict | None = None) -> None:
        self.plant, self.session, self.rec = plant, session, rec
        self.notes = notes or {}

    def start(self, info: RunInfo) -> None:
        pass

    def block(self, block: Block) -> None:
        if self.rec is None:
            return
        import rerun as rr

        from tspend.recorder.arrow import time_column

        start, k = block.start, len(block.data["t"])
        times = time_column(block.data["t"])
        columns = self.plant.log.series(start, start + k)
        exact = {"counts": self.plant.log.counts[start:start + k].astype(float),
                 "rig_time_us": self.plant.log.rig_time_us[start:start + k].astype(float),
                 "sensor_seq": self.plant.log.sensor_seq[start:start + k].astype(float),
                 "ref": block.data["ref"], "state": block.data["state"], "u": block.data["u"]}
        for name, values in {**columns, **exact}.items():
            self.rec.send_columns(f"{RIG_ENTITY}/{name}", indexes=[times],
                                  columns=rr.Scalars.columns(scalars=np.asarray(values, float)))

    def inner(self, snap) -> None:
        pass

    def finish(self, end: RunEnd) -> None:
        if self.rec is not None:
            import json

            import rerun as rr

            # at the end: the notes hold what the run found on its way (the start's check)
            self.rec.log(f"{RIG_ENTITY}/session", rr.TextDocument(
                json.dumps(self.notes, indent=2), media_type="text/plain"), static=True)
        clock = getattr(self.plant, "clock", None)  # none when no frame ever came
        end.metrics["timing"] = {**self.plant.log.block(self.session.period_s,
                                                       self.plant.settings.miss_policy),
                                 "clock": clock.block() if clock is not None else {},
                                 **self.notes.get("timing_notes", {})}


#: samples of the warm-up on the model plant (first calls compile and import: 0.5 s on the
#: first cycle would put the whole schedule behind)
WARM_UP_SAMPLES = 5


def warm_up(prepared, settings) -> None:
    """A few samples of the controller and the task's checks on the model plant, then the
    controller reset to the state the run starts from (the seed's generator, as built)."""
    import numpy as np

    from tspend.loop.metrics import MetricsAccumulator
    from tspend.loop.runner import ClosedLoop
    from tspend.loop.simulation import run_info

    scenario, plant = prepared.scenario, prepared.plant
    short = replace(settings, steps=WARM_UP_SAMPLES)
    loop = ClosedLoop(plant, prepared.controller, scenario.reference, scenario.disturbance,
                      short, task=prepared.task)
    loop.run(run_info(scenario, plant, WARM_UP_SAMPLES, None, prepared.controller, prepared.task),
             [MetricsAccumulator(settings.dt, ss_start=0.0)])
    prepared.controller.reset(np.random.default_rng(scenario.run.seed))
    plant.reset(np.asarray(scenario.plant.x0, dtype=float))


def start_check(prepared, timing_notes: dict, stop=None):
    """The rig's check of its start before START (:meth:`RigPlant.check_start`): the
    controller's :meth:`~tspend.controllers.base.Controller.before_start` on the state
    read then, at the run's first reference; what it found goes into ``timing_notes``
    (``start_check``).  None for a controller that checks nothing.  A signal during the
    check (``stop``, the CLI's) cuts it short: the start is held back, and the loop ends
    interrupted at its first sample, START never sent."""
    from tspend.controllers.base import Observation
    from tspend.runtime.interrupts import Interrupted

    scenario, ctrl, task = prepared.scenario, prepared.controller, prepared.task
    if not ctrl.checks_start:
        return None

    def check(state: np.ndarray | None) -> bool:
        if state is None:
            timing_notes["start_check"] = {"before_start": False}
            print("rig: the rig reads no state before START (its hello): the start is "
                  "checked at the first cycle, the rig started", flush=True)
            return True
        # an admission may take seconds: said, so a quiet rig is not taken for a hung host
        print(f"rig: the start checked before START ({type(ctrl).__name__})", flush=True)
        t0 = time.perf_counter()
        ref = scenario.reference.derivatives(np.zeros(1), ctrl.order)[0]
        found = {"before_start": True, "state": dict(zip(task.names, map(float, state)))}
        timing_notes["start_check"] = found
        try:
            if stop is not None:
                stop.in_controller = True  # a signal raises into the check, as into a step
            refusal = ctrl.before_start(Observation(0.0, state, state[task.view_index], ref,
                                                    task.names, task.constraints))
        except Interrupted:
            pass  # the signal is recorded in stop: said below
        finally:
            if stop is not None:
                stop.in_controller = False
        if stop is not None and stop.signal_name is not None:
            # also where the code it cut turned the signal into an answer of its own
            # (IPOPT's failed solve, so "no plan"): that answer is not a verdict
            found.update(interrupted=stop.signal_name, ms=1e3 * (time.perf_counter() - t0))
            # what the check found before the cut is dropped: the metrics claim no verdict
            ctrl.interrupted()
            print(f"rig: the check of the start cut short by {stop.signal_name}; START not "
                  "sent", flush=True)
            return False
        found.update(refused=refusal, ms=1e3 * (time.perf_counter() - t0))
        if refusal:
            print(f"rig: the start is refused before START: {refusal}", flush=True)
        return refusal is None

    return check


def stop_reason(status: str | None) -> int:
    """The stop frame's reason for a run that ended ``status`` (docs/rig.md's ``X``)."""
    from tspend.loop.runner import CONTROLLER_ERROR, NOT_REACHED

    if status in (None, "completed", NOT_REACHED):
        return protocol.STOP_DONE
    if status == "interrupted":
        return protocol.STOP_SIGNAL
    if status in (CONTROLLER_ERROR, "failed", "diverged"):
        return protocol.STOP_ERROR
    return protocol.STOP_TASK  # the task ended it: a bound, a fall, a refused start


def end_session(session: RigSession, status: str | None) -> None:
    """The stop frame at the loop's end, its reason how the run ended."""
    session.stop_reason = stop_reason(status)
    session.close()


def run_on_rig(prepared, session: RigSession, plant: RigPlant, sinks: Sequence[Sink] = (),
               stop=None, rec=None, notes: dict | None = None, fifo: bool = True):
    """Run ``prepared``'s controller on the rig; a :class:`~tspend.loop.simulation.RunResult`
    with its history (what the host saw and sent: the twin's reference).  The real-time
    settings granted go into the timing block."""
    from tspend.loop.metrics import MetricsAccumulator
    from tspend.loop.runner import ClosedLoop, LoopSettings
    from tspend.loop.simulation import History, RunResult, machine_info, run_info
    from tspend.rig.realtime import real_time

    scenario, ctrl, task = prepared.scenario, prepared.controller, prepared.task
    steps, dt = plant.settings.cycles, session.period_s
    settings = LoopSettings(dt=dt, steps=steps, block_size=BLOCK_SIZE, snapshot_every=0,
                            state_bound=scenario.plant.state_bound,
                            control_bound=scenario.run.control_bound, compiled=False)
    loop = ClosedLoop(plant, ctrl, scenario.reference, scenario.disturbance, settings, stop,
                      task=task)
    metrics = MetricsAccumulator(dt, ss_start=0.5 * steps * dt, seed=scenario.run.seed,
                                 machine=machine_info(prepared.plant, task, scenario, prepared.drawn))
    info = replace(run_info(scenario, prepared.plant, steps, None, ctrl, task), extras=())
    warm_up(prepared, settings)
    notes = dict(notes or {})
    notes["timing_notes"] = timing_notes = dict(notes.get("timing_notes", {}))
    check = start_check(prepared, timing_notes, stop)
    if check is not None:
        # before START and the real-time settings: an admission may take seconds
        plant.check_start(check)
    with real_time(fifo=fifo) as granted:
        timing_notes["realtime"] = granted.as_dict()
        for line in granted.notes:
            print(f"real time: {line}", flush=True)
        timing = TimingSink(plant, session, rec, notes)
        for sink in sinks:  # the first block comes at the end now: no "compiling" notice
            getattr(sink, "cancel", lambda: None)()
        history = History()
        end = loop.run(info, [DeferredSinks([metrics, timing, history, *sinks],
                                            lambda status: end_session(session, status))])
    return RunResult(scenario, end, history.arrays(), ctrl, plant, info)
