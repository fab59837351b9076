"""How a run or an env step ends, written once and built for numba and for JAX.

Every check here is one text over three names, ``isfinite``, ``where`` (a select of two
values already computed) and ``build`` (how a function is compiled), as
``FullModel.accel_factory(sin, cos, tanh)`` builds the laws and
:func:`tspend.loop.envstep.reward_factory` the reward: :func:`ending_checks` with
``math.isfinite`` and numba's ``njit`` gives the CPU loops' checks (this module's names,
which :mod:`tspend.loop.fastloop` and :mod:`tspend.loop.envstep` call), and with
``jnp.isfinite``, ``jnp.where`` and no build the MJX backend's (:func:`jax_checks`, which
:mod:`tspend.mjx.sweep` and :mod:`tspend.mjx.vector_env` call).  So an ending cannot change
on one backend only.  The texts use no ``if`` on data, no ``not``/``or`` (a JAX value has
no truth) and combine booleans with ``|`` and ``&``; they loop over the state's entries
(a few), which JAX unrolls.

What decides which ending a run had (fell, rail_end, a joint limit: the task's
``termination``; the messages) runs on the host, once per ended run, on the state these
checks stopped at.
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple

from numba import njit

from tspend.runtime.jit import JIT

__all__ = ["BAD_INPUT", "ENDED", "NOT_FINITE", "REFILL", "RUNNING", "UNSTABLE", "Checks",
           "all_finite", "beyond", "ending_checks", "jax_checks", "physics_ending", "refuses_input",
           "sample_ends"]

#: what an env's physics step reports (:mod:`tspend.loop.envstep`): ran; the task's bounds
#: crossed; the state not finite; an input MuJoCo would ignore (not stepped); MuJoCo reset
#: an unstable simulation; nothing done, the step needs the tables' next window
RUNNING, ENDED, NOT_FINITE, BAD_INPUT, UNSTABLE, REFILL = 0, 1, 2, 3, 4, 5


class Checks(NamedTuple):
    """The checks of one backend (:func:`ending_checks`)."""

    #: ``beyond(full, lo, hi)``: any ``full[j]`` outside ``(lo[j], hi[j])`` (NaN: none)
    beyond: Callable
    #: ``all_finite(v)``: every entry finite
    all_finite: Callable
    #: ``sample_ends(x, u, full, lo, hi, state_bound, control_bound)``: whether the runner
    #: looks at this sample (it ends the run)
    sample_ends: Callable
    #: ``physics_ending(full, lo, hi)``: NOT_FINITE, ENDED or RUNNING after a physics step
    physics_ending: Callable
    #: ``refuses_input(u, d, max_input)``: an input MuJoCo would refuse
    refuses_input: Callable


def ending_checks(isfinite: Callable, where: Callable, build: Callable) -> Checks:
    """The endings' one text over ``isfinite``, ``where`` and ``build`` (module docstring)."""

    @build
    def beyond(full, lo, hi):
        out = (full[0] < lo[0]) | (full[0] > hi[0])
        for j in range(1, full.size):
            out = out | (full[j] < lo[j]) | (full[j] > hi[j])
        return out

    @build
    def all_finite(v):
        ok = isfinite(v[0])
        for j in range(1, v.size):
            ok = ok & isfinite(v[j])
        return ok

    @build
    def sample_ends(x, u, full, lo, hi, state_bound, control_bound):
        # u not finite or beyond the control bound, the view beyond the state bound (NaN
        # compares False: a non-finite state reaches u first, the runner's rule), the
        # task's bounds crossed; a bound of 0 checks nothing
        out = where(isfinite(u), False, True)
        out = out | ((control_bound > 0.0) & (abs(u) > control_bound))
        for j in range(x.size):
            out = out | ((state_bound > 0.0) & (abs(x[j]) > state_bound))
        return out | beyond(full, lo, hi)

    @build
    def physics_ending(full, lo, hi):
        # the CPU env's order: a state not finite first, then the task's bounds
        return where(all_finite(full), where(beyond(full, lo, hi), ENDED, RUNNING), NOT_FINITE)

    @build
    def refuses_input(u, d, max_input):
        # MuJoCo's mj_step ignores a control or force at or beyond mjMAXVAL (and NaN)
        return where((abs(u) < max_input) & (abs(d) < max_input), False, True)

    return Checks(beyond, all_finite, sample_ends, physics_ending, refuses_input)


@njit(**JIT)
def _select(condition, if_true, if_false):
    return if_true if condition else if_false


#: the CPU loops' checks, compiled
beyond, all_finite, sample_ends, physics_ending, refuses_input = ending_checks(
    math.isfinite, _select, njit(**JIT))


def jax_checks() -> Checks:
    """The same checks in JAX (traced into the caller's program)."""
    import jax.numpy as jnp

    return ending_checks(jnp.isfinite, jnp.where, lambda fn: fn)

