"""``gymnasium.make_vec("tspend/<scenario>-v0", num_envs=N, vectorization_mode="vector_entry_point", backend="mjx")``.

The CPU vector env (:class:`tspend.gym.vector.TspendVectorEnv`) with its physics stepped
by MJX: env ``i`` is the machine the scenario's ``[randomize]`` draws at ``seed + i``
(:func:`tspend.mjx.machines.build_fleet`, the CPU plant's own model), each step holds the
action over ``frame_skip`` physics steps and stops an env at the first physics step that
crosses the task's bounds or leaves the finite numbers, all envs in one jitted call.
Everything else is the CPU env's own: the spaces, the action's clipping and scaling, the
reward (:func:`tspend.loop.envstep.reward_of`, the function the CPU env calls, on the
observation the step returns), the statuses and messages (the task's), the truncation at
the scenario's duration and the autoreset (``NEXT_STEP`` or ``SAME_STEP``).  A template
:class:`tspend.gym.TspendEnv` gives the layout, so the two backends cannot drift apart.

The observation of env i is that of the CPU vector env within about 1e-12 after 100 steps
in float64 (tests/test_mjx.py holds it to 1e-9), its rewards within rounding and its
terminations the same.  Not on this backend (refused in one line): ``init_noise``,
``render_mode``, effects that act per sample in Python.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from tspend.runtime.errors import ScenarioError
from tspend.loop import envstep

__all__ = ["MjxVectorEnv"]


class MjxVectorEnv(VectorEnv):
    """N envs of a scenario stepped by MJX (module docstring); the arguments of
    :class:`tspend.gym.vector.TspendVectorEnv` (``threads`` ignored) and ``precision``
    (``"float64"``, ``"float32"``)."""

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, scenario: str | Path = "pendulum_mujoco", num_envs: int = 1, *,
                 seed: int | None = None, render_mode: str | None = None,
                 overrides: dict | None = None, threads: int | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                 precision: str = "float64", **options: Any) -> None:
        import jax.numpy as jnp

        from tspend.gym import TspendEnv
        from tspend.mjx import set_precision
        from tspend.mjx.machines import build_fleet
        from tspend.scenario import load_scenario, override

        if isinstance(num_envs, bool) or not isinstance(num_envs, int) or not 1 <= num_envs <= 1 << 20:
            raise ScenarioError(f"num_envs {num_envs!r}: must be an integer from 1 to {1 << 20}")
        options.pop("max_episode_steps", None)
        if render_mode is not None:
            raise ScenarioError("backend='mjx': no render_mode (render env 0 on the CPU backend)")
        noise = options.get("init_noise", 0.0)
        if np.any(np.asarray(noise, dtype=float) != 0.0):
            raise ScenarioError("backend='mjx': init_noise is not supported (every episode "
                                "starts where a run starts)")
        from tspend.gym import autoreset_mode_of

        mode = autoreset_mode_of(autoreset_mode)
        self.precision = set_precision(precision)
        self._dtype = jnp.float64 if precision == "float64" else jnp.float32
        scn = load_scenario(scenario)
        overrides = dict(overrides or {})
        if overrides:
            scn = override(scn, **overrides)
        base = scn.run.seed if seed is None else int(seed)
        #: the CPU env of env 0: the layout, spaces and reward weights every env shares
        self.template = TspendEnv(scenario, overrides={**overrides, "run.seed": base}, **options)
        first = self.template
        self.fleet = build_fleet(override(scn, **{"run.seed": base}),
                                 [base + i for i in range(num_envs)], steps=first.horizon)
        self.num_envs = num_envs
        self.render_mode = None
        self.autoreset_mode = mode
        self.metadata = {**self.metadata, "render_fps": first.metadata["render_fps"],
                         "autoreset_mode": mode}
        self.single_observation_space = first.observation_space
        self.single_action_space = first.action_space
        self.observation_space = batch_space(first.observation_space, num_envs)
        self.action_space = batch_space(first.action_space, num_envs)
        self.dt, self.frame_skip, self.horizon = first.dt, first.frame_skip, first.horizon
        f = self.fleet
        self._u_lo, self._u_hi = f.u_lo.copy(), f.u_hi.copy()
        if first.normalize:
            self._lo, self._hi = np.full(num_envs, -1.0), np.full(num_envs, 1.0)
        else:
            self._lo, self._hi = self._u_lo, self._u_hi
        self._u_scale = np.where(np.isfinite(self._u_hi) & (self._u_hi > 0), self._u_hi, 1.0)
        self._n_state = len(first.task.names)
        self._ref = f.ref                          # (horizon + 1, n + 1) on the host
        self._step = _make_env_step(f, self.frame_skip, self.horizon, first, self.dt)
        self._model = _device_model(f, self._dtype)
        self._data0 = _initial(f, self._dtype)
        self._data = self._data0
        pad = np.zeros(self.horizon + self.frame_skip)
        pad[:self.horizon] = f.dist
        put = self._put
        #: what every step reads, on the device once
        self._tables = (put(f.d_to_tau), put(f.lo), put(f.hi), put(pad), put(f.ref),
                        put(self._u_scale))
        self._clock = np.zeros(num_envs, dtype=np.int64)
        self._clock_dev = put(self._clock, int)
        size = first.observation_space.shape[0]
        self._obs = np.zeros((num_envs, size))
        self._autoreset = np.zeros(num_envs, dtype=bool)
        #: envs reset on the host (same-step autoreset) whose device data restarts next step
        self._restart = np.zeros(num_envs, dtype=bool)
        self._running = np.full(num_envs, "running", dtype=object)
        self._no_message = np.full(num_envs, "", dtype=object)

    def _put(self, a: Any, dtype: Any = None) -> Any:
        import jax
        import jax.numpy as jnp

        return jax.device_put(jnp.asarray(a, dtype=dtype or self._dtype), jax.devices()[0])

    # -- the gymnasium interface ------------------------------------------------------------
    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        """Every env where a run starts (``seed`` is accepted as the CPU env's: nothing
        here draws from it)."""
        if seed is not None and not isinstance(seed, (int, np.integer)):
            if len(list(seed)) != self.num_envs:
                raise ScenarioError(f"reset seed: {len(list(seed))} seeds for {self.num_envs} envs")
        self._data = self._data0
        self._clock[:] = 0
        self._clock_dev = self._put(self._clock, int)
        self._autoreset[:] = False
        self._restart[:] = False
        self._obs[:] = self._first_obs()
        every = np.ones(self.num_envs, dtype=bool)
        infos = {"t": np.zeros(self.num_envs), "_t": every, "u": np.zeros(self.num_envs),
                 "_u": every, "status": np.full(self.num_envs, "running", dtype=object),
                 "_status": every, "message": np.full(self.num_envs, "", dtype=object),
                 "_message": every}
        return self._out(self._obs), infos

    def step(self, actions):
        """One step of every env in one call on the device (physics, endings, the
        observation, the reward, the autoreset's restart); the host reads back N numbers
        per quantity and names the endings of the envs that ended."""
        import jax

        u = self._applied(actions)
        skip = self._autoreset.copy()               # next-step autoreset: this step resets
        restart = skip | self._restart
        self._restart[:] = False
        out = self._step(self._model, self._data, self._data0, self._put(u),
                         self._clock_dev, self._put(restart, bool), self._put(skip, bool),
                         *self._tables)
        self._data, self._clock_dev = out[0], out[1]
        clock, obs, reward, code, full = jax.device_get(out[1:])
        self._clock = np.asarray(clock, dtype=np.int64)
        code = np.asarray(code)
        # a non-finite state is not observed: the env keeps its last observation (the CPU's)
        seen = (code != envstep.NOT_FINITE) | skip
        self._obs = np.where(seen[:, None], np.asarray(obs, dtype=float), self._obs)
        terminated = (code != envstep.RUNNING) & ~skip
        truncated = (self._clock >= self.horizon) & ~skip & ~terminated
        ended = terminated | truncated
        # copies of ready-made object arrays: no Python object made per env
        status, message = self._running.copy(), self._no_message.copy()
        status[truncated] = "completed"
        for i in np.flatnonzero(terminated):     # the envs that ended now, not every env
            status[i], message[i] = (self.fleet.tasks[i].termination(
                np.asarray(full[i], dtype=float), self._clock[i] * self.dt) or ("diverged", "")) \
                if code[i] == envstep.ENDED else ("diverged", "the state is not finite")
        next_step = self.autoreset_mode == AutoresetMode.NEXT_STEP
        if next_step:
            self._autoreset = ended
        # t before the reset: the clock of an env reset here restarts at 0
        infos = envstep.vector_step_infos(self._clock * self.dt, u, status, message,
                                          terminated, ended, not next_step,
                                          lambda i: self._out(self._obs[i]), self._reset_some)
        return self._out(self._obs), np.asarray(reward, dtype=float), terminated, truncated, infos

    def close_extras(self, **kwargs: Any) -> None:
        self.template.close()

    # -- internals --------------------------------------------------------------------------
    def _first_obs(self) -> np.ndarray:
        f = self.fleet
        full = np.concatenate((f.qpos0, f.qvel0), axis=1)
        return np.concatenate((full, np.broadcast_to(self._ref[0], (self.num_envs,
                                                                      self._ref.shape[1]))), axis=1)

    def _reset_some(self, which: np.ndarray) -> None:
        """Envs ``which`` back where a run starts: their observation now, their data and
        clock on the device at the start of the next step."""
        self._restart |= which
        self._clock[which] = 0
        self._obs[which] = self._first_obs()[which]

    def _applied(self, actions: Any) -> np.ndarray:
        try:
            a = np.asarray(actions, dtype=float)
        except (TypeError, ValueError):
            raise ScenarioError(f"actions {actions!r:.80}: not numbers") from None
        if a.size != self.num_envs or not np.isfinite(a).all():
            raise ScenarioError(f"actions {actions!r:.80}: expected {self.num_envs} finite "
                                f"numbers (the action space is {self.action_space})")
        a = np.minimum(np.maximum(a.reshape(-1), self._lo), self._hi)
        if self.template.normalize:
            a = self._u_lo + 0.5 * (a + 1.0) * (self._u_hi - self._u_lo)
        return np.ascontiguousarray(a)

    def _out(self, obs: np.ndarray) -> np.ndarray:
        return obs.astype(self.single_observation_space.dtype)


def _device_model(fleet: Any, dtype: Any) -> Any:
    from tspend.mjx.sweep import _subset

    return _subset(fleet, np.arange(fleet.n_envs), dtype)


def _initial(fleet: Any, dtype: Any) -> Any:
    from tspend.mjx.sweep import initial_data

    return initial_data(fleet, np.arange(fleet.n_envs), dtype)


def env_substeps(fleet: Any, frame_skip: int, horizon: int) -> Any:
    """One env's physics over a step, as a pure function ``one(model, data, u, clock, skip,
    d_to_tau, lo, hi, dist)``: hold u over ``frame_skip`` physics steps (fewer at the
    episode's end, none when ``skip``), the ending found after the first that crosses the
    bounds ``lo < s < hi`` (ENDED) or is not finite (NOT_FINITE), as
    :func:`tspend.loop.envstep.env_step` does; returns the data, the code, the physics steps
    done and the full state after them.  The data is stepped on past an ending (an ended
    env restarts before its next physics): only the code, the count and the state are held,
    not the whole data at every physics step."""
    import jax
    import jax.numpy as jnp
    from mujoco import mjx

    act, omega, nstep = fleet.actuator, fleet.omega, fleet.nstep
    RUNNING, ENDED, NOT_FINITE = envstep.RUNNING, envstep.ENDED, envstep.NOT_FINITE

    def one(model, data, u, clock, skip, d_to_tau, lo, hi, dist):
        k = jnp.where(skip, 0, jnp.clip(horizon - clock, 0, frame_skip))
        full0 = jnp.concatenate((data.qpos, data.qvel))

        def body(j, carry):
            data, code, done, held = carry
            active = (j < k) & (code == RUNNING)
            d = jax.lax.dynamic_index_in_dim(dist, clock + j, keepdims=False)
            data = data.replace(ctrl=data.ctrl.at[act].set(u),
                                qfrc_applied=data.qfrc_applied.at[omega].set(d_to_tau * d))
            for _ in range(nstep):
                data = mjx.step(model, data)
            full = jnp.concatenate((data.qpos, data.qvel))
            finite = jnp.all(jnp.isfinite(full))
            beyond = jnp.any(full < lo) | jnp.any(full > hi)
            now = jnp.where(~finite, NOT_FINITE, jnp.where(beyond, ENDED, RUNNING))
            return (data, jnp.where(active, now, code), done + active.astype(jnp.int32),
                    jnp.where(active, full, held))

        data, code, done, full = jax.lax.fori_loop(
            0, frame_skip, body, (data, jnp.int32(RUNNING), jnp.int32(0), full0))
        return data, code, done, full

    return one


def _make_env_step(fleet: Any, frame_skip: int, horizon: int, template: Any, dt: float) -> Any:
    """Every env's step in one jitted call: the restart of the envs reset, the physics
    (:func:`env_substeps`), the observation [full state, r .. r^(n) at the new clock] and
    the CPU env's reward (:func:`tspend.loop.envstep.reward_factory`'s text in JAX);
    returns the data, the clock (both stay on the device), the observations, rewards,
    codes and full states."""
    import jax
    import jax.numpy as jnp

    reward_of = envstep.reward_factory(jnp.mod)
    view, tracking = np.asarray(template._view_index), np.asarray(template._tracking)
    wraps, w = np.asarray(template._wrap_flags), template.reward_weights
    alive, control = float(w.alive), float(w.control)
    n_state = len(template.task.names)
    physics = env_substeps(fleet, frame_skip, horizon)

    def one(model, data, data0, u, clock, restart, skip, d_to_tau, lo, hi, dist, ref, u_scale):
        data = jax.tree_util.tree_map(lambda a, b: jnp.where(restart, a, b), data0, data)
        clock = jnp.where(restart, 0, clock)
        data, code, done, full = physics(model, data, u, clock, skip, d_to_tau, lo, hi, dist)
        # a reset step has no physics: the env stays where a run starts
        data = jax.tree_util.tree_map(lambda a, b: jnp.where(skip, a, b), data0, data)
        clock = clock + done
        obs = jnp.concatenate((full, ref[jnp.minimum(clock, horizon)]))
        wrote = ((code == envstep.RUNNING) | (code == envstep.ENDED)) & ~skip
        reward = jnp.where(wrote, reward_of(obs, n_state, view, tracking, wraps, alive,
                                            control, u_scale, u, done * dt), 0.0)
        return data, clock, obs, reward, code, full

    axes = (fleet.in_axes, 0, 0, 0, 0, 0, 0, 0, 0, 0, None, None, 0)
    return jax.jit(jax.vmap(one, in_axes=axes))
