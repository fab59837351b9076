"""N machines of a scenario stepped in one call: a gymnasium vector env (docs/gym.md).

::

    import gymnasium, tspend.gym
    envs = gymnasium.make_vec("tspend/pendulum_mujoco-v0", num_envs=16,
                              vectorization_mode="vector_entry_point", control_period=0.02)

Env ``i`` is ``TspendEnv(scenario, overrides={..., "run.seed": base + i}, **options)``
(``base``: the ``seed`` option, default the scenario's ``run.seed``): its machine is
the one the scenario's ``[randomize]`` draws at that seed, and its first reset without a
seed uses it.  Each step runs every env's compiled step (:func:`tspend.loop.envstep.
env_steps`, without the GIL), the envs shared out among ``threads`` threads (default:
one per core this process may use), each env on its own mjData: no process per env,
and the observation, reward,
terminated and truncated of env i are those of the single env i, bit for bit
(tests/test_gym_vector.py).  Machines without the compiled step (ODE plants, effects
that act per sample in Python) are stepped one after the other through
:meth:`TspendEnv.step`, with the same results.

Autoreset is gymnasium 1.x's default, next step (``AutoresetMode.NEXT_STEP``): the step
after env i terminated or was truncated resets it (without a seed: its ``np_random``
draws the episode's seed, as the single env does) and returns its first observation,
reward 0, not terminated, not truncated; that step's action for env i is ignored.
``info`` holds ``t`` (s), ``u`` (the command applied) and ``status`` per env (with
gymnasium's ``_t``, ``_u``, ``_status`` masks) and ``message`` for the envs whose
episode ended.  ``render()`` draws env 0.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from tspend.runtime.extras import require

require("gymnasium", "tspend.gym.vector")  # else one line naming the extra

import gymnasium  # noqa: E402
import numpy as np  # noqa: E402
from gymnasium.vector import AutoresetMode, VectorEnv  # noqa: E402
from gymnasium.vector.utils import batch_space  # noqa: E402

from tspend.runtime.errors import ScenarioError
from tspend.gym import TspendEnv, autoreset_mode_of
from tspend.loop import envstep

__all__ = ["TspendVectorEnv"]


class TspendVectorEnv(VectorEnv):
    """``num_envs`` copies of a scenario's env, stepped in one compiled call (module
    docstring).

    Parameters
    ----------
    scenario : str or Path
        A scenario name or a ``.toml`` path, as :class:`tspend.gym.TspendEnv`.
    num_envs : int
        The number of machines (>= 1).
    seed : int, optional
        Env i's machine is drawn, and its first reset seeded, at ``seed + i`` (default:
        the scenario's ``run.seed``).
    render_mode : {None, "rgb_array"}
        ``render()`` returns env 0's frame.
    autoreset_mode : AutoresetMode or str
        ``NEXT_STEP`` (gymnasium's default, module docstring) or ``SAME_STEP``: an env
        whose episode ends is reset in the same step, its last observation and info in
        ``info["final_obs"]``, ``info["final_info"]`` (what stable-baselines3 expects).
    threads : int, optional
        Threads stepping the envs (default: the cores this process may use; 1: the
        caller's thread alone).  Python threads waiting on a condition, not spinning (on
        a machine busy with other work, numba's ``prange``, OpenMP, was measured 4x
        slower than one thread); a step still waits for its slowest share, so on a busy
        machine ``threads=1`` can be faster (docs/benchmarks.md).
    overrides : dict, optional
        Dotted scenario keys to values, as ``TspendEnv``.
    backend : {"cpu", "mjx"}
        ``"mjx"``: the envs' physics stepped by MuJoCo MJX in one jitted call
        (:class:`tspend.mjx.vector_env.MjxVectorEnv`, option ``precision``).
    **options
        The rest of :class:`tspend.gym.TspendEnv`'s options (``control_period``,
        ``frame_skip``, ``reward``, ``init_noise``, ``normalize``, ``width``, ``height``).
    """

    metadata = {"render_modes": ["rgb_array"], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __new__(cls, *args: Any, backend: str = "cpu", **kwargs: Any):
        # backend="mjx": the same envs with MJX physics (tspend.mjx.vector_env, docs/accelerator.md)
        if backend == "mjx":
            from tspend.mjx import require
            from tspend.mjx.vector_env import MjxVectorEnv

            require()
            return MjxVectorEnv(*args, **kwargs)
        if backend != "cpu":
            raise ScenarioError(f"backend {backend!r}: allowed: cpu, mjx")
        return super().__new__(cls)

    def __init__(self, scenario: str | Path = "pendulum_mujoco", num_envs: int = 1, *,
                 seed: int | None = None, render_mode: str | None = None,
                 overrides: dict | None = None, threads: int | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                 backend: str = "cpu", **options: Any) -> None:
        from tspend.scenario import load_scenario, override

        if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
            raise ScenarioError(f"num_envs {num_envs!r}: must be an integer >= 1")
        options.pop("max_episode_steps", None)   # make_vec's; the scenario's duration rules
        mode = autoreset_mode_of(autoreset_mode)
        scn = load_scenario(scenario)
        overrides = dict(overrides or {})
        if overrides:
            scn = override(scn, **overrides)
        base = scn.run.seed if seed is None else int(seed)
        self.envs = [TspendEnv(scenario, overrides={**overrides, "run.seed": base + i},
                               render_mode=render_mode if i == 0 else None, **options)
                     for i in range(num_envs)]
        first = self.envs[0]
        self.num_envs = num_envs
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": first.metadata["render_fps"],
                         "autoreset_mode": mode}
        self.autoreset_mode = mode
        self.single_observation_space = first.observation_space
        self.single_action_space = first.action_space
        self.observation_space = batch_space(first.observation_space, num_envs)
        self.action_space = batch_space(first.action_space, num_envs)
        self.dt, self.frame_skip = first.dt, first.frame_skip

        self._lo = np.array([e._a_lo for e in self.envs])
        self._hi = np.array([e._a_hi for e in self.envs])
        self._u_lo = np.array([e.u_range[0] for e in self.envs])
        self._u_hi = np.array([e.u_range[1] for e in self.envs])
        self._horizon = np.array([e.horizon for e in self.envs], dtype=np.int64)
        size = first.observation_space.shape[0]
        #: every env has the compiled step: one call steps them all
        self.compiled = all(e.frame is not None for e in self.envs)
        self._ints = np.zeros((num_envs, envstep.INT_SLOTS), dtype=np.int64)
        self._floats = np.zeros((num_envs, envstep.FLOAT_SLOTS))
        if self.compiled:
            for i, env in enumerate(self.envs):
                env.adopt_rows(self._ints[i], self._floats[i])
        self._obs = np.zeros((num_envs, size))
        self._code = np.zeros(num_envs, dtype=np.int64)
        self._done = np.zeros(num_envs, dtype=np.int64)
        self._reward = np.zeros(num_envs)
        self._autoreset = np.zeros(num_envs, dtype=bool)
        if threads is None:
            threads = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") \
                else (os.cpu_count() or 1)
        if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
            raise ScenarioError(f"threads {threads!r}: must be an integer >= 1")
        #: each thread's share of the envs: [first, last) (the last share is the caller's)
        self.threads = min(threads, num_envs)
        edges = np.linspace(0, num_envs, self.threads + 1).round().astype(int)
        self._shares = list(zip(edges[:-1].tolist(), edges[1:].tolist()))
        self._pool = ThreadPoolExecutor(self.threads - 1, thread_name_prefix="tspend-env") \
            if self.threads > 1 and self.compiled else None

    # -- the gymnasium interface ------------------------------------------------------------
    def reset(self, *, seed: int | list[int | None] | None = None,
              options: dict | None = None):
        """Reset every env: ``seed`` an int (env i gets ``seed + i``), a list (one per env)
        or None (each env's own rule: :meth:`TspendEnv.reset`)."""
        if seed is None:
            seeds: list[int | None] = [None] * self.num_envs
        elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds = [int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ScenarioError(f"reset seed: {len(seeds)} seeds for {self.num_envs} envs")
        infos: dict[str, Any] = {}
        for i, (env, s) in enumerate(zip(self.envs, seeds)):
            self._obs[i], info = env.reset(seed=s, options=options)
            infos = self._add_info(infos, info, i)
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        return self._out(self._obs), infos

    def step(self, actions):
        """Step every env (resetting those whose episode ended at the last step); the
        batched observation, reward, terminated, truncated and info (module docstring)."""
        u = self._applied(actions)
        reset = self._autoreset
        code, done, reward = self._code, self._done, self._reward
        code.fill(envstep.RUNNING)
        reward.fill(0.0)
        resetting = reset.any()
        if resetting:
            for i in np.flatnonzero(reset):
                self._obs[i], _ = self.envs[i].reset()
        ended_as: dict[int, tuple[str, str]] = {}
        if self.compiled:
            self._compiled_steps(u, reset)
            refill = code == envstep.REFILL
            if refill.any():
                # the envs at the end of their tables' window: the next window, then the step
                for i in np.flatnonzero(refill):
                    self.envs[i].refill()
                code[refill] = envstep.RUNNING
                self._compiled_steps(u, ~refill)
            clock = self._ints[:, envstep.CLOCK]
        else:
            for i in np.flatnonzero(~reset):
                self._obs[i], reward[i], ended, _, info = self.envs[i].step(u[i:i + 1])
                if ended:
                    code[i] = envstep.ENDED
                    ended_as[i] = (info["status"], info["message"])
            clock = np.array([env._ints[envstep.CLOCK] for env in self.envs], dtype=np.int64)
        terminated = code != envstep.RUNNING
        truncated = clock >= self._horizon
        if resetting:
            terminated &= ~reset
            truncated &= ~reset
        truncated &= ~terminated
        ended = terminated | truncated
        status = np.full(self.num_envs, "running", dtype=object)
        message = np.full(self.num_envs, "", dtype=object)
        if ended.any():
            status[truncated] = "completed"
            for i in np.flatnonzero(terminated):
                env = self.envs[i]
                env._u = float(u[i])
                status[i], message[i] = env._status(int(code[i]), int(done[i]), float(u[i])) \
                    if self.compiled else ended_as[i]
        def reset(which: np.ndarray) -> None:
            for i in np.flatnonzero(which):
                self._obs[i], _ = self.envs[i].reset()

        next_step = self.autoreset_mode == AutoresetMode.NEXT_STEP
        if next_step:
            self._autoreset = ended
        infos = envstep.vector_step_infos(clock * self.dt, u, status, message, terminated,
                                          ended, not next_step,
                                          lambda i: self._out(self._obs[i]), reset)
        return self._out(self._obs), reward.copy(), terminated, truncated, infos

    def render(self):
        """Env 0's frame (``render_mode="rgb_array"``)."""
        return self.envs[0].render()

    def close_extras(self, **kwargs: Any) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
        for env in self.envs:
            env.close()

    # -- internals --------------------------------------------------------------------------
    def _compiled_steps(self, u: np.ndarray, skip: np.ndarray) -> None:
        """Every env not skipped, one compiled call per thread's share."""
        args = (self._ints, self._floats, u, skip, self._code, self._done, self._reward,
                self._obs)
        others = [self._pool.submit(envstep.env_steps, *args, a, b)
                  for a, b in self._shares[:-1]] if self._pool is not None else []
        envstep.env_steps(*args, *self._shares[-1])
        for f in others:
            f.result()

    def _applied(self, actions: Any) -> np.ndarray:
        """Each env's command, as :meth:`TspendEnv.applied_action` makes it."""
        try:
            a = np.asarray(actions, dtype=float)
        except (TypeError, ValueError):
            raise ScenarioError(f"actions {actions!r:.80}: not numbers") from None
        if a.size != self.num_envs or not np.isfinite(a.sum()) and not np.isfinite(a).all():
            raise ScenarioError(f"actions {actions!r:.80}: expected {self.num_envs} finite "
                                f"numbers (the action space is {self.action_space})")
        a = np.minimum(np.maximum(a.reshape(-1), self._lo), self._hi)
        if self.envs[0].normalize:
            a = self._u_lo + 0.5 * (a + 1.0) * (self._u_hi - self._u_lo)
        return np.ascontiguousarray(a)

    def _out(self, obs: np.ndarray) -> np.ndarray:
        return obs.astype(self.single_observation_space.dtype)   # a copy either way

