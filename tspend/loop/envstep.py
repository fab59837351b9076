"""A gymnasium env step in one compiled call, and N of them in one call (docs/gym.md).

:class:`tspend.gym.TspendEnv` holds its action over ``frame_skip`` physics steps, checks
the task's bounds after each one and returns the observation and the reward.  When the
plant is a MuJoCo plant offering ``compiled_mujoco(dt)`` (as the fast loops need,
:mod:`tspend.loop.fastloop`) and nothing runs per sample in Python (no effects wrapper,
no measurement hook), :func:`env_step` does all of that in one ``@njit`` call that calls
MuJoCo's C ``mj_step`` itself, on the plant's own mjModel and mjData: an env step then
costs its physics and one call.  :func:`env_steps` runs it for a share of N envs,
without the GIL, so that a vector env's threads step their shares at once (each env's
mjData is its own: the threads share nothing they write).

Why this route (measured on the 2-core machine, benchmarks/env_speed.py): ``mj_step(m,
d, nstep=k)`` from Python is one call too, but the task's bounds must be checked after
every physics step (a run ends at the first step that crosses them), which it cannot;
``mujoco.rollout`` steps many models on its own threads but restarts each call from a
state vector, so an env would no longer be the same mjData from step to step (MuJoCo's
warm start), and it stops at no bound.

An env is two rows of numbers (:class:`Frame`): int64 slots (MuJoCo's addresses, the
addresses and sizes of the env's arrays, its clock) and float64 slots (dt, the reward's
weights), named by the module's slot constants.  Compiled code gets an env as those two
rows, N envs as two matrices: a call then costs a microsecond whatever the env holds,
where a NamedTuple of ~40 arrays and numbers (the fast loops' way, fine once per run)
costs numba ~20 us per call to type and unbox.

The arithmetic is the Python step's, in the same order (the reward: :func:`reward_of`,
used by both), so the compiled env is equal to the Python one bit for bit
(tests/test_gym_fast.py).  Every physics step reads its disturbance and every sample its
reference from tables computed once per env (the same numbers as computing them per
step, checked there too).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import carray, njit, types
from numba.extending import intrinsic

# the endings' one text (:mod:`tspend.loop.endings`) and its codes
from tspend.loop.endings import (BAD_INPUT, ENDED, NOT_FINITE, REFILL, RUNNING, UNSTABLE,
                                 physics_ending, refuses_input)
from tspend.runtime.jit import JIT

__all__ = ["BAD_INPUT", "ENDED", "NOT_FINITE", "REFILL", "RUNNING", "UNSTABLE", "Frame",
           "env_step", "env_steps", "reward_factory", "reward_of"]

# the int64 slots of a frame: addresses (of mjModel, mjData, arrays) and counts
(STEP_FN, MODEL, DATA, QPOS, NQ, QVEL, NV, CTRL, ACTUATOR, QFRC, OMEGA, WARN_QPOS, WARN_QVEL,
 WARN_QACC, NSTEP, FRAME_SKIP, HORIZON, CLOCK, BASE, WINDOW, REF, NREF, DIST, FULL, NFULL,
 OBS, VIEW, NVIEW, LO, HI, TRACKING, WRAPS) = range(32)
INT_SLOTS = 32
# the float64 slots
DT, MAX_INPUT, D_TO_TAU, ALIVE, CONTROL, U_SCALE = range(6)
FLOAT_SLOTS = 6

#: the package's numba options plus numba's reference counting, which typing ``carray``
#: needs (nothing here allocates)
_JIT = {**JIT, "_nrt": True}


def _pointer_to(nbtype: Any) -> Any:
    @intrinsic
    def pointer(typingctx, address):
        """The int64 ``address`` as a pointer to ``nbtype`` (an array's memory)."""
        sig = types.CPointer(nbtype)(types.int64)

        def codegen(context, builder, signature, args):
            return builder.inttoptr(args[0], context.get_value_type(signature.return_type))

        return sig, codegen

    return pointer


@intrinsic
def _mj_step(typingctx, function, model, data):
    """Call MuJoCo's C ``mj_step(model, data)`` at the address ``function``: a ctypes
    function as an argument costs numba ~6 us per call to type, an address nothing."""
    sig = types.void(types.int64, types.int64, types.int64)

    def codegen(context, builder, signature, args):
        from llvmlite import ir

        pointer = ir.IntType(8).as_pointer()
        kind = ir.FunctionType(ir.VoidType(), [pointer, pointer])
        step = builder.inttoptr(args[0], kind.as_pointer())
        builder.call(step, [builder.inttoptr(args[1], pointer), builder.inttoptr(args[2], pointer)])
        return context.get_dummy_value()

    return sig, codegen


_f64 = _pointer_to(types.float64)
_i64 = _pointer_to(types.int64)
_i32 = _pointer_to(types.int32)


class Frame:
    """One env's two rows (module docstring) and the arrays they point into, kept alive.

    ``link`` is the plant's ``compiled_mujoco(dt)`` (:class:`tspend.plants.mujoco_plant.MujocoLink`),
    ``mj_step`` MuJoCo's C function (:func:`tspend.plants.mujoco_plant.mj_step_pointer`);
    ``ref`` (W + 1, n + 1) and ``dist`` (W,) a window of the tables: r .. r^(n) at the
    times of physics steps ``BASE .. BASE + W``, d at steps ``BASE .. BASE + W - 1``;
    ``full`` the full state (scratch), ``obs`` the observation [full; r .. r^(n)] a step
    writes; the task's ``view_index``, bounds ``lo < s < hi``; the reward's ``tracking``
    weights and ``wraps`` (1 for an angle), ``alive``, ``control``, ``u_scale``.
    """

    def __init__(self, link: Any, mj_step: Any, frame_skip: int, horizon: int, dt: float, ref: np.ndarray,
                 dist: np.ndarray, full: np.ndarray, obs: np.ndarray, view_index: np.ndarray,
                 lo: np.ndarray, hi: np.ndarray, tracking: np.ndarray, wraps: np.ndarray,
                 alive: float, control: float, u_scale: float) -> None:
        own = np.ascontiguousarray
        view_index = own(view_index, np.int64)
        lo, hi, tracking = own(lo, float), own(hi, float), own(tracking, float)
        wraps = own(wraps, np.int64)
        for a in (ref, dist, full, obs):   # written in place: must be C-contiguous floats
            assert a.dtype == np.float64 and a.flags.c_contiguous
        self.keep = (link, ref, dist, obs, view_index, lo, hi, tracking, wraps)
        #: the full state after the last physics step (where the task's bounds were crossed)
        self.full = full
        number = link.warning_number
        at = number.ctypes.data

        ints = np.zeros(INT_SLOTS, dtype=np.int64)
        import ctypes

        ints[STEP_FN] = ctypes.cast(mj_step, ctypes.c_void_p).value
        ints[MODEL], ints[DATA] = link.model_address, link.data_address
        ints[QPOS], ints[NQ] = link.qpos.ctypes.data, link.qpos.size
        ints[QVEL], ints[NV] = link.qvel.ctypes.data, link.qvel.size
        ints[CTRL], ints[ACTUATOR] = link.ctrl.ctypes.data, link.actuator
        ints[QFRC], ints[OMEGA] = link.qfrc.ctypes.data, link.omega
        # MjData's warning counters are a strided view (a struct per warning)
        ints[WARN_QPOS] = at + link.bad_qpos * number.strides[0]
        ints[WARN_QVEL] = at + link.bad_qvel * number.strides[0]
        ints[WARN_QACC] = at + link.bad_qacc * number.strides[0]
        ints[NSTEP], ints[FRAME_SKIP], ints[HORIZON] = link.nstep, frame_skip, horizon
        ints[WINDOW] = dist.size
        ints[REF], ints[NREF], ints[DIST] = ref.ctypes.data, ref.shape[1], dist.ctypes.data
        ints[FULL], ints[NFULL], ints[OBS] = full.ctypes.data, full.size, obs.ctypes.data
        ints[VIEW], ints[NVIEW] = view_index.ctypes.data, view_index.size
        ints[LO], ints[HI] = lo.ctypes.data, hi.ctypes.data
        ints[TRACKING], ints[WRAPS] = tracking.ctypes.data, wraps.ctypes.data
        assert link.qpos.flags.c_contiguous and link.qvel.flags.c_contiguous
        assert full.size == link.qpos.size + link.qvel.size and lo.size == hi.size == full.size
        floats = np.zeros(FLOAT_SLOTS)
        floats[DT], floats[MAX_INPUT], floats[D_TO_TAU] = dt, link.max_input, link.d_to_tau
        floats[ALIVE], floats[CONTROL], floats[U_SCALE] = alive, control, u_scale
        self.ints, self.floats = ints, floats

    def adopt(self, ints: np.ndarray, floats: np.ndarray) -> None:
        """Move the rows into ``ints`` and ``floats`` (a vector env's matrices' rows)."""
        ints[:], floats[:] = self.ints, self.floats
        self.ints, self.floats = ints, floats


def reward_factory(mod: Any) -> Any:
    """The reward's one text, built for numba (``np.mod``: :func:`reward_of`) and for JAX
    (``jnp.mod``: the MJX envs, :mod:`tspend.mjx.vector_env`, :mod:`tspend.mjx.brax_env`),
    as ``FullModel.accel_factory`` builds the laws."""

    def reward(obs: np.ndarray, n_state: int, view_index: np.ndarray, tracking: np.ndarray,
               wraps: np.ndarray, alive: float, control: float, u_scale: float, u: float,
               seconds: float) -> float:
        """``seconds * alive / (1 + c)``, ``c = sum_i tracking_i e_i^2 + control (u /
        u_scale)^2`` with ``e = x_view - r[:n]``, angles wrapped to [-pi, pi) (tspend.gym's
        docstring): the survival reward ``seconds * alive`` less a penalty ``seconds * alive
        * c / (1 + c)`` that never reaches it, so every step survived pays and ending early
        never does."""
        cost = 0.0
        for k in range(view_index.size):
            e = obs[view_index[k]] - obs[n_state + k]
            if wraps[k]:
                e = mod(e + np.pi, 2 * np.pi) - np.pi
            cost += tracking[k] * (e * e)
        s = u / u_scale
        return seconds * alive / (1.0 + cost + control * (s * s))

    return reward


#: the reward of one step, compiled (:func:`reward_factory`)
reward_of = njit(**_JIT)(reward_factory(np.mod))


@njit(**_JIT)
def _read_state(qpos: np.ndarray, qvel: np.ndarray, full: np.ndarray) -> None:
    nq = qpos.size
    for j in range(nq):
        full[j] = qpos[j]
    for j in range(qvel.size):
        full[nq + j] = qvel[j]


@njit(**_JIT)
def env_step(ints: np.ndarray, floats: np.ndarray, u: float) -> tuple[int, int, float]:
    """Hold ``u`` over the env's ``FRAME_SKIP`` physics steps (fewer at the episode's
    end), stopping after the first that crosses the task's bounds or is not finite.

    Returns ``(code, done, reward)``: what happened (module constants), the physics steps
    done, and the step's reward; the clock advanced by ``done``.  The observation is
    written unless the step diverged (NOT_FINITE, BAD_INPUT, UNSTABLE: the last finite
    one stays; reward 0).  REFILL (nothing done) when the step's physics steps are not
    all in the tables' window.
    """
    i0 = ints[CLOCK]
    k = max(min(ints[FRAME_SKIP], ints[HORIZON] - i0), 0)
    at = i0 - ints[BASE]
    window = ints[WINDOW]
    if at < 0 or at + k > window:
        return REFILL, 0, 0.0
    nq, nv, n_state = ints[NQ], ints[NV], ints[NFULL]
    qpos, qvel = carray(_f64(ints[QPOS]), (nq,)), carray(_f64(ints[QVEL]), (nv,))
    ctrl, qfrc = _f64(ints[CTRL]), _f64(ints[QFRC])
    bad = (_i32(ints[WARN_QPOS]), _i32(ints[WARN_QVEL]), _i32(ints[WARN_QACC]))
    dist = carray(_f64(ints[DIST]), (window,))
    full = carray(_f64(ints[FULL]), (n_state,))
    lo, hi = carray(_f64(ints[LO]), (n_state,)), carray(_f64(ints[HI]), (n_state,))
    max_input, d_to_tau = floats[MAX_INPUT], floats[D_TO_TAU]
    actuator, omega, model, data = ints[ACTUATOR], ints[OMEGA], ints[MODEL], ints[DATA]
    step = ints[STEP_FN]
    code, done = RUNNING, 0
    for j in range(k):
        d = dist[at + j]
        if refuses_input(u, d, max_input):
            code = BAD_INPUT
            break
        ctrl[actuator] = u
        qfrc[omega] = d_to_tau * d
        for _ in range(ints[NSTEP]):
            _mj_step(step, model, data)
        if bad[0][0] or bad[1][0] or bad[2][0]:
            code = UNSTABLE
            break
        done += 1
        _read_state(qpos, qvel, full)
        code = physics_ending(full, lo, hi)
        if code != RUNNING:
            break
    ints[CLOCK] = i0 + done
    if code != RUNNING and code != ENDED:
        return code, done, 0.0
    nref = ints[NREF]
    ref = carray(_f64(ints[REF]), (window + 1, nref))
    obs = carray(_f64(ints[OBS]), (n_state + nref,))
    _read_state(qpos, qvel, full)
    for j in range(n_state):
        obs[j] = full[j]
    for j in range(nref):
        obs[n_state + j] = ref[at + done, j]
    nview = ints[NVIEW]
    reward = reward_of(obs, n_state, carray(_i64(ints[VIEW]), (nview,)),
                       carray(_f64(ints[TRACKING]), (nview,)),
                       carray(_i64(ints[WRAPS]), (nview,)), floats[ALIVE], floats[CONTROL],
                       floats[U_SCALE], u, done * floats[DT])
    return code, done, reward


@njit(**_JIT)
def env_steps(ints: np.ndarray, floats: np.ndarray, u: np.ndarray, skip: np.ndarray,
              code: np.ndarray, done: np.ndarray, reward: np.ndarray, obs: np.ndarray,
              first: int, last: int) -> None:
    """:func:`env_step` for the envs ``e`` in ``first .. last - 1`` (rows ``ints[e]``,
    ``floats[e]``) not skipped (``skip[e]``: it is being reset); its results in
    ``code[e]``, ``done[e]``, ``reward[e]`` and ``obs[e]`` (its observation, copied).
    Without the GIL: a vector env's threads each run a share of the envs."""
    for e in range(first, last):
        if skip[e]:
            continue
        row = ints[e]
        c, k, r = env_step(row, floats[e], u[e])
        code[e], done[e], reward[e] = c, k, r
        n = row[NFULL] + row[NREF]
        mine = carray(_f64(row[OBS]), (n,))
        for j in range(n):
            obs[e, j] = mine[j]


def vector_step_infos(t: np.ndarray, u: np.ndarray, status: np.ndarray, message: np.ndarray,
                      terminated: np.ndarray, ended: np.ndarray, reset_now: bool,
                      final_obs_of, reset) -> dict:
    """The infos of one step of a vector env, in gymnasium's layout (each key with its
    ``_key`` mask), for the CPU and the MJX vector envs alike.  ``reset_now`` (every
    autoreset mode but next-step): the ended envs' final observations
    (``final_obs_of(i)``) and infos go into the infos, then ``reset(ended)`` resets them."""
    every = np.ones(len(u), dtype=bool)
    infos = {"t": t, "_t": every, "u": u, "_u": every, "status": status, "_status": every,
             "message": message, "_message": terminated.copy()}
    if reset_now and ended.any():
        final_obs = np.full(len(u), None, dtype=object)
        final_info = np.full(len(u), None, dtype=object)
        for i in np.flatnonzero(ended):
            final_obs[i] = final_obs_of(i)
            final_info[i] = {"t": float(t[i]), "status": status[i], "message": message[i],
                             "u": float(u[i])}
        reset(ended)
        infos.update(final_obs=final_obs, _final_obs=ended, final_info=final_info,
                     _final_info=ended)
    return infos

