"""``gymnasium.make_vec("tspend/<scenario>-v0", num_envs=N, vectorization_mode="vector_entry_point", backend="mjx")``.

The CPU vector env (:class:`tspend.gym.vector.TspendVectorEnv`) with its physics stepped
by MJX: env ``i`` is the machine the scenario's ``[randomize]`` draws at ``seed + i``
(:func:`tspend.mjx.machines.build_fleet`, the CPU plant's own model), each step holds the
action over ``frame_skip`` physics steps and stops an env where the CPU env stops it (an
input MuJoCo refuses, MuJoCo's instability check, a state not finite, the task's bounds:
:mod:`tspend.loop.endings`, the CPU env's text in JAX), all envs in one jitted call that
also makes the observations, the rewards (:func:`tspend.loop.envstep.reward_factory`'s
text), the terminations, the truncations at the scenario's duration and the restart of
the envs that ended (autoreset ``NEXT_STEP`` or ``SAME_STEP``).  Each env's data, clock and
last observation stay on the device between steps: the host sends the actions, reads
back one packed array (observation, reward, termination, truncation, clock and ending
code per env) in one transfer and words the endings of the envs that ended only (the
task's statuses and messages).  A template :class:`tspend.gym.TspendEnv` gives the
spaces, the action's clipping and scaling and the reward's weights, so the two backends
cannot drift apart.

The observation of env i is that of the CPU vector env within about 1e-12 after 100 steps
in float64 (tests/test_mjx.py holds it to 1e-9), its rewards within rounding and its
terminations the same.  Not on this backend (refused in one line): ``init_noise``,
``render_mode``, effects that act per sample in Python.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from tspend.runtime.errors import ScenarioError
from tspend.loop import envstep

__all__ = ["MjxVectorEnv", "flat_io"]


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
        from tspend.gym import autoreset_mode_of
        from tspend.mjx import set_precision

        _check_options(num_envs, render_mode, options)
        mode = autoreset_mode_of(autoreset_mode)
        self.precision = set_precision(precision)
        #: the CPU env of env 0 (the layout, spaces and reward weights every env shares)
        #: and the envs' machines
        self.template, self.fleet = _template_and_fleet(scenario, num_envs, seed, overrides,
                                                        options)
        # again: the fleet's build turns float64 on (its models go to MJX unrounded), and
        # float32 data stepped under it met MJX's float64 RK4 tableau (a scan carry's types
        # then differ)
        set_precision(precision)
        first = self.template
        self.num_envs, self.render_mode, self.autoreset_mode = num_envs, None, mode
        self.metadata = {**self.metadata, "render_fps": first.metadata["render_fps"],
                         "autoreset_mode": mode}
        self.single_observation_space = first.observation_space
        self.single_action_space = first.action_space
        self.observation_space = batch_space(first.observation_space, num_envs)
        self.action_space = batch_space(first.action_space, num_envs)
        self.dt, self.frame_skip, self.horizon = first.dt, first.frame_skip, first.horizon
        f = self.fleet
        self._u_lo, self._u_hi = f.u_lo.copy(), f.u_hi.copy()
        unit = np.ones(num_envs)
        self._lo, self._hi = (-unit, unit) if first.normalize else (self._u_lo, self._u_hi)
        self._u_scale = np.where(np.isfinite(self._u_hi) & (self._u_hi > 0), self._u_hi, 1.0)
        self._u_half_span = 0.5 * (self._u_hi - self._u_lo)
        #: the applied input, written in place each step (no N-sized temporaries)
        self._u = np.empty(num_envs)
        self._u_dtype = np.float64 if precision == "float64" else np.float32
        self._obs_dtype = first.observation_space.dtype
        self._first = _first_obs(f)
        self._device = _DeviceEnvs(f, first, self._u_scale, self._first, precision,
                                   mode == AutoresetMode.NEXT_STEP)
        self._obs = self._first.copy()
        # the statuses and messages a step copies (a copy of an object array takes a
        # reference per element; a gather from labels took ten times as long at 4096 envs)
        self._running = np.full(num_envs, "running", dtype=object)
        self._no_message = np.full(num_envs, "", dtype=object)
        self._running.setflags(write=False)
        self._no_message.setflags(write=False)

    # -- the gymnasium interface ------------------------------------------------------------
    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        """Every env where a run starts (``seed`` is accepted as the CPU env's: nothing
        here draws from it)."""
        if seed is not None and not isinstance(seed, (int, np.integer)):
            if len(list(seed)) != self.num_envs:
                raise ScenarioError(f"reset seed: {len(list(seed))} seeds for {self.num_envs} envs")
        self._device.reset()
        self._obs = self._first.copy()
        every = np.ones(self.num_envs, dtype=bool)
        infos = {"t": np.zeros(self.num_envs), "_t": every, "u": np.zeros(self.num_envs),
                 "_u": every, "status": self._running.copy(), "_status": every,
                 "message": self._no_message.copy(), "_message": every}
        return self._out(self._obs), infos

    def step(self, actions):
        """One step of every env in one call on the device: the restart of the envs ended
        at the last step, the physics, the endings, the observation, the reward, the
        terminations and truncations.  The host sends N actions, reads back one packed
        array, and looks further only at the envs that ended (their status and message,
        by the task's words): nothing of it loops over the envs.  What it returns is the
        caller's own (copies, or read-only views of the step's own packed array), never
        overwritten by a later step;
        at a step where no env ended the infos' status and message are one shared read-only
        array each (a copy of an object array takes a reference per env)."""
        u = self._applied(actions)
        packed = self._device.step(u if self._u_dtype is np.float64 else
                                   u.astype(self._u_dtype))
        obs, (reward, terminated, truncated, clock, code) = self._device.layout.parts(packed)
        self._obs = self._out(obs)
        terminated, truncated = terminated != 0.0, truncated != 0.0
        u = u.copy()          # the infos' own: self._u is rewritten at the next step
        status, message = self._running, self._no_message    # shared, read-only
        if truncated.any() or terminated.any():
            status, message = self._running.copy(), self._no_message.copy()
            status[truncated] = "completed"
        if terminated.any():
            self._name_endings(terminated, clock, u, status, message, code, obs)
        # t before the reset: the clock of an env reset here restarts at 0
        t = np.multiply(clock, self.dt, dtype=float)
        infos = envstep.vector_step_infos(t, u, status, message, terminated,
                                          terminated | truncated,
                                          self.autoreset_mode != AutoresetMode.NEXT_STEP,
                                          lambda i: self._obs[i].copy(), self._reset_some)
        # the rewards (float64) and the clock (whole steps, exact in the float type) are
        # read where they lie: ``packed`` is this step's own buffer, never written again
        return self._obs, reward.astype(float, copy=False), terminated, truncated, infos

    def close_extras(self, **kwargs: Any) -> None:
        self.template.close()

    # -- internals --------------------------------------------------------------------------
    def _name_endings(self, terminated: np.ndarray, clock: np.ndarray, u: np.ndarray,
                      status: np.ndarray, message: np.ndarray, code: np.ndarray,
                      obs: np.ndarray) -> None:
        """The status and message of each env that ended now, as the CPU env words them
        (from the step's ending codes, and for a task's ending the full state it stopped
        at: the first columns of ``obs``, the packed observations in the data's float
        type)."""
        from tspend.mjx.sweep import plant_error

        which = np.flatnonzero(terminated)
        full = obs[which, :self._device.layout.n_full]
        for i, c, s in zip(which, code[which].astype(np.int64), full):
            t = float(clock[i]) * self.dt
            if c == envstep.ENDED:
                status[i], message[i] = (self.fleet.tasks[i].termination(
                    np.asarray(s, dtype=float), t) or ("diverged", ""))
            elif c == envstep.NOT_FINITE:
                status[i], message[i] = "diverged", "the state is not finite"
            else:     # BAD_INPUT, UNSTABLE: the plant's own words
                d = float(self._device.dist[min(int(clock[i]), self.horizon - 1)])
                error = plant_error(self.fleet, c == envstep.BAD_INPUT, float(u[i]), d, t)
                status[i], message[i] = "diverged", f"the plant failed ({error})"

    def _reset_some(self, which: np.ndarray) -> None:
        """Envs ``which`` (ended at this step) where a run starts: their observation now;
        their data and clock restart on the device at the next step."""
        self._obs[which] = self._first[which]

    def _applied(self, actions: Any) -> np.ndarray:
        try:
            a = np.asarray(actions, dtype=float)
        except (TypeError, ValueError):
            raise ScenarioError(f"actions {actions!r:.80}: not numbers") from None
        if a.size != self.num_envs or not np.isfinite(a).all():
            raise ScenarioError(f"actions {actions!r:.80}: expected {self.num_envs} finite "
                                f"numbers (the action space is {self.action_space})")
        u = self._u
        np.clip(a.reshape(-1), self._lo, self._hi, out=u)
        if self.template.normalize:     # u_lo + (a + 1) (u_hi - u_lo) / 2, in place
            u += 1.0
            u *= self._u_half_span
            u += self._u_lo
        return u

    def _out(self, obs: np.ndarray) -> np.ndarray:
        return obs.astype(self._obs_dtype)


def _check_options(num_envs: Any, render_mode: Any, options: dict) -> None:
    """ScenarioError (one line) for what this backend cannot do; drops the CPU env's
    ``max_episode_steps`` (the horizon is the scenario's)."""
    if isinstance(num_envs, bool) or not isinstance(num_envs, int) or not 1 <= num_envs <= 1 << 20:
        raise ScenarioError(f"num_envs {num_envs!r}: must be an integer from 1 to {1 << 20}")
    options.pop("max_episode_steps", None)
    if render_mode is not None:
        raise ScenarioError("backend='mjx': no render_mode (render env 0 on the CPU backend)")
    noise = options.get("init_noise", 0.0)
    if np.any(np.asarray(noise, dtype=float) != 0.0):
        raise ScenarioError("backend='mjx': init_noise is not supported (every episode "
                            "starts where a run starts)")


def _template_and_fleet(scenario: Any, num_envs: int, seed: int | None, overrides: dict | None,
                        options: dict) -> tuple[Any, Any]:
    """The CPU env at the first seed (the layout every env shares) and the machines of
    seeds ``seed .. seed + num_envs - 1`` (the scenario's run.seed when ``seed`` is None)."""
    from tspend.gym import TspendEnv
    from tspend.mjx.machines import build_fleet
    from tspend.scenario import load_scenario, override

    scn = load_scenario(scenario)
    overrides = dict(overrides or {})
    if overrides:
        scn = override(scn, **overrides)
    base = scn.run.seed if seed is None else int(seed)
    template = TspendEnv(scenario, overrides={**overrides, "run.seed": base}, **options)
    fleet = build_fleet(override(scn, **{"run.seed": base}),
                        [base + i for i in range(num_envs)], steps=template.horizon)
    return template, fleet


def _first_obs(fleet: Any) -> np.ndarray:
    """Every env's observation where a run starts: [its reset state, r .. r^(n) at 0]."""
    full = np.concatenate((fleet.qpos0, fleet.qvel0), axis=1)
    ref0 = np.broadcast_to(fleet.ref[0], (full.shape[0], fleet.ref.shape[1]))
    return np.concatenate((full, ref0), axis=1)


class _Layout(NamedTuple):
    """Where each quantity lies in the step's packed array, one flat buffer: the
    observations (n_envs x n_obs, row-major), then a row of n_envs for each of reward,
    termination, truncation, clock and ending code, so that what the host copies out is
    contiguous (a strided copy of the observations took ten times a contiguous one at
    4096 envs)."""

    n_envs: int
    n_obs: int
    #: the full state (positions, velocities) is the observation's first n_full columns
    n_full: int

    def parts(self, packed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Views of ``packed``: the observations and the five rows (reward, terminated,
        truncated, clock, code)."""
        split = self.n_envs * self.n_obs
        return (packed[:split].reshape(self.n_envs, self.n_obs),
                packed[split:].reshape(5, self.n_envs))


class _DeviceEnvs:
    """What the envs keep on the device between steps (each env's MJX data, clock, last
    observation and whether it restarts at the next step) and the one jitted call that
    steps them (:func:`_make_env_step`); the host sends the actions and reads back one
    packed array (:class:`_Layout`)."""

    def __init__(self, fleet: Any, template: Any, u_scale: np.ndarray, first_obs: np.ndarray,
                 precision: str, next_step: bool) -> None:
        import jax
        import jax.numpy as jnp

        self.dtype = jnp.float64 if precision == "float64" else jnp.float32
        self.device = jax.devices()[0]
        horizon, frame_skip = template.horizon, template.frame_skip
        self.dist = np.asarray(fleet.dist, dtype=float)
        pad = np.zeros(horizon + frame_skip)
        pad[:horizon] = fleet.dist
        # the clock travels in the packed array's float type: exact below 2^24 in float32
        if self.dtype == jnp.float32 and horizon >= 1 << 24:
            raise ScenarioError(f"precision float32: {horizon} steps in an episode, at most "
                                f"{(1 << 24) - 1} (float64 has no such bound)")
        self.layout = _Layout(*first_obs.shape, fleet.qpos0.shape[1] + fleet.qvel0.shape[1])
        put = self.put
        # the model and data travel as a few flat buffers (one per dtype): flattening an
        # MJX dataclass in Python took about 0.6 ms per model on every call, and each of
        # the 290 arrays of a flat list cost the call's dispatch some microseconds more
        model, data0 = _device_model(fleet, self.dtype), _initial(fleet, self.dtype)
        model_leaves, model_tree = jax.tree_util.tree_flatten(model)
        data_leaves, data_tree = jax.tree_util.tree_flatten(data0)
        model_buffers, data_buffers = Buffers(model_leaves), Buffers(data_leaves)
        self.model = model_buffers.pack(model_leaves, self.device)
        self.data0 = data_buffers.pack(data_leaves, self.device)
        self.first_obs = put(first_obs)
        #: what every step reads
        self.tables = (put(fleet.d_to_tau), put(fleet.lo), put(fleet.hi), put(pad),
                       put(fleet.ref), put(u_scale))
        #: each flat buffer's tree structure and layout (:class:`Buffers`), model then data
        self.trees = ((model_tree, model_buffers), (data_tree, data_buffers))
        self.call = _make_env_step(fleet, frame_skip, horizon, template, template.dt, next_step,
                                   self.trees)
        self._config, self._x64 = jax.config, precision == "float64"
        self._precision = precision
        self.reset()

    def put(self, a: Any, dtype: Any = None) -> Any:
        import jax
        import jax.numpy as jnp

        return jax.device_put(jnp.asarray(a, dtype=dtype or self.dtype), self.device)

    def reset(self) -> None:
        import jax
        import jax.numpy as jnp

        n = self.first_obs.shape[0]
        # copies: the step takes over (donates) the buffers of what it replaces
        self.data = tuple(jnp.copy(a) for a in self.data0)
        self.obs = jnp.copy(self.first_obs)
        self.clock = self.put(np.zeros(n, dtype=np.int64), int)
        self.pending = self.put(np.zeros(n, dtype=bool), bool)

    def step(self, u: np.ndarray) -> np.ndarray:
        """The packed array of one step (:class:`_Layout`), on the host, read-only."""
        # JAX's float width is per process, and the call compiles at its first use: an
        # object built since with the other precision has changed it
        if self._config.jax_enable_x64 != self._x64:
            from tspend.mjx import set_precision

            set_precision(self._precision)
        # u as numpy: the jitted call's own argument handling puts it on the device,
        # cheaper than a device_put before it
        self.data, self.clock, self.obs, self.pending, packed = self.call(
            self.model, self.data, self.data0, self.obs, self.first_obs, u, self.clock,
            self.pending, *self.tables)
        return np.asarray(packed)     # one transfer


class Buffers:
    """Where each of a list of arrays lies in one flat buffer per dtype: a jitted call then
    takes a few arguments, not one per array.  :meth:`pack` and :meth:`unpack` trace
    under ``jax.jit`` (slices and reshapes there, no copy the compiler keeps)."""

    def __init__(self, leaves: list) -> None:
        self.dtypes = sorted({np.dtype(a.dtype) for a in leaves}, key=str)
        ends = [0] * len(self.dtypes)
        self.where: list[tuple[int, int, tuple[int, ...]]] = []    # (buffer, start, shape)
        for a in leaves:
            group = self.dtypes.index(np.dtype(a.dtype))
            self.where.append((group, ends[group], tuple(a.shape)))
            ends[group] += int(np.prod(a.shape, dtype=np.int64))

    def pack(self, leaves: list, device: Any = None) -> tuple:
        """The buffers of ``leaves`` (laid out as at construction), on ``device`` if given."""
        import jax
        import jax.numpy as jnp

        parts: list[list] = [[] for _ in self.dtypes]
        for a, (group, _, _) in zip(leaves, self.where):
            parts[group].append(jnp.ravel(jnp.asarray(a, dtype=self.dtypes[group])))
        buffers = tuple(jnp.concatenate(p) for p in parts)
        return buffers if device is None else tuple(jax.device_put(b, device) for b in buffers)

    def unpack(self, buffers: tuple) -> list:
        return [buffers[group][start:start + int(np.prod(shape, dtype=np.int64))].reshape(shape)
                for group, start, shape in self.where]


def flat_io(trees: tuple) -> tuple[Any, Any, Any]:
    """The way a jitted call over flat buffers goes in and out, from ``trees`` (each of the
    model's and the data's tree structure and :class:`Buffers`): the model from its
    buffers, the data from its buffers, and the data's buffers from the data."""
    (model_tree, model_buffers), (data_tree, data_buffers) = trees
    return (lambda buffers: model_tree.unflatten(model_buffers.unpack(buffers)),
            lambda buffers: data_tree.unflatten(data_buffers.unpack(buffers)),
            lambda data: data_buffers.pack(data_tree.flatten_up_to(data)))


def _device_model(fleet: Any, dtype: Any) -> Any:
    from tspend.mjx.sweep import _subset

    return _subset(fleet, np.arange(fleet.n_envs), dtype)


def _initial(fleet: Any, dtype: Any) -> Any:
    from tspend.mjx.sweep import initial_data

    return initial_data(fleet, np.arange(fleet.n_envs), dtype)


def env_substeps(fleet: Any, frame_skip: int, horizon: int) -> Any:
    """One env's physics over a step, as a pure function ``one(model, data, u, clock, skip,
    d_to_tau, lo, hi, dist)``: hold u over ``frame_skip`` physics steps (fewer at the
    episode's end, none when ``skip``), stopping at the first input MuJoCo refuses
    (BAD_INPUT, not stepped), the first step MuJoCo finds unstable (UNSTABLE) or the first
    that leaves the finite numbers (NOT_FINITE) or crosses the bounds ``lo < s < hi``
    (ENDED), as :func:`tspend.loop.envstep.env_step` does, by the same text
    (:mod:`tspend.loop.endings`); returns the data, the code, the physics steps done and
    the full state after them.  The data is stepped on past an ending (an ended env
    restarts before its next physics): only the code, the count and the state are held,
    not the whole data at every physics step."""
    import jax
    import jax.numpy as jnp
    from mujoco import mjx

    from tspend.loop.endings import jax_checks
    from tspend.mjx.sweep import mujoco_steps

    act, omega, nstep, max_input = fleet.actuator, fleet.omega, fleet.nstep, fleet.max_input
    RUNNING, BAD_INPUT, UNSTABLE = envstep.RUNNING, envstep.BAD_INPUT, envstep.UNSTABLE
    checks = jax_checks()

    def one(model, data, u, clock, skip, d_to_tau, lo, hi, dist):
        k = jnp.where(skip, 0, jnp.clip(horizon - clock, 0, frame_skip))
        full0 = jnp.concatenate((data.qpos, data.qvel))

        def body(j, carry):
            data, code, done, held = carry
            active = (j < k) & (code == RUNNING)
            d = jax.lax.dynamic_index_in_dim(dist, clock + j, keepdims=False)
            refused = checks.refuses_input(u, d, max_input)
            data = data.replace(ctrl=data.ctrl.at[act].set(u),
                                qfrc_applied=data.qfrc_applied.at[omega].set(d_to_tau * d))
            data, unstable = mujoco_steps(mjx, model, data, nstep, max_input)
            full = jnp.concatenate((data.qpos, data.qvel))
            now = jnp.where(refused, BAD_INPUT, jnp.where(unstable, UNSTABLE,
                                                          checks.physics_ending(full, lo, hi)))
            # a refused or unstable step is not done (the CPU env's count)
            did = active & (now != BAD_INPUT) & (now != UNSTABLE)
            return (data, jnp.where(active, now, code), done + did.astype(jnp.int32),
                    jnp.where(did, full, held))

        data, code, done, full = jax.lax.fori_loop(
            0, frame_skip, body, (data, jnp.int32(RUNNING), jnp.int32(0), full0))
        return data, code, done, full

    return one


def _make_env_step(fleet: Any, frame_skip: int, horizon: int, template: Any, dt: float,
                   next_step: bool, trees: tuple) -> Any:
    """Every env's step in one jitted call: the restart of the envs that ended at the last
    step (``pending``; with ``next_step`` autoreset that step is the reset, with no
    physics), the physics (:func:`env_substeps`), the observation [full state, r .. r^(n)
    at the new clock] (the last one kept where the step diverged, as the CPU env keeps
    it), the CPU env's reward (:func:`tspend.loop.envstep.reward_factory`'s text in JAX),
    the terminations and truncations.  Returns what stays on the device (data, clock,
    observation, pending) and one packed array for the host, laid out as :class:`_Layout`
    says (one output buffer, one transfer).  The full state a task's
    ending stopped at is the observation's first columns (the observation is written at
    an ``ENDED`` step, in the data's own float type).  The model and the data come and go
    as flat buffers (``trees``: each one's tree structure and :class:`Buffers`)."""
    import jax
    import jax.numpy as jnp

    reward_of = envstep.reward_factory(jnp.mod)
    view, tracking = np.asarray(template._view_index), np.asarray(template._tracking)
    wraps, w = np.asarray(template._wrap_flags), template.reward_weights
    alive, control = float(w.alive), float(w.control)
    n_state = len(template.task.names)
    physics = env_substeps(fleet, frame_skip, horizon)
    RUNNING, ENDED = envstep.RUNNING, envstep.ENDED

    def one(model, data, data0, obs, obs0, u, clock, pending, d_to_tau, lo, hi, dist, ref,
            u_scale):
        skip = pending if next_step else jnp.zeros((), dtype=bool)
        data = jax.tree_util.tree_map(lambda a, b: jnp.where(pending, a, b), data0, data)
        clock, obs = jnp.where(pending, 0, clock), jnp.where(pending, obs0, obs)
        data, code, done, full = physics(model, data, u, clock, skip, d_to_tau, lo, hi, dist)
        # a reset step has no physics: the env stays where a run starts
        data = jax.tree_util.tree_map(lambda a, b: jnp.where(skip, a, b), data0, data)
        clock = clock + done
        wrote = ((code == RUNNING) | (code == ENDED)) & ~skip
        new = jnp.concatenate((full, ref[jnp.minimum(clock, horizon)])).astype(obs.dtype)
        obs = jnp.where(wrote | skip, new, obs)
        reward = jnp.where(wrote, reward_of(new, n_state, view, tracking, wraps, alive,
                                            control, u_scale, u, done * dt), 0.0)
        terminated = (code != RUNNING) & ~skip
        truncated = (clock >= horizon) & ~skip & ~terminated
        rows = jnp.stack((reward, terminated, truncated, clock, code)).astype(obs.dtype)
        return data, clock, obs, terminated | truncated, rows

    axes = (fleet.in_axes, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, None, None, 0)
    every = jax.vmap(one, in_axes=axes)
    model_of, data_of, buffers_of = flat_io(trees)

    def flat(model, data, data0, *rest):
        data, clock, obs, pending, rows = every(model_of(model), data_of(data), data_of(data0),
                                                *rest)
        packed = jnp.concatenate((obs.reshape(-1), rows.T.reshape(-1)))
        return buffers_of(data), clock, obs, pending, packed

    # the data, observation, clock and restart flags a step replaces are donated: their
    # buffers are reused, not freed and taken anew each step (on the CPU the free alone
    # grew with the number of envs)
    return jax.jit(flat, donate_argnums=(1, 3, 6, 7))
