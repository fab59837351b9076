"""The closed loop's samples in compiled code, when the plant and the controller allow it.

:class:`tspend.runner.ClosedLoop` runs a block's samples through a *segment*: a stretch
of samples ``[a, b)`` of the block, run without Python between them.  This module is the
one place that decides whether a loop gets one (:func:`segment_runner`): the controller
must offer ``compiled()`` (a :class:`tspend.controller.CompiledController`), the plant a
``compiled()`` step, and no per-sample hook may be on (sensor noise, delay, the outer
loop: :mod:`tspend.effects`); otherwise the generic Python loop runs, sample by sample.
Everything else (the blocks, the divergence messages, stop requests, snapshots, sinks)
stays with the runner, which calls a segment between two of these events, so they happen
at the same samples as in the generic loop.

Two kinds of segment:

* :class:`CompiledSegment` (analytic plants, :class:`tspend.plants.analytic.CompiledPlant`):
  controller step, RK4 and the block buffers in one ``@njit`` loop;
* :class:`MujocoSegment` (a MuJoCo plant offering ``state_views()``): a tight Python loop
  of the compiled controller sample and the plant's ``step`` (one ``mj_step(m, d,
  nstep=k)``), reading the state from MuJoCo's arrays in place.

The arithmetic is the generic loop's, in the same order, so blocks are equal bit for bit
(tests/test_fastloop.py).  One difference in kind: where Python's ``math`` raises on an
overflow inside the plant (the generic loop then ends "the plant failed"), compiled code
carries inf/NaN into the next sample, which ends "the state is not finite"; the samples
kept are the same.
"""

from __future__ import annotations

import math
from typing import Any, Callable, NamedTuple, Protocol

import numpy as np
from numba import njit
from numba.extending import overload

from .bspline import JIT
from .plants.analytic import rk4_step

#: what a segment reports: every sample ran, or it stopped at a sample to look at
RAN, CHECK = 0, 1


class Bounds(NamedTuple):
    """The runner's divergence bounds (0 = only non-finite values stop the run)."""

    state: float
    control: float


class Buffers(NamedTuple):
    """The block's arrays the segment writes (:class:`tspend.runner.BlockBuffer`'s)."""

    X: np.ndarray
    U: np.ndarray
    D: np.ndarray
    E: np.ndarray


class Segment(Protocol):
    def __call__(self, a: int, b: int, t: np.ndarray, ref: np.ndarray, dist: np.ndarray,
                 dt: float) -> tuple[int, int]:
        """Run samples ``a .. b-1`` of the block; ``(b, RAN)``, or ``(i, CHECK)`` when
        sample i's u is not finite or out of bounds (recorded; the plant not stepped)."""


#: compiled controller steps by the type of their settings (``CompiledController``), filled
#: as loops are built: compiled code picks the step by type, so the loop caches on disk
_CONTROLLER_STEPS: dict[type, Callable] = {}


def controller_sample(settings, state, scratch, x, ref, dt, diag) -> float:
    """One compiled controller sample, the step chosen by the type of ``settings``
    (compiled code only)."""
    raise TypeError("controller_sample is for compiled code")


@overload(controller_sample, jit_options=JIT)
def _controller_sample(settings, state, scratch, x, ref, dt, diag):
    step = _CONTROLLER_STEPS.get(getattr(settings, "instance_class", None))
    if step is None:
        return None

    def impl(settings, state, scratch, x, ref, dt, diag):
        return step(settings, state, scratch, x, ref, dt, diag)

    return impl


@njit(**JIT)
def _out_of_bounds(x: np.ndarray, u: float, bounds: Bounds) -> bool:
    if not math.isfinite(u):
        return True
    if bounds.control > 0.0 and abs(u) > bounds.control:
        return True
    if bounds.state > 0.0:
        for j in range(x.size):
            # NaN compares False: a non-finite state reaches u first (the runner's rule)
            if abs(x[j]) > bounds.state:
                return True
    return False


@njit(**JIT)
def _analytic_samples(settings, state, scratch, params, s, clock, work,
                      x, diag, buf: Buffers, a: int, b: int, t: np.ndarray, ref: np.ndarray,
                      dist: np.ndarray, dt: float, bounds: Bounds) -> tuple[int, int]:
    """Samples ``a .. b-1``: what :meth:`tspend.runner.ClosedLoop._loop` does per sample."""
    n = x.size
    hidden = s.size - n
    for i in range(a, b):
        for j in range(n):
            x[j] = s[j]
        u = controller_sample(settings, state, scratch, x, ref[i], dt, diag)
        for j in range(n):
            buf.X[i, j] = x[j]
        buf.U[i] = u
        for j in range(diag.size):
            buf.D[i, j] = diag[j]
        for j in range(hidden):
            buf.E[i, j] = s[n + j]
        if _out_of_bounds(x, u, bounds):
            return i, CHECK
        rk4_step(params, clock[0], s, u, dist[i], dt, work)
        clock[0] += dt
    return b, RAN


class CompiledSegment:
    """An analytic plant and a compiled controller in one compiled loop."""

    def __init__(self, compiled_controller: Any, compiled_plant: Any, diag: np.ndarray,
                 buffers: Buffers, bounds: Bounds, order: int) -> None:
        c, p = compiled_controller, compiled_plant
        _CONTROLLER_STEPS.setdefault(type(c.settings), c.step)
        self._args = (c.settings, c.state, c.scratch, p.params, p.state,
                      p.clock, p.work, np.zeros(order), diag, buffers)
        self._bounds = bounds

    def __call__(self, a: int, b: int, t: np.ndarray, ref: np.ndarray, dist: np.ndarray,
                 dt: float) -> tuple[int, int]:
        return _analytic_samples(*self._args, a, b, t, ref, dist, dt, self._bounds)


class SampleFailed(Exception):
    """The plant's step failed at sample ``i`` of the block (recorded): the runner ends the
    run as its generic loop does on the plant's exception ``error``."""

    def __init__(self, i: int, error: BaseException) -> None:
        super().__init__(str(error))
        self.i, self.error = i, error


class MujocoSegment:
    """A MuJoCo plant (its ``state_views()``) with a compiled controller sample, in a tight
    Python loop: the physics is the cost there, and the plant's own ``step`` (its input
    and instability checks) runs unchanged."""

    def __init__(self, controller_step: Callable, diag: np.ndarray, plant: Any, views: Any,
                 buffers: Buffers, bounds: Bounds) -> None:
        self._step, self._diag, self._plant_step = controller_step, diag, plant.step
        self._views, self._buf, self._bounds = views, buffers, bounds

    def __call__(self, a: int, b: int, t: np.ndarray, ref: np.ndarray, dist: np.ndarray,
                 dt: float) -> tuple[int, int]:
        step, diag, plant_step, v = self._step, self._diag, self._plant_step, self._views
        X, U, D, E = self._buf
        qpos, qvel, q_th, v_th, q_cart, v_cart = v
        state_bound, control_bound = self._bounds
        isfinite = math.isfinite
        x = np.empty(2)
        for i in range(a, b):
            x[0] = qpos[q_th]
            x[1] = qvel[v_th]
            u = step(x, ref[i], dt)
            X[i] = x
            U[i] = u
            D[i] = diag
            E[i, 0] = qpos[q_cart]
            E[i, 1] = qvel[v_cart]
            if not isfinite(u) or (control_bound > 0.0 and abs(u) > control_bound) or (
                    state_bound > 0.0 and (abs(x[0]) > state_bound or abs(x[1]) > state_bound)):
                return i, CHECK
            try:
                plant_step(u, dist[i], dt)
            except Exception as exc:
                raise SampleFailed(i, exc) from exc
        return b, RAN


def segment_runner(plant: Any, controller: Any, hook: Any, buffers: Buffers, bounds: Bounds,
                   dt: float) -> Segment | None:
    """A compiled segment for this loop, or None: the generic loop runs (module docstring)."""
    if hook is not None:
        return None
    compiled_controller = getattr(controller, "compiled", None)
    if compiled_controller is None:
        return None
    order = int(controller.order)
    compiled_plant = getattr(plant, "compiled", None)
    if compiled_plant is not None:
        p = compiled_plant()
        if p is not None and buffers.E.shape[1] == p.state.size - order:
            return CompiledSegment(compiled_controller(), p, controller.diag, buffers, bounds,
                                   order)
    state_views = getattr(plant, "state_views", None)
    if state_views is not None and order == 2 and buffers.E.shape[1] == 2:
        return MujocoSegment(controller.step, controller.diag, plant, state_views(), buffers,
                             bounds)
    return None
