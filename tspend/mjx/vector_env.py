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
        self._step = _make_env_step(f, self.frame_skip, self.horizon)
        self._model = _device_model(f, self._dtype)
        self._data0 = _initial(f, self._dtype)
        self._data = self._data0
        pad = np.zeros(self.horizon + self.frame_skip)
        pad[:self.horizon] = f.dist
        self._dist = jnp.asarray(pad, dtype=self._dtype)
        self._d_to_tau = jnp.asarray(f.d_to_tau, dtype=self._dtype)
        self._lo_s = jnp.asarray(f.lo, dtype=self._dtype)
        self._hi_s = jnp.asarray(f.hi, dtype=self._dtype)
        self._clock = np.zeros(num_envs, dtype=np.int64)
        size = first.observation_space.shape[0]
        self._obs = np.zeros((num_envs, size))
        self._autoreset = np.zeros(num_envs, dtype=bool)
        self._u_applied = np.zeros(num_envs)

    # -- the gymnasium interface ------------------------------------------------------------
    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        """Every env where a run starts (``seed`` is accepted as the CPU env's: nothing
        here draws from it)."""
        if seed is not None and not isinstance(seed, (int, np.integer)):
            if len(list(seed)) != self.num_envs:
                raise ScenarioError(f"reset seed: {len(list(seed))} seeds for {self.num_envs} envs")
        self._data = self._data0
        self._clock[:] = 0
        self._autoreset[:] = False
        self._u_applied[:] = 0.0
        self._obs[:] = self._first_obs()
        every = np.ones(self.num_envs, dtype=bool)
        infos = {"t": np.zeros(self.num_envs), "_t": every, "u": np.zeros(self.num_envs),
                 "_u": every, "status": np.full(self.num_envs, "running", dtype=object),
                 "_status": every, "message": np.full(self.num_envs, "", dtype=object),
                 "_message": every}
        return self._out(self._obs), infos

    def step(self, actions):
        import jax.numpy as jnp

        u = self._applied(actions)
        reset = self._autoreset.copy()
        if reset.any():
            self._reset_some(reset)
        data, code, done, full = self._step(
            self._model, self._data, jnp.asarray(u, dtype=self._dtype),
            jnp.asarray(self._clock), jnp.asarray(reset), self._d_to_tau, self._lo_s,
            self._hi_s, self._dist)
        self._data = data
        code = np.asarray(code).astype(np.int64)
        done = np.asarray(done).astype(np.int64)
        full = np.asarray(full, dtype=float)
        self._clock += done
        wrote = (code == envstep.RUNNING) | (code == envstep.ENDED)
        wrote &= ~reset
        first = self.template
        reward = np.zeros(self.num_envs)
        w = first.reward_weights
        for i in np.flatnonzero(wrote):
            self._obs[i, :self._n_state] = full[i]
            self._obs[i, self._n_state:] = self._ref[min(self._clock[i], self.horizon)]
            # the CPU env's reward, the same function on the same observation
            reward[i] = envstep.reward_of(self._obs[i], self._n_state, first._view_index,
                                          first._tracking, first._wrap_flags, float(w.alive),
                                          float(w.control), float(self._u_scale[i]), float(u[i]),
                                          done[i] * self.dt)
        terminated = (code != envstep.RUNNING) & ~reset
        truncated = (self._clock >= self.horizon) & ~reset & ~terminated
        ended = terminated | truncated
        status = np.full(self.num_envs, "running", dtype=object)
        message = np.full(self.num_envs, "", dtype=object)
        status[truncated] = "completed"
        for i in np.flatnonzero(terminated):
            if code[i] == envstep.ENDED:
                status[i], message[i] = self.fleet.tasks[i].termination(
                    full[i], self._clock[i] * self.dt) or ("diverged", "")
            else:
                status[i], message[i] = "diverged", "the state is not finite"
        next_step = self.autoreset_mode == AutoresetMode.NEXT_STEP
        if next_step:
            self._autoreset = ended
        # t before the reset: the clock of an env reset here restarts at 0
        infos = envstep.vector_step_infos(self._clock * self.dt, u, status, message,
                                          terminated, ended, not next_step,
                                          lambda i: self._out(self._obs[i]), self._reset_some)
        return self._out(self._obs), reward, terminated, truncated, infos

    def close_extras(self, **kwargs: Any) -> None:
        self.template.close()

    # -- internals --------------------------------------------------------------------------
    def _first_obs(self) -> np.ndarray:
        f = self.fleet
        full = np.concatenate((f.qpos0, f.qvel0), axis=1)
        return np.concatenate((full, np.broadcast_to(self._ref[0], (self.num_envs,
                                                                      self._ref.shape[1]))), axis=1)

    def _reset_some(self, which: np.ndarray) -> None:
        import jax
        import jax.numpy as jnp

        mask = jnp.asarray(which)

        def pick(fresh, now):
            m = mask.reshape((-1,) + (1,) * (now.ndim - 1))
            return jnp.where(m, fresh, now)

        self._data = jax.tree_util.tree_map(pick, self._data0, self._data)
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
    """One env's step, as a pure function ``one(model, data, u, clock, skip, d_to_tau, lo,
    hi, dist)``: hold u over ``frame_skip`` physics steps (fewer at the episode's end, none
    when ``skip``), stopping after the first that crosses the bounds ``lo < s < hi``
    (ENDED) or is not finite (NOT_FINITE), as :func:`tspend.loop.envstep.env_step` does;
    returns the data, the code, the physics steps done and the full state after them."""
    import jax
    import jax.numpy as jnp
    from mujoco import mjx

    act, omega, nstep = fleet.actuator, fleet.omega, fleet.nstep
    RUNNING, ENDED, NOT_FINITE = envstep.RUNNING, envstep.ENDED, envstep.NOT_FINITE

    def one(model, data, u, clock, skip, d_to_tau, lo, hi, dist):
        k = jnp.where(skip, 0, jnp.clip(horizon - clock, 0, frame_skip))

        def body(j, carry):
            data, code, done = carry
            active = (j < k) & (code == RUNNING)
            d = jax.lax.dynamic_index_in_dim(dist, clock + j, keepdims=False)
            new = data.replace(ctrl=data.ctrl.at[act].set(u),
                               qfrc_applied=data.qfrc_applied.at[omega].set(d_to_tau * d))
            for _ in range(nstep):
                new = mjx.step(model, new)
            full = jnp.concatenate((new.qpos, new.qvel))
            finite = jnp.all(jnp.isfinite(full))
            beyond = jnp.any(full < lo) | jnp.any(full > hi)
            now = jnp.where(~finite, NOT_FINITE, jnp.where(beyond, ENDED, RUNNING))
            data = jax.tree_util.tree_map(lambda a, b: jnp.where(active, a, b), new, data)
            return data, jnp.where(active, now, code), done + active.astype(jnp.int32)

        data, code, done = jax.lax.fori_loop(0, frame_skip, body,
                                             (data, jnp.int32(RUNNING), jnp.int32(0)))
        return data, code, done, jnp.concatenate((data.qpos, data.qvel))

    return one


def _make_env_step(fleet: Any, frame_skip: int, horizon: int) -> Any:
    """:func:`env_substeps` of every env in one jitted call."""
    import jax

    axes = (fleet.in_axes, 0, 0, 0, 0, 0, 0, 0, None)
    return jax.jit(jax.vmap(env_substeps(fleet, frame_skip, horizon), in_axes=axes))
