"""The closed-loop runner: plant, controller, reference and disturbance, sample by sample.

It knows nothing of Rerun or MuJoCo: a plant satisfies :class:`tspend.plants.base.Plant`
and every output goes to sinks (:mod:`tspend.loop.sinks`).  Samples are gathered in blocks
of fixed size, preallocated once, and each full block is handed to the sinks, so a long
run keeps only one block in memory.

Every sample the controller gets one :class:`tspend.controllers.base.Observation`: the
plant's full state and the task's view of it (:class:`tspend.task.Task`).

A run ends ``completed``; with the task's termination status (``fell``, ``rail_end``,
``joint_limit``, ``state_bound``: :data:`tspend.task.TERMINATIONS`) at the first sample
whose full state crosses the task's bounds (that sample recorded, its control never
applied); ``diverged`` when the state, control or a parameter stops
being finite or leaves its configured bound (the block up to the last finite sample is
still delivered); ``interrupted`` when a :class:`StopRequest` is set (the CLI's SIGINT/SIGTERM handlers
do that; the loop honours it between samples) or on KeyboardInterrupt; then
:class:`RunInterrupted` is raised after the sinks have finished, so the caller can set
the exit status.  Sinks always get :meth:`finish`.
"""

from __future__ import annotations

import math
import time
import warnings
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from tspend.controllers.base import Controller, Diagnostic, Observation, check_diagnostics
from tspend.runtime.errors import DivergenceError, RunRefused
from tspend.loop.fastloop import CHECK, Bounds, Buffers, SampleFailed, Segment, segment_runner
from tspend.runtime.interrupts import Interrupted, StopRequest
from tspend.runtime.plugins import own_failure
from tspend.plants.base import Plant
from tspend.config.signals import Disturbance, Reference
from tspend.loop.sinks import Block, RunEnd, RunInfo, Sink
from tspend.task import TERMINATIONS, Task, build_task


class RunInterrupted(Exception):
    """A request to stop the run (a signal); carries the exit status to use."""

    def __init__(self, signal_name: str, exit_status: int) -> None:
        super().__init__(f"interrupted by {signal_name}")
        self.signal_name = signal_name
        self.exit_status = exit_status
        #: how the run ended (metrics up to the stop), set by the runner
        self.end: RunEnd | None = None


@dataclass(frozen=True)
class LoopSettings:
    dt: float
    steps: int
    block_size: int = 1000
    snapshot_every: int = 20          # steps between inner snapshots (0 = never)
    state_bound: float = 0.0          # 0 = only non-finite values stop the run
    control_bound: float = 0.0
    #: run stretches of samples in compiled code when plant and controller offer it
    #: (:mod:`tspend.loop.fastloop`); False forces the generic loop (same results)
    compiled: bool = True
    #: sampled control: the controller runs every ``control_every`` steps and its u is
    #: held in between (zero-order hold); a computed u is applied ``control_delay`` steps
    #: later (computation delay; 0 applied before the first one arrives)
    control_every: int = 1
    control_delay: int = 0

    @property
    def sampled(self) -> bool:
        return self.control_every > 1 or self.control_delay > 0


def output_error(xp: Any, x: Any, ref: Any, wraps: np.ndarray | None) -> Any:
    """e = x - r per sample (k, n), the entries of revolute angles (``wraps``; None: none)
    wrapped to (-pi, pi] only where they turned over, so an unwrapped error keeps its exact
    value.  One text for the CPU runner (numpy) and the accelerator (jax.numpy)."""
    e = x - ref
    if wraps is None or not np.any(wraps):
        return e
    turned = xp.asarray(wraps) & (xp.abs(e) > np.pi)
    return xp.where(turned, xp.mod(e + np.pi, 2 * np.pi) - np.pi, e)


class BlockBuffer:
    """Preallocated arrays of one block; ``view(k)`` exposes the first k samples.

    The runner's own keys (``t x ref e u d``), then each of the controller's declared
    diagnostics under its name, then the plant's extras as ``extra/NAME``.
    """

    def __init__(self, size: int, n: int, diag_width: int, extras: tuple[str, ...],
                 diagnostics: tuple[Diagnostic, ...] = (), full_size: int = 0,
                 wraps: np.ndarray | None = None) -> None:
        self.n = n
        self.x = np.zeros((size, n))
        #: the plant's full state per sample (``state`` in a block: the joints' metrics)
        self.full = np.zeros((size, full_size))
        #: the view's entries that are angles of a revolute joint: their error is wrapped
        #: to (-pi, pi] (a pole swung up once is at 2 pi, not 2 pi off)
        self.wraps = wraps if wraps is not None and wraps.any() else None
        #: the controller's wall time per evaluation (s; NaN on held samples), filled by
        #: the generic loop only (``timed``)
        self.compute = np.full(size, np.nan)
        self.timed = False
        self.u = np.zeros(size)
        self.diag = np.zeros((size, diag_width))
        self.extra_names = extras
        self.extra = np.zeros((size, len(extras)))
        self.diagnostics = diagnostics

    def view(self, k: int, t: np.ndarray, ref: np.ndarray, d: np.ndarray) -> dict[str, np.ndarray]:
        D, X = self.diag[:k], self.x[:k]
        e = output_error(np, X, ref[:k, :self.n], self.wraps)
        data = {"t": t[:k], "x": X, "ref": ref[:k], "e": e, "u": self.u[:k],
                "d": d[:k]}
        if self.full.shape[1]:
            data["state"] = self.full[:k]

        for diagnostic in self.diagnostics:
            data[diagnostic.name] = D[:, diagnostic.columns]
        for j, name in enumerate(self.extra_names):
            data[f"extra/{name}"] = self.extra[:k, j]
        return data


#: the status of a run the controller ended by raising, exiting or returning no number
CONTROLLER_ERROR = "controller_error"
#: the status of a run that kept every bound but did not reach the task's goal
NOT_REACHED = "not_reached"
#: the status of a run a check refused at its first sample, before any input was applied
#: (:class:`~tspend.runtime.errors.RunRefused`: a safety filter that cannot certify its start)
REFUSED = "refused"


def _control_value(u: object) -> float:
    """The controller's return as the number u (TypeError naming what came back instead:
    a vector, a string, None)."""
    if isinstance(u, (bool, str, bytes)) or u is None:
        raise TypeError(f"step() returned {type(u).__name__} {u!r:.40}, not a number")
    arr = np.asarray(u)
    if arr.size != 1 or arr.dtype.kind not in "iuf":
        raise TypeError(f"step() returned a {arr.dtype} array of shape {arr.shape}, not one number")
    return float(arr.reshape(()))


def controller_failure(exc: BaseException, t: float, kind: str) -> str:
    """One line saying how the controller failed at ``t``, naming the innermost frame of
    the controller's own code (a plug-in's file and line), not tspend's."""
    import traceback

    frames = [f for f in traceback.extract_tb(exc.__traceback__)
              if "/tspend/loop/" not in f.filename.replace("\\", "/")]
    where = f" ({frames[-1].filename}, line {frames[-1].lineno}, in {frames[-1].name})" if frames else ""
    what = (f"SystemExit({exc.code!r})" if isinstance(exc, SystemExit)
            else f"{type(exc).__name__}: {exc}")
    return f"{CONTROLLER_ERROR} at t = {t:.4f} s: controller '{kind}' failed: {what}{where}"


#: a run that ends with the actuator saturated this long (s) says so in its message
SATURATED_FOR_S = 0.1


def _what_else(plant: Plant, metrics: dict) -> str:
    """What else was true when the task ended a run, that a reader needs to know its
    cause: a constraint MuJoCo applied then (a contact holding the cart), and the actuator
    saturated over the last samples."""
    parts = []
    try:
        active = plant.constraint_active()
    except Exception:  # a plant that cannot say: nothing to add
        active = ""
    if active:
        parts.append(f"MuJoCo applied {active}")
    sat = metrics.get("saturated_at_end_s") or 0.0
    if sat >= SATURATED_FOR_S:
        act = metrics.get("actuator") or {}
        unit = f" {act['u_unit']}" if act.get("u_unit") else ""
        applied = metrics.get("max_abs_u", float("nan"))
        force = (f" ({act['force_per_u'] * applied:.4g} {act['force_unit']} at rest)"
                 if act.get("force_unit") and applied is not None else "")
        # the command is u, never a force: the actuator clipped it before any force
        parts.append(f"the actuator was saturated for the last {sat:.3g} s (commanded up to "
                     f"{metrics.get('max_abs_u_command', float('nan')):.4g}{unit}, applied at "
                     f"most {applied:.4g}{unit}{force})")
    return ("; while " + " and ".join(parts)) if parts else ""


def _read_only(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a``: what a controller is handed, so that no controller (a
    plug-in's included) can write into the state the task then judges, or into the
    reference and state the recording keeps."""
    v = a.view()
    v.flags.writeable = False
    return v


class ClosedLoop:
    """Runs ``controller`` on ``plant`` tracking ``reference`` under ``disturbance``.

    ``task``: the view the controller tracks and the bounds that end the run (default:
    the plant domain's task, :func:`tspend.task.build_task`).
    """

    def __init__(self, plant: Plant, controller: Controller, reference: Reference,
                 disturbance: Disturbance, settings: LoopSettings,
                 stop: StopRequest | None = None,
                 hook: "Callable[[float, np.ndarray, np.ndarray], np.ndarray] | None" = None,
                 task: Task | None = None) -> None:
        if plant.order != controller.order:
            raise ValueError(f"plant order {plant.order} != controller order {controller.order}")
        check_diagnostics(controller.diagnostics, controller.diag)
        self.task = task if task is not None else build_task(
            plant, reference=reference, disturbance=disturbance)
        self.plant = plant
        self.controller = controller
        self.reference = reference
        self.disturbance = disturbance
        self.s = settings
        self.stop = stop if stop is not None else StopRequest()
        #: per-sample hook (t, x, ref row) -> the state the controller sees; it may shape
        #: the reference row in place (tspend.loop.effects: sensor noise, delay, outer loop)
        self.hook = hook
        self._done = 0
        self.end: RunEnd | None = None
        #: which loop ran: "compiled" (:mod:`tspend.loop.fastloop`) or "generic"
        self.path = ""

    def run(self, info: RunInfo, sinks: list[Sink]) -> RunEnd:
        for sink in sinks:
            sink.start(info)
        started = time.perf_counter()
        done, status, message = 0, "completed", ""
        try:
            # overflow on the way to a divergence is expected: it is detected and reported
            with np.errstate(over="ignore", invalid="ignore"):
                done, status, message = self._loop(sinks)
        except (KeyboardInterrupt, RunInterrupted) as exc:
            stop = exc if isinstance(exc, RunInterrupted) else RunInterrupted("SIGINT", 130)
            stop.end = self._finish(sinks, "interrupted", str(stop), self._done, started)
            raise stop from None
        except Exception as exc:  # a bug or a plant failure: keep what was recorded
            self._finish(sinks, "failed", f"{type(exc).__name__}: {exc}", self._done, started)
            raise
        return self._finish(sinks, status, message, done, started)

    def _finish(self, sinks: list[Sink], status: str, message: str, done: int,
                started: float) -> RunEnd:
        wall = time.perf_counter() - started
        for sink in sinks:  # optional: a sink that acts on how the run ended (a rig's stop)
            if hasattr(sink, "ending"):
                sink.ending(status)
        metrics = {}
        for sink in sinks:
            if hasattr(sink, "result"):
                metrics = sink.result(wall_s=wall)
        own = self.controller.run_metrics()
        if own:
            metrics = {**metrics, **own}
        if status in TERMINATIONS and status != NOT_REACHED:
            message += _what_else(self.plant, metrics)
        goal = metrics.get("goal")
        if status == "completed" and goal is not None and goal["met"] is False:
            # every bound held but the task's goal was not reached: no "completed" claimed
            status = NOT_REACHED
            when = (f"reached only at t = {goal['reached_at_s']:.4g} s" if goal["reached_at_s"] is not None
                    else "never within it to the end")
            message = (f"{NOT_REACHED}: the tracked output was not within {goal['angle_rad']:g} of "
                       f"its reference from t = {goal['by_s']:g} s to the end ({when})")
        end = RunEnd(status=status, message=message, steps_done=done, metrics=metrics)
        for sink in sinks:
            try:
                sink.finish(end)
            except Exception as exc:  # one failing sink must not cost the others their data
                warnings.warn(f"sink {type(sink).__name__} failed to finish: {exc}",
                              RuntimeWarning, stacklevel=2)
        self.end = end
        return end

    def _loop(self, sinks: list[Sink]) -> tuple[int, str, str]:
        s, plant, ctrl = self.s, self.plant, self.controller
        n, dt = ctrl.order, s.dt
        extras = tuple(plant.extras().keys())
        buf = BlockBuffer(s.block_size, n, ctrl.diag.size, extras, ctrl.diagnostics,
                          len(self.task.names), self._wraps())
        X, U, D, E, F = buf.x, buf.u, buf.diag, buf.extra, buf.full
        diag = ctrl.diag
        # inner snapshots cost a numpy evaluation each: only for sinks that draw them, and
        # only from controllers that have an inner state to show
        snapshot = ctrl.snapshot
        snap_sinks = [sk for sk in sinks if getattr(sk, "wants_inner", False)] \
            if ctrl.has_snapshots else []
        snap_every = s.snapshot_every if snap_sinks else 0
        bounded = s.state_bound > 0.0 or s.control_bound > 0.0
        isfinite = math.isfinite
        stop, hook, task = self.stop, self.hook, self.task
        view, names, watched = task.view_index, task.names, bool(task.watched)
        constraints = task.constraints
        crossed = task.ended
        segment = segment_runner(plant, ctrl, hook, Buffers(X, U, D, E, F),
                                 Bounds(s.state_bound, s.control_bound), dt, task,
                                 s.control_every, s.control_delay) if s.compiled else None
        every, delay = s.control_every, s.control_delay
        C, clock = buf.compute, time.perf_counter
        buf.timed = segment is None
        # u computed but not applied yet (computation delay): (step it applies from, u)
        pending: deque[tuple[int, float]] = deque()
        held = 0.0
        self.path = "generic" if segment is None else "compiled"
        if segment is not None:
            return self._segments(sinks, segment, buf, snap_sinks, snap_every)
        for start in range(0, s.steps, s.block_size):
            k = min(s.block_size, s.steps - start)
            t = (start + np.arange(k)) * dt
            ref = self.reference.derivatives(t, n)
            dist = self.disturbance(t)
            i = 0
            try:
                for i in range(k):
                    if stop.signal_name is not None:
                        raise RunInterrupted(stop.signal_name, stop.exit_status)
                    full = plant.full_state()
                    x = full[view]
                    g = start + i
                    if g % every == 0:
                        seen = x if hook is None else hook(t[i], x, ref[i])
                        c0 = clock()
                        stop.in_controller = True
                        try:
                            u_new = _control_value(ctrl.step(Observation(
                                t[i], _read_only(full), _read_only(seen), _read_only(ref[i]),
                                names, constraints), dt * every))
                            if stop.signal_name is not None:
                                # the signal's exception swallowed by the code it cut, which
                                # answered for it (IPOPT's "no plan"): that answer not applied
                                raise Interrupted(stop.signal_name, stop.exit_status)
                        except Interrupted as exc:
                            # a signal while the controller's code ran (a plug-in sleeping
                            # in its step): the stop at this sample, what came before kept
                            ctrl.interrupted()
                            raise RunInterrupted(exc.signal_name, exc.exit_status) from None
                        except BaseException as exc:
                            if not own_failure(exc):
                                raise  # Ctrl-C without the CLI's handlers: the run's stop
                            if stop.signal_name is not None:
                                # the signal's exception, turned into another by the code it
                                # interrupted (IPOPT's "no plan" for a solve cut short)
                                ctrl.interrupted()
                                raise RunInterrupted(stop.signal_name, stop.exit_status) from None
                            if isinstance(exc, RunRefused):
                                # refused before its first input: nothing of it applied
                                return self._diverged(sinks, start, buf, t, ref, dist, i,
                                                      f"{REFUSED} at t = {float(t[i]):.4f} s: "
                                                      f"{exc}", REFUSED)
                            # the controller's own failure (a plug-in's bug, a wrong return,
                            # sys.exit, a BaseException of its own: GeneratorExit,
                            # CancelledError): the run ends as it, what came before kept
                            return self._diverged(sinks, start, buf, t, ref, dist, i,
                                                  controller_failure(exc, float(t[i]), ctrl.kind),
                                                  CONTROLLER_ERROR)
                        finally:
                            stop.in_controller = False
                        C[i] = clock() - c0
                        if delay:
                            pending.append((g + delay, u_new))
                        else:
                            held = u_new
                    else:
                        C[i] = math.nan
                    while pending and pending[0][0] <= g:
                        held = pending.popleft()[1]
                    u = held
                    X[i] = x
                    F[i] = full
                    U[i] = u
                    D[i] = diag
                    if extras:
                        E[i] = tuple(plant.extras().values())
                    # a non-finite state or parameter reaches u within the sample
                    if (not isfinite(u) or (bounded and self._out_of_bounds(x, u))
                            or (watched and crossed(full))):
                        problem, kept, status = self._diagnose(x, u, t[i], full)
                        return self._diverged(sinks, start, buf, t, ref, dist, i + kept, problem,
                                              status)
                    try:
                        plant.step(u, dist[i], dt)
                    except (ArithmeticError, ValueError, DivergenceError) as exc:
                        return self._plant_failed(sinks, start, buf, t, ref, dist, i, exc)
                    if snap_every and (start + i) % snap_every == 0:
                        snap = snapshot(float(t[i]), start + i, x)
                        for sink in snap_sinks:
                            sink.inner(snap)
            except BaseException:
                # interrupted or failed inside sample i: the samples before it are complete
                self._emit(sinks, start, buf, t, ref, dist, i)
                self._done = start + i
                raise
            ended = self._end_block(sinks, start, buf, t, ref, dist, k)
            if ended is not None:
                return ended
        return s.steps, "completed", ""

    def _wraps(self) -> np.ndarray:
        """Which entries of the task's view are revolute joints' angles."""
        hinges = {j.name for j in self.plant.joints if j.kind == "hinge"}
        return np.array([name in hinges for name in self.task.view], dtype=bool)

    def _segments(self, sinks: list[Sink], segment: Segment, buf: BlockBuffer,
                  snap_sinks: list[Sink], snap_every: int) -> tuple[int, str, str]:
        """:meth:`_loop` with each stretch of samples between two events (a snapshot, a
        divergence, a stop check, the block's end) run by a compiled ``segment``
        (:mod:`tspend.loop.fastloop`): the same samples, blocks, snapshots and endings."""
        s, n, dt, X, U, D = self.s, self.controller.order, self.s.dt, buf.x, buf.u, buf.diag
        stop = self.stop
        snapshot = self.controller.snapshot
        for start in range(0, s.steps, s.block_size):
            k = min(s.block_size, s.steps - start)
            t = (start + np.arange(k)) * dt
            ref = self.reference.derivatives(t, n)
            dist = self.disturbance(t)
            i = 0
            try:
                while i < k:
                    if stop.signal_name is not None:
                        raise RunInterrupted(stop.signal_name, stop.exit_status)
                    snap = i + (-(start + i)) % snap_every if snap_every else k
                    try:
                        i, code = segment(i, min(k, snap + 1), t, ref, dist, dt)
                    except SampleFailed as failed:
                        i = failed.i
                        if not isinstance(failed.error, (ArithmeticError, ValueError,
                                                         DivergenceError)):
                            raise failed.error from None
                        return self._plant_failed(sinks, start, buf, t, ref, dist, i,
                                                  failed.error)
                    if code == CHECK:
                        problem, kept, status = self._diagnose(X[i], float(U[i]), t[i],
                                                               segment.full)
                        return self._diverged(sinks, start, buf, t, ref, dist, i + kept, problem,
                                              status)
                    if i == snap + 1:
                        inner = snapshot(float(t[snap]), start + snap, X[snap].copy())
                        for sink in snap_sinks:
                            sink.inner(inner)
            except BaseException:
                self._emit(sinks, start, buf, t, ref, dist, i)
                self._done = start + i
                raise
            ended = self._end_block(sinks, start, buf, t, ref, dist, k)
            if ended is not None:
                return ended
        return s.steps, "completed", ""

    def _end_block(self, sinks: list[Sink], start: int, buf: BlockBuffer, t: np.ndarray,
                   ref: np.ndarray, dist: np.ndarray, k: int) -> tuple[int, str, str] | None:
        """Deliver a full block, or end the run as diverged at its first non-finite
        diagnostic (the samples before it delivered)."""
        D = buf.diag[:k]
        bad = self._first_non_finite(D) if D.shape[1] else None
        if bad is not None:
            return self._diverged(sinks, start, buf, t, ref, dist, bad,
                                  f"diverged at t = {t[bad]:.4f} s: a parameter or "
                                  f"estimate is not finite")
        self._emit(sinks, start, buf, t, ref, dist, k)
        self._done = start + k
        return None

    def _plant_failed(self, sinks: list[Sink], start: int, buf: BlockBuffer, t: np.ndarray,
                      ref: np.ndarray, dist: np.ndarray, i: int,
                      exc: BaseException) -> tuple[int, str, str]:
        """The plant's step raised at sample i (math.exp overflow, sin(inf), MuJoCo's own
        instability check): sample i is kept, the run ends."""
        return self._diverged(sinks, start, buf, t, ref, dist, i + 1,
                              f"diverged at t = {t[i]:.4f} s: the plant failed ({exc})")

    def _diverged(self, sinks: list[Sink], start: int, buf: BlockBuffer, t: np.ndarray,
                  ref: np.ndarray, dist: np.ndarray, kept: int,
                  message: str, status: str = "diverged") -> tuple[int, str, str]:
        """Deliver the block's first ``kept`` samples and end the run as ``status``."""
        self._emit(sinks, start, buf, t, ref, dist, kept)
        self._done = start + kept
        return self._done, status, message

    @staticmethod
    def _first_non_finite(D: np.ndarray) -> int | None:
        ok = np.isfinite(D).all(axis=1)
        return None if ok.all() else int(np.argmin(ok))

    def _out_of_bounds(self, x: np.ndarray, u: float) -> bool:
        return ((self.s.state_bound > 0.0 and float(np.abs(x).max()) > self.s.state_bound)
                or (self.s.control_bound > 0.0 and abs(u) > self.s.control_bound))

    def _diagnose(self, x: np.ndarray, u: float, t: float,
                  full: np.ndarray) -> tuple[str, int, str]:
        """What ended the run at time t, whether that sample is kept (1: finite) or not,
        and the run's status."""
        if not np.all(np.isfinite(x)):
            return f"diverged at t = {t:.4f} s: the state is not finite", 0, "diverged"
        if not math.isfinite(u):
            return f"diverged at t = {t:.4f} s: the control u is not finite", 0, "diverged"
        if self.s.state_bound > 0.0:
            worst = int(np.argmax(np.abs(x)))
            if abs(x[worst]) > self.s.state_bound:
                return (f"diverged at t = {t:.4f} s: |x{worst + 1}| = {abs(x[worst]):.4g} "
                        f"exceeds state_bound {self.s.state_bound:g}", 1, "diverged")
        if self.s.control_bound > 0.0 and abs(u) > self.s.control_bound:
            return (f"diverged at t = {t:.4f} s: |u| = {abs(u):.4g} exceeds "
                    f"control_bound {self.s.control_bound:g}", 1, "diverged")
        ended = self.task.termination(full, float(t))
        assert ended is not None, "a sample was stopped with nothing to report"
        status, message = ended
        return message, 1, status

    def _emit(self, sinks: list[Sink], start: int, buf: BlockBuffer, t: np.ndarray,
              ref: np.ndarray, dist: np.ndarray, k: int) -> None:
        if k <= 0:
            return
        block = Block(start=start, data=buf.view(k, t, ref, dist))
        for sink in sinks:
            sink.block(block)
            # wall times are not data (two runs differ): only to the sinks that time
            if buf.timed and getattr(sink, "wants_compute_times", False):
                sink.compute_times(buf.compute[:k])
