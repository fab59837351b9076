"""The closed loop's samples in compiled code, when the plant and the controller allow it.

:class:`tspend.loop.runner.ClosedLoop` runs a block's samples through a *segment*: a stretch
of samples ``[a, b)`` of the block, run without Python between them.  This module is the
one place that decides whether a loop gets one (:func:`segment_runner`): the controller
must offer ``compiled()`` (a :class:`tspend.controllers.base.CompiledController`), the plant a
``compiled()`` step (or ``compiled_mujoco(dt)``) and ``extras_index()``, and no per-sample hook may be on (sensor noise, delay, the outer
loop: :mod:`tspend.loop.effects`); otherwise the generic Python loop runs, sample by sample.
Sampled control (a controller period of several steps, a computation delay) runs in both
(:class:`Hold`).
Everything else (the blocks, the divergence messages, stop requests, snapshots, sinks)
stays with the runner, which calls a segment between two of these events, so they happen
at the same samples as in the generic loop.

Two kinds of segment:

* :class:`CompiledSegment` (analytic plants, :class:`tspend.plants.analytic.CompiledPlant`):
  controller step, RK4 and the block buffers in one ``@njit`` loop;
* :class:`MujocoCompiledSegment` (a MuJoCo plant offering ``compiled_mujoco(dt)``): the
  same loop calling MuJoCo's C ``mj_step`` (through ctypes) on the plant's own mjModel and
  mjData, so nothing of Python runs per sample.  A huge input or MuJoCo's instability
  reset ends the segment and the plant's own Python ``step`` / check says why, as in the
  generic loop.  (Other routes: a tight Python loop of the compiled sample and
  ``mj_step`` was measured at 2.3x bare ``mj_step``; ``mujoco.set_mjcb_control`` with a
  numba cfunc was not taken: the callback is process-global, shared by threads, and
  could reach the controller's arrays only through a cfunc compiled per run.)

Each sample reads the plant's full state, takes the task's view ``x`` out of it
(:class:`Reading`: indices, so the loop knows no plant), calls the controller with both,
records, and ends the segment at the first sample whose state crosses the task's bounds
(``lo < s < hi``, :mod:`tspend.task`) or whose u is not finite or out of bounds.

The arithmetic is the generic loop's, in the same order, so blocks are equal bit for bit
(tests/test_fastloop.py).  One difference in kind: where Python's ``math`` raises on an
overflow inside the plant (the generic loop then ends "the plant failed"), compiled code
carries inf/NaN into the next sample, which ends "the state is not finite"; the samples
kept are the same.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple, Protocol

import numpy as np
from numba import njit
from numba.extending import overload

from tspend.loop.endings import refuses_input, sample_ends  # the endings' one text
from tspend.runtime.jit import JIT
from tspend.plants.analytic import rk4_step

#: what a segment reports: every sample ran, or it stopped at a sample to look at; the
#: plant-level codes are handled inside this module (they become SampleFailed)
RAN, CHECK, BAD_INPUT, UNSTABLE = 0, 1, 2, 3


class Bounds(NamedTuple):
    """The runner's divergence bounds (0 = only non-finite values stop the run)."""

    state: float
    control: float


class Reading(NamedTuple):
    """How a sample reads the full state ``s``: the task's view ``x[k] = s[view_index[k]]``,
    the plant's extras ``E[k] = s[extra_index[k]]``, and the task's bounds ``lo < s < hi``."""

    view_index: np.ndarray   # not "view": numba takes .view for ndarray.view
    extra_index: np.ndarray
    lo: np.ndarray
    hi: np.ndarray


class Buffers(NamedTuple):
    """The block's arrays the segment writes (:class:`tspend.loop.runner.BlockBuffer`'s)."""

    X: np.ndarray
    U: np.ndarray
    D: np.ndarray
    E: np.ndarray
    #: the full state per sample (issue 20: the joints' metrics)
    F: np.ndarray


class Hold(NamedTuple):
    """Sampled control (``run.control_period``, ``run.control_delay``) as compiled code
    keeps it, between segments: the controller runs at every ``every``-th step and its u
    is held (zero-order hold); a computed u is applied ``delay`` steps later (0 before the
    first one arrives).  What :meth:`tspend.loop.runner.ClosedLoop._loop` does with its
    ``held`` and its deque of pending u, in arrays."""

    every: int
    delay: int
    #: the run's step number of the next sample
    step: np.ndarray     # (1,) int64
    #: the u applied now
    held: np.ndarray     # (1,)
    #: u computed but not applied yet: a ring of (step it applies from, u)
    due: np.ndarray      # (capacity,) int64
    value: np.ndarray    # (capacity,)
    #: the ring's first entry and its number of entries
    ring: np.ndarray     # (2,) int64


def hold_of(every: int, delay: int) -> Hold:
    """A fresh :class:`Hold`: at most ``delay // every + 1`` u wait at any step."""
    capacity = delay // every + 2
    return Hold(int(every), int(delay), np.zeros(1, dtype=np.int64), np.zeros(1),
                np.zeros(capacity, dtype=np.int64), np.zeros(capacity),
                np.zeros(2, dtype=np.int64))


@njit(**JIT)
def _held_sample(settings, state, scratch, t: float, full: np.ndarray, x: np.ndarray,
                 ref: np.ndarray, dt: float, diag: np.ndarray, hold: Hold) -> float:
    """The u applied at this sample: the controller's, evaluated when the step is a
    multiple of ``every`` (over ``dt * every``), held and delayed as :class:`Hold` says."""
    g = hold.step[0]
    hold.step[0] = g + 1
    due, value, ring = hold.due, hold.value, hold.ring
    capacity = due.size
    if g % hold.every == 0:
        u_new = controller_sample(settings, state, scratch, t, full, x, ref, dt * hold.every,
                                  diag)
        if hold.delay:
            k = (ring[0] + ring[1]) % capacity
            due[k] = g + hold.delay
            value[k] = u_new
            ring[1] += 1
        else:
            hold.held[0] = u_new
    while ring[1] > 0 and due[ring[0]] <= g:
        hold.held[0] = value[ring[0]]
        ring[0] = (ring[0] + 1) % capacity
        ring[1] -= 1
    return hold.held[0]


class Segment(Protocol):
    def __call__(self, a: int, b: int, t: np.ndarray, ref: np.ndarray, dist: np.ndarray,
                 dt: float) -> tuple[int, int]:
        """Run samples ``a .. b-1`` of the block; ``(b, RAN)``, or ``(i, CHECK)`` when
        sample i's u is not finite or out of bounds, or its state crosses the task's
        bounds (recorded; the plant not stepped; the full state left in ``full``)."""

    full: np.ndarray


#: compiled controller steps by the type of their settings (``CompiledController``), filled
#: as loops are built: compiled code picks the step by type, so the loop caches on disk
_CONTROLLER_STEPS: dict[type, Callable] = {}


def controller_sample(settings, state, scratch, t, full, x, ref, dt, diag) -> float:
    """One compiled controller sample, the step chosen by the type of ``settings``
    (compiled code only)."""
    raise TypeError("controller_sample is for compiled code")


@overload(controller_sample, jit_options=JIT)
def _controller_sample(settings, state, scratch, t, full, x, ref, dt, diag):
    # numba's own attribute of a NamedTuple type: the class compiled code dispatches on
    step = _CONTROLLER_STEPS.get(getattr(settings, "instance_class", None))
    if step is None:
        return None

    def impl(settings, state, scratch, t, full, x, ref, dt, diag):
        return step(settings, state, scratch, t, full, x, ref, dt, diag)

    return impl


@njit(**JIT)
def _take_sample(settings, state, scratch, full, x, diag, buf: Buffers, reading: Reading,
                 i: int, t: np.ndarray, ref: np.ndarray, dt: float,
                 bounds: Bounds, hold: Hold) -> tuple[float, bool]:
    """Sample i from the full state ``full``: the view, the controller (sampled and held),
    the block's row; returns u and whether the runner must look at this sample (it ends
    the run)."""
    view, extra = reading.view_index, reading.extra_index
    for j in range(view.size):
        x[j] = full[view[j]]
    u = _held_sample(settings, state, scratch, t[i], full, x, ref[i], dt, diag, hold)
    for j in range(x.size):
        buf.X[i, j] = x[j]
    buf.U[i] = u
    for j in range(diag.size):
        buf.D[i, j] = diag[j]
    for j in range(extra.size):
        buf.E[i, j] = full[extra[j]]
    for j in range(min(full.size, buf.F.shape[1])):
        buf.F[i, j] = full[j]
    return u, sample_ends(x, u, full, reading.lo, reading.hi, bounds.state, bounds.control)


@njit(**JIT)
def _analytic_samples(settings, state, scratch, params, s, clock, work, full_order,
                      full, x, diag, buf: Buffers, reading: Reading, a: int, b: int,
                      t: np.ndarray, ref: np.ndarray, dist: np.ndarray, dt: float,
                      bounds: Bounds, hold: Hold) -> tuple[int, int]:
    """Samples ``a .. b-1``: what :meth:`tspend.loop.runner.ClosedLoop._loop` does per sample."""
    for i in range(a, b):
        for j in range(full.size):
            full[j] = s[full_order[j]]
        u, check = _take_sample(settings, state, scratch, full, x, diag, buf, reading, i, t,
                                ref, dt, bounds, hold)
        if check:
            return i, CHECK
        rk4_step(params, clock[0], s, u, dist[i], dt, work)
        clock[0] += dt
    return b, RAN


class CompiledSegment:
    """An analytic plant and a compiled controller in one compiled loop."""

    def __init__(self, compiled_controller: Any, compiled_plant: Any, full_order: np.ndarray,
                 diag: np.ndarray, buffers: Buffers, reading: Reading, bounds: Bounds,
                 order: int, hold: Hold) -> None:
        c, p = compiled_controller, compiled_plant
        _CONTROLLER_STEPS.setdefault(type(c.settings), c.step)
        self.full = np.zeros(full_order.size)
        self._args = (c.settings, c.state, c.scratch, p.params, p.state,
                      p.clock, p.work, full_order, self.full, np.zeros(order), diag, buffers,
                      reading)
        self._bounds, self._hold = bounds, hold

    def __call__(self, a: int, b: int, t: np.ndarray, ref: np.ndarray, dist: np.ndarray,
                 dt: float) -> tuple[int, int]:
        return _analytic_samples(*self._args, a, b, t, ref, dist, dt, self._bounds, self._hold)


class SampleFailed(Exception):
    """The plant's step failed at sample ``i`` of the block (recorded): the runner ends the
    run as its generic loop does on the plant's exception ``error``."""

    def __init__(self, i: int, error: BaseException) -> None:
        super().__init__(str(error))
        self.i, self.error = i, error


@njit(**JIT)
def _mujoco_samples(settings, state, scratch, mj_step, link, full, x, diag, buf: Buffers,
                    reading: Reading, a: int, b: int, t: np.ndarray, ref: np.ndarray,
                    dist: np.ndarray, dt: float, bounds: Bounds, hold: Hold) -> tuple[int, int]:
    """Samples ``a .. b-1`` on MuJoCo: :meth:`tspend.plants.mujoco_plant.MujocoPlant.step`
    with MuJoCo's C ``mj_step`` called from here; the full state is [qpos; qvel]."""
    qpos, qvel, numbers = link.qpos, link.qvel, link.warning_number
    nq = qpos.size
    for i in range(a, b):
        for j in range(nq):
            full[j] = qpos[j]
        for j in range(qvel.size):
            full[nq + j] = qvel[j]
        u, check = _take_sample(settings, state, scratch, full, x, diag, buf, reading, i, t,
                                ref, dt, bounds, hold)
        if check:
            return i, CHECK
        d = dist[i]
        if refuses_input(u, d, link.max_input):
            return i, BAD_INPUT
        link.ctrl[link.actuator] = u
        link.qfrc[link.omega] = link.d_to_tau * d
        for _ in range(link.nstep):
            mj_step(link.model_address, link.data_address)
        if numbers[link.bad_qpos] or numbers[link.bad_qvel] or numbers[link.bad_qacc]:
            return i, UNSTABLE
    return b, RAN


class MujocoCompiledSegment:
    """A MuJoCo plant (its ``compiled_mujoco(dt)``) and a compiled controller in one
    compiled loop calling MuJoCo's C ``mj_step``."""

    def __init__(self, compiled_controller: Any, plant: Any, link: Any, mj_step: Any,
                 diag: np.ndarray, buffers: Buffers, reading: Reading, bounds: Bounds,
                 order: int, hold: Hold) -> None:
        c = compiled_controller
        _CONTROLLER_STEPS.setdefault(type(c.settings), c.step)
        self._plant, self._buf = plant, buffers
        self.full = np.zeros(link.qpos.size + link.qvel.size)
        self._args = (c.settings, c.state, c.scratch, mj_step, link, self.full,
                      np.zeros(order), diag, buffers, reading)
        self._bounds, self._hold = bounds, hold

    def __call__(self, a: int, b: int, t: np.ndarray, ref: np.ndarray, dist: np.ndarray,
                 dt: float) -> tuple[int, int]:
        i, code = _mujoco_samples(*self._args, a, b, t, ref, dist, dt, self._bounds,
                                  self._hold)
        if code == BAD_INPUT:
            # the plant's own step refuses the input and says why
            try:
                self._plant.step(float(self._buf.U[i]), float(dist[i]), dt)
            except Exception as exc:
                raise SampleFailed(i, exc) from exc
            return i + 1, RAN  # the plant took it after all: sample i is complete
        if code == UNSTABLE:
            error = self._plant.instability(float(t[i]))
            raise SampleFailed(i, error)
        return i, code


def segment_runner(plant: Any, controller: Any, hook: Any, buffers: Buffers, bounds: Bounds,
                   dt: float, task: Any, every: int = 1, delay: int = 0) -> Segment | None:
    """A compiled segment for this loop, or None: the generic loop runs (module docstring).

    ``task`` is the run's :class:`tspend.task.Task` (its view and bounds); ``every`` and
    ``delay`` the sampled control's steps per controller sample and delay (:class:`Hold`)."""
    if hook is not None:
        return None
    compiled_controller = controller.compiled()
    if compiled_controller is None:
        return None
    extra = plant.extras_index()
    if extra is None or extra.size != buffers.E.shape[1]:
        return None
    reading = Reading(np.ascontiguousarray(task.view_index, dtype=np.intp),
                      np.ascontiguousarray(extra, dtype=np.intp), task.lo, task.hi)
    order = int(controller.order)
    p = plant.compiled()
    if p is not None:
        full_order = np.ascontiguousarray(p.full_order, dtype=np.intp)
        return CompiledSegment(compiled_controller, p, full_order, controller.diag, buffers,
                               reading, bounds, order, hold_of(every, delay))
    link = plant.compiled_mujoco(dt)
    if link is not None:
        from tspend.plants.mujoco_plant import mj_step_pointer

        return MujocoCompiledSegment(compiled_controller, plant, link, mj_step_pointer(),
                                     controller.diag, buffers, reading, bounds, order,
                                     hold_of(every, delay))
    return None
