"""A tspend scenario as a functional JAX environment in brax's form (brax's ``Env``).

::

    from tspend.mjx.brax_env import BraxEnv
    env = BraxEnv("pendulum_mujoco", control_period=0.02)
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    state = jax.jit(env.step)(state, jnp.zeros(env.action_size))

``reset(rng)`` and ``step(state, action)`` are pure functions of a pytree state (brax's
``State``: ``pipeline_state`` the MJX data, ``obs``, ``reward``, ``done``, ``info``), so
they jit, vmap and run under brax's trainers (``brax.training.agents.ppo.train``:
examples/train_mjx_ppo.py).  The machine is the one the scenario's ``[randomize]``
draws at ``seed`` (default ``run.seed``), as :class:`tspend.gym.TspendEnv` builds it, or
with ``machines=K`` one of the K machines it draws at ``seed .. seed + K - 1``, picked by
each reset's ``rng`` (default: 256 when the scenario has a ``[randomize]``, so each env of
a vmapped batch trains on its own machine; :func:`tspend.mjx.machines.build_fleet`, the
CPU's machines at those seeds); the
observation is that env's ([full state, r .. r^(n)]), the step holds the action over
``frame_skip`` physics steps and stops where the CPU env stops (an input MuJoCo refuses,
MuJoCo's instability check, a state not finite, the task's bounds:
:func:`tspend.mjx.vector_env.env_substeps`); ``done`` is 1 when the task ended the run,
the step diverged, or the scenario's duration was reached
(``info["truncation"]``).

Actions are in [-1, 1] (what brax's policies output), mapped linearly onto
``[-action_scale, action_scale]`` (default: the actuator's bound) and clipped to the
actuator's range.  The reward is the gym env's, the same text
(:func:`tspend.loop.envstep.reward_factory`) built for JAX: no host call in a step (pass
``reward_fn``, a JAX function of ``(obs, u, seconds)``, to replace it).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable

import numpy as np

from tspend.runtime.errors import ScenarioError
from tspend.loop import envstep

__all__ = ["BraxEnv"]


def _base():
    try:
        from brax.envs.base import Env, State
    except ImportError:
        return object, None
    return Env, State


_Env, _State = _base()


class BraxEnv(_Env):
    """A scenario as brax's functional ``Env`` (module docstring).

    Parameters: ``scenario``, ``seed``, ``control_period`` / ``frame_skip``,
    ``overrides``, ``reward`` as :class:`tspend.gym.TspendEnv`; ``action_scale`` (the
    actuator's unit per unit of action); ``precision`` (``"float64"``, ``"float32"``);
    ``reward_fn`` and ``machines`` (module docstring).
    """

    #: machines a reset picks from at most
    MAX_MACHINES = 1 << 16

    def __init__(self, scenario: str | Path = "pendulum_mujoco", *, seed: int | None = None,
                 control_period: float | None = None, frame_skip: int | None = None,
                 overrides: dict | None = None, reward: Any = None,
                 action_scale: float | None = None, precision: str = "float64",
                 reward_fn: Callable | None = None, machines: int | None = None) -> None:
        import jax.numpy as jnp

        from tspend.gym import TspendEnv
        from tspend.mjx import set_precision
        from tspend.mjx.machines import build_fleet
        from tspend.mjx.sweep import _subset, initial_data
        from tspend.mjx.vector_env import env_substeps
        from tspend.scenario import load_scenario, override

        if _State is None:
            raise ScenarioError("BraxEnv needs brax: pip install brax")
        self.precision = set_precision(precision)
        dtype = jnp.float64 if precision == "float64" else jnp.float32
        self.template = TspendEnv(scenario, seed=seed, control_period=control_period,
                                  frame_skip=frame_skip, overrides=overrides, reward=reward)
        env = self.template
        scn = load_scenario(scenario)
        if overrides:
            scn = override(scn, **dict(overrides))
        first = scn.run.seed if seed is None else int(seed)
        if machines is None:
            machines = 256 if scn.randomize else 1
        if isinstance(machines, bool) or not isinstance(machines, int) or \
                not 1 <= machines <= self.MAX_MACHINES:
            raise ScenarioError(f"machines {machines!r}: an integer from 1 to {self.MAX_MACHINES}")
        fleet = build_fleet(override(scn, **{"run.seed": first}),
                            [first + i for i in range(machines)], steps=env.horizon)
        set_precision(precision)
        self.fleet = fleet
        lo, hi = env.u_range
        if action_scale is None:
            action_scale = hi if math.isfinite(hi) and hi > 0 else math.nan
        if not (isinstance(action_scale, (int, float)) and math.isfinite(action_scale)
                and action_scale > 0):
            raise ScenarioError(f"action_scale {action_scale!r}: a number > 0 (the actuator's "
                                f"range [{lo:g}, {hi:g}] gives none)")
        self.action_scale = float(action_scale)
        self._u_lo, self._u_hi = lo, hi
        self._dtype = dtype
        index = np.arange(machines)
        #: every machine's model (the fields that differ on a leading axis) and start
        self._models = _subset(fleet, index, dtype)
        self._data0 = initial_data(fleet, index, dtype)
        self._one = env_substeps(fleet, env.frame_skip, env.horizon)
        pad = np.zeros(env.horizon + env.frame_skip)
        pad[:env.horizon] = fleet.dist
        self._dist = jnp.asarray(pad, dtype=dtype)
        self._ref = jnp.asarray(fleet.ref, dtype=dtype)
        self._lo, self._hi = jnp.asarray(fleet.lo, dtype=dtype), jnp.asarray(fleet.hi, dtype=dtype)
        self._d_to_tau = jnp.asarray(fleet.d_to_tau, dtype=dtype)
        self._n_state = len(env.task.names)
        self._reward = reward_fn if reward_fn is not None else self._jax_reward()

    def machine(self, i: Any) -> Any:
        """The mjx.Model of machine ``i`` (an int or a traced index)."""
        import jax

        return jax.tree_util.tree_map(lambda x, a: x if a is None else x[i], self._models,
                                      self.fleet.in_axes, is_leaf=lambda x: x is None)

    # -- brax's Env ----------------------------------------------------------------------
    @property
    def observation_size(self) -> int:
        return int(self.template.observation_space.shape[0])

    @property
    def action_size(self) -> int:
        return 1

    @property
    def backend(self) -> str:
        return "mjx"

    def reset(self, rng: Any) -> Any:
        """Where a run starts on a machine ``rng`` picks (``info["machine"]``): its x0 on
        it, as the CPU env's reset without ``init_noise``."""
        import jax
        import jax.numpy as jnp

        i = jax.random.randint(rng, (), 0, self.fleet.n_envs)
        data = jax.tree_util.tree_map(lambda x: x[i], self._data0)
        zero = jnp.zeros((), dtype=self._dtype)
        obs = jnp.concatenate((data.qpos, data.qvel, self._ref[0]))
        info = {"clock": jnp.int32(0), "u": zero, "code": jnp.int32(envstep.RUNNING),
                "truncation": zero, "machine": i}
        return _State(pipeline_state=data, obs=obs, reward=zero, done=zero, metrics={},
                      info=info)

    def step(self, state: Any, action: Any) -> Any:
        import jax.numpy as jnp

        a = jnp.clip(jnp.reshape(action, (-1,))[0], -1.0, 1.0).astype(self._dtype)
        u = jnp.clip(a * self.action_scale, self._u_lo, self._u_hi)
        clock, i = state.info["clock"], state.info["machine"]
        data, code, done, full = self._one(self.machine(i), state.pipeline_state, u, clock,
                                           jnp.bool_(False), self._d_to_tau[i], self._lo[i],
                                           self._hi[i], self._dist)
        clock = clock + done
        wrote = (code == envstep.RUNNING) | (code == envstep.ENDED)
        ref = self._ref[jnp.minimum(clock, self._ref.shape[0] - 1)]
        obs = jnp.where(wrote, jnp.concatenate((full, ref)), state.obs)
        seconds = done.astype(self._dtype) * self.template.dt
        reward = jnp.where(wrote, self._reward(obs, u, seconds), 0.0).astype(self._dtype)
        truncated = (clock >= self.template.horizon) & (code == envstep.RUNNING)
        finished = (code != envstep.RUNNING) | truncated
        info = {**state.info, "clock": clock, "u": u, "code": code,
                "truncation": truncated.astype(self._dtype)}
        return state.replace(pipeline_state=data, obs=obs, reward=reward,
                             done=finished.astype(self._dtype), info=info)

    @property
    def unwrapped(self) -> "BraxEnv":
        return self

    # -- the reward ------------------------------------------------------------------------
    def _jax_reward(self) -> Callable:
        """The gym env's reward (:func:`tspend.loop.envstep.reward_factory`'s text) in JAX."""
        import jax.numpy as jnp

        env = self.template
        w = env.reward_weights
        law = envstep.reward_factory(jnp.mod)
        view, tracking = np.asarray(env._view_index), np.asarray(env._tracking)
        wraps, n_state = np.asarray(env._wrap_flags), self._n_state
        alive, control, u_scale = float(w.alive), float(w.control), float(env.u_scale)

        def reward(obs, u, seconds):
            return law(obs, n_state, view, tracking, wraps, alive, control, u_scale, u, seconds)

        return reward
