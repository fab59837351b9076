"""tspend's scenarios as gymnasium environments (docs/gym.md).

``import tspend.gym`` registers every scenario in the project's ``scenarios/`` (and in
``./scenarios``) as ``tspend/<scenario>-v0``::

    import gymnasium, tspend.gym
    env = gymnasium.make("tspend/pendulum_mujoco-v0", control_period=0.02)

:class:`TspendEnv` is a thin layer on the machinery a run uses
(:mod:`tspend.loop.simulation`): the scenario's plant with its real-world effects
(``build_plant``), its task (view, reference, termination bounds: :mod:`tspend.task`),
its disturbance and its measurement effects (:class:`tspend.loop.effects.Measurement`).
Nothing here integrates anything: each env step holds the action (zero-order hold) over
``frame_skip`` physics steps of ``run.dt``, exactly as the runner's sampled loop does; on
a MuJoCo plant without per-sample effects in one compiled call
(:mod:`tspend.loop.envstep`), otherwise through ``plant.step(u, d, run.dt)``.  N envs in
one call: :mod:`tspend.gym.vector`.

Observation (:attr:`TspendEnv.observation_names`, :attr:`TspendEnv.observation_units`):
the plant's full named state (positions, then velocities, the task's view entries as the
controller measures them) followed by the reference and its derivatives
``r, r', .., r^(n)`` at the sample time (n: the task view's length).  Action: the
actuator's force (or torque, voltage), a Box with the actuator's bounds (tightened by
``effects.saturation``).  Reward per step, over the step's duration ``T``::

    c = sum_i tracking_i * e_i**2 + control * (u / u_scale)**2
    reward = T * alive / (1 + c)  =  T * alive - T * alive * c / (1 + c)

with ``e = x_view - r[:n]`` (angles of revolute joints wrapped to (-pi, pi]) at the end
of the step, ``u_scale`` the actuator's bound (1 when unbounded); :class:`RewardWeights`
holds the defaults.  The survival reward ``T * alive`` outweighs the tracking and effort
penalty, which stays below it however large ``c``: every step survived pays, so ending an
episode early never does (as gymnasium's pendulums pay for every step alive).  An episode terminates when the task ends the run (``fell``,
``rail_end``, ``joint_limit``, ``state_bound``; ``diverged`` for a non-finite state or a
plant failure: ``info["status"]``) and is truncated at the scenario's ``run.duration``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tspend.runtime.extras import require

require("gymnasium", "tspend.gym")  # else one line naming the extra, not a bare ModuleNotFoundError

import gymnasium  # noqa: E402
import numpy as np  # noqa: E402
from gymnasium import spaces  # noqa: E402

from tspend.config.tables import shown_key
from tspend.controllers.base import Observation
from tspend.loop import envstep
from tspend.runtime.errors import DivergenceError, ScenarioError, TspendError

__all__ = ["ENV_PREFIX", "RenderError", "RewardWeights", "TspendEnv", "autoreset_mode_of",
           "env_id", "register_all"]

#: the namespace of the registered ids: ``tspend/<scenario>-v0``
ENV_PREFIX = "tspend"


class RenderError(TspendError):
    """No frame can be drawn: no GL backend (set MUJOCO_GL=egl or osmesa), or a plant
    without a MuJoCo model."""

    exit_status = 2


@dataclass(frozen=True)
class RewardWeights:
    """The reward's weights (module docstring).

    ``alive`` > 0: the most a second survived earns (every step survived pays, so that
    ending early never pays); ``tracking`` >= 0: weights on the squared errors of the view's
    entries, the output then its derivatives (the output's unit^-2, ...); entries past the
    view's length are ignored, missing ones are 0; ``control`` >= 0: weight on
    ``(u / u_scale)**2``.  The penalty of a step is ``alive * c / (1 + c)`` for ``c`` the
    weighted sum (module docstring).
    """

    alive: float = 1.0
    tracking: tuple[float, ...] = (100.0, 1.0, 0.0)
    control: float = 1.0

    def __post_init__(self) -> None:
        def number(name: str, v: Any) -> float:
            try:
                f = float(v)
            except (TypeError, ValueError):
                raise ScenarioError(f"reward.{name}: a number, got {v!r:.40}") from None
            if not math.isfinite(f):
                raise ScenarioError(f"reward.{name}: must be finite, got {v!r:.40}")
            return f

        if not number("alive", self.alive) > 0.0:
            raise ScenarioError(f"reward.alive: must be > 0 (the reward of a step survived), "
                                f"got {self.alive!r:.40}")
        if number("control", self.control) < 0.0:
            raise ScenarioError(f"reward.control: must be >= 0, got {self.control!r:.40}")
        tracking = tuple(self.tracking) if isinstance(self.tracking, (list, tuple)) else None
        if tracking is None or len(tracking) > 16:
            raise ScenarioError(f"reward.tracking: a list of up to 16 weights, got "
                                f"{self.tracking!r:.40}")
        if any(number("tracking", w) < 0.0 for w in tracking):
            raise ScenarioError(f"reward.tracking: every weight must be >= 0, got "
                                f"{self.tracking!r:.40}")
        object.__setattr__(self, "tracking", tuple(float(w) for w in tracking))


def env_id(scenario: str) -> str:
    """The registered id of a scenario: ``tspend/<scenario>-v0``."""
    return f"{ENV_PREFIX}/{scenario}-v0"


def reward_weights(reward: Any) -> RewardWeights:
    """``reward`` (RewardWeights, a dict of its fields, or None: the defaults) as weights;
    ScenarioError naming what is wrong."""
    if not isinstance(reward, (RewardWeights, dict, type(None))):
        raise ScenarioError(f"reward: a RewardWeights or a dict, got {type(reward).__name__}")
    unknown = sorted(set(reward or {}) - set(RewardWeights.__dataclass_fields__)) \
        if isinstance(reward, dict) else []
    if unknown:
        raise ScenarioError(f"reward: unknown key(s) {', '.join(shown_key(str(k)) for k in unknown)}; allowed: "
                            f"{', '.join(RewardWeights.__dataclass_fields__)}")
    return reward if isinstance(reward, RewardWeights) else RewardWeights(**dict(reward or {}))


def initial_noise(init_noise: Any, size: int) -> np.ndarray:
    """``init_noise`` as one bound per entry of plant.x0 (one number for all, or ``size``);
    ScenarioError for anything else or a negative or non-finite bound."""
    noise = np.broadcast_to(np.asarray(init_noise, dtype=float), (size,)) \
        if np.ndim(init_noise) == 0 or np.size(init_noise) == size else None
    if noise is None or not np.all(np.isfinite(noise)) or np.any(noise < 0):
        raise ScenarioError(f"init_noise {init_noise!r}: one number >= 0 or {size} "
                            f"(plant.x0's length)")
    return np.array(noise, dtype=float)


class TspendEnv(gymnasium.Env):
    """A tspend scenario as a gymnasium environment (module docstring; docs/gym.md).

    Parameters
    ----------
    scenario : str or Path
        A scenario name (``tspend list``) or a path to a ``.toml`` file.
    seed : int, optional
        The seed of the first :meth:`reset` when that call gives none (default: the
        scenario's ``run.seed``).
    control_period : float, optional
        Seconds per env step (the action is held over it); a whole multiple of ``run.dt``.
        Default: the scenario's ``run.control_period``, else ``run.dt``.
    frame_skip : int, optional
        Physics steps (of ``run.dt``) per env step; an alternative to ``control_period``.
    render_mode : {None, "rgb_array"}
        ``"rgb_array"``: :meth:`render` returns an (height, width, 3) uint8 frame drawn by
        ``mujoco.Renderer`` (needs a GL backend: MUJOCO_GL=egl or osmesa).
    overrides : dict, optional
        Dotted scenario keys to values (``{"run.duration": 5.0}``), as ``tspend.run``.
    reward : RewardWeights or dict, optional
        The reward's weights (:class:`RewardWeights`).
    init_noise : float or sequence of float
        Each reset adds ``uniform(-init_noise, init_noise)`` (drawn from the env's
        ``np_random``) to the scenario's ``plant.x0`` (the view's initial state); 0, the
        default, starts every episode where a run starts.
    width, height : int
        The rendered frame's size (pixels).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}
    #: physics steps the reference and disturbance tables hold at least (a window of them)
    table_window = 4096

    def __init__(self, scenario: str | Path = "pendulum_mujoco", *, seed: int | None = None,
                 control_period: float | None = None, frame_skip: int | None = None,
                 render_mode: str | None = None, overrides: dict | None = None,
                 reward: RewardWeights | dict | None = None,
                 init_noise: float | tuple[float, ...] = 0.0,
                 width: int = 640, height: int = 480, normalize: bool = False) -> None:
        from tspend.loop import simulation
        from tspend.plants import randomize
        from tspend.scenario import load_scenario, override

        scn = load_scenario(scenario)
        if overrides:
            scn = override(scn, **dict(overrides))
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ScenarioError(f"render_mode {render_mode!r}: allowed: "
                                f"{', '.join(self.metadata['render_modes'])} or None")
        self.scenario = scn
        self.render_mode = render_mode
        self.width, self.height = int(width), int(height)
        self.reward_weights = reward_weights(reward)
        self._first_seed = scn.run.seed if seed is None else int(seed)

        self.dt = float(scn.run.dt)
        self.frame_skip = self._frame_skip(control_period, frame_skip)
        self.control_period = self.frame_skip * self.dt
        self.metadata = {**self.metadata, "render_fps": max(1, round(1.0 / self.control_period))}
        #: physics steps of a whole episode (the run's ``steps``)
        self.horizon = simulation.steps_of(scn)

        self.plant = simulation.build_plant(scn)
        #: where an episode starts: plant.x0 as the scenario's [randomize] drew it at its seed
        #: (the machine build_plant made is drawn at the same seed)
        self.x0 = np.asarray(randomize.draw(scn).scenario.plant.x0, dtype=float)
        self.task = simulation.scenario_task(scn, self.plant)
        self.order = len(self.task.view)
        n, N = self.order, len(self.task.names)
        self.init_noise = initial_noise(init_noise, len(scn.plant.x0))
        self.normalize = bool(normalize)
        self._observation_layout()
        self._action_layout(simulation.machine_info(self.plant, self.task, scn))
        self._tracking = np.zeros(n)
        w = np.asarray(self.reward_weights.tracking, dtype=float)[:n]
        self._tracking[:w.size] = w
        hinges = {j.name for j in self.plant.joints if j.kind == "hinge"}
        self._wraps = np.array([v in hinges for v in self.task.view], dtype=bool)
        self._work_arrays(n, N)
        self._renderer: Any = None
        self._camera: Any = None
        self._seeded = False

    # -- construction helpers -------------------------------------------------------
    def _observation_layout(self) -> None:
        """The observation's names and units (the full state, then r and its derivatives),
        its space and the state columns' names."""
        n, N = self.order, len(self.task.names)
        refs = tuple("r" + "'" * k for k in range(n + 1))
        view_units = [self.task.units[j] for j in self.task.view_index]
        ref_units = [self._per_second(view_units[0], k) for k in range(n + 1)]
        #: what each entry of an observation is, and its unit
        self.observation_names: tuple[str, ...] = tuple(self.task.names) + refs
        self.observation_units: tuple[str, ...] = tuple(self.task.units) + tuple(ref_units)
        #: normalised spaces for learning libraries: actions in [-1, 1] (float32) mapped
        #: onto the actuator's range, observations as float32
        dtype = np.float32 if self.normalize else np.float64
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(N + n + 1,), dtype=dtype)
        #: each state's name as in an export and the metrics (the model's joint, its unit)
        from tspend.plants.domain import unit_slug

        self.state_columns = tuple(f"{name}_{unit_slug(unit)}" if unit_slug(unit) else name
                                   for name, unit in zip(self.task.names, self.task.units))

    def _action_layout(self, machine: Any) -> None:
        """The action's space (the actuator's range, or [-1, 1] onto it), name and unit."""
        lo, hi = machine.u_lo, machine.u_hi
        if self.normalize and not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
            raise ScenarioError(f"normalize=True: the actuator's range [{lo:g}, {hi:g}] is not "
                                f"finite: nothing to scale [-1, 1] onto")
        self.u_range = (float(lo), float(hi))
        self.action_space = (spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32) if self.normalize
                             else spaces.Box(np.array([lo]), np.array([hi]), dtype=np.float64))
        self._a_lo = float(self.action_space.low[0])
        self._a_hi = float(self.action_space.high[0])
        self.action_name = self.plant.inputs[0].name if self.plant.inputs else "u"
        self.action_unit = (self.plant.inputs[0].unit if self.plant.inputs else "") or \
            self._control_unit()
        self.u_scale = hi if math.isfinite(hi) and hi > 0 else 1.0

    def _work_arrays(self, n: int, N: int) -> None:
        """What each step works in: the clock, the observation, the reference and
        disturbance tables' window, the compiled step's frame."""
        # physics steps done in this episode and the tables' window's first step, in the
        # compiled step's int64 row (envstep.CLOCK, BASE): the compiled step advances it
        self._ints = np.zeros(envstep.INT_SLOTS, dtype=np.int64)
        self._obs = np.zeros(N + n + 1)
        self._u = 0.0
        self._hook = None
        # the reference and its derivatives at the physics steps' times and the disturbance
        # at each step, a window of them at a time (the same numbers as computing them
        # per step, tested): the table of a long episode would not fit in memory
        window = max(self.table_window, 16 * self.frame_skip)
        self._ref_table = np.zeros((window + 1, n + 1))
        self._dist_table = np.zeros(window)
        self._fill_tables(0)
        self._view_index = np.ascontiguousarray(self.task.view_index, dtype=np.int64)
        self._wrap_flags = self._wraps.astype(np.int64)
        #: the compiled step's view of this env (None: the Python step runs)
        self.frame = self._compiled_frame()
        if self.frame is not None:
            self._ints = self.frame.ints

    def _compiled_frame(self) -> envstep.Frame | None:
        """The env for :func:`tspend.loop.envstep.env_step`, when its plant offers MuJoCo's
        compiled step and nothing runs per sample in Python (no effects wrapper, no
        measurement hook: :mod:`tspend.loop.effects`)."""
        from tspend.loop.effects import needs_hook, needs_plant_wrapper
        from tspend.plants.mujoco_plant import mj_step_pointer

        effects = self.scenario.effects
        if needs_hook(effects) or needs_plant_wrapper(effects):
            return None
        link = self.plant.compiled_mujoco(self.dt)
        if link is None:
            return None
        task, w = self.task, self.reward_weights
        return envstep.Frame(link, mj_step_pointer(), self.frame_skip, self.horizon, self.dt,
                             self._ref_table, self._dist_table, np.zeros(len(task.names)), self._obs,
                             self._view_index, task.lo, task.hi, self._tracking,
                             self._wrap_flags, float(w.alive), float(w.control),
                             float(self.u_scale))

    def adopt_rows(self, ints: np.ndarray, floats: np.ndarray) -> None:
        """Keep the compiled step's rows in ``ints``, ``floats`` (rows of a vector env's
        matrices: :class:`tspend.gym.vector.TspendVectorEnv`)."""
        self.frame.adopt(ints, floats)
        self._ints = self.frame.ints

    def _frame_skip(self, control_period: float | None, frame_skip: int | None) -> int:
        if frame_skip is not None:
            if control_period is not None:
                raise ScenarioError("give control_period or frame_skip, not both")
            if int(frame_skip) != frame_skip or frame_skip < 1:
                raise ScenarioError(f"frame_skip {frame_skip!r}: must be an integer >= 1")
            return int(frame_skip)
        period = self.scenario.run.control_period if control_period is None else control_period
        if not period:
            return 1
        every = int(round(period / self.dt))
        if not (period > 0) or every < 1 or abs(every * self.dt - period) > 1e-9 * period:
            raise ScenarioError(f"control_period {period!r} s: must be a whole multiple of "
                                f"run.dt = {self.dt:g} s")
        return every

    def _fill_tables(self, start: int) -> None:
        """The tables' window from physics step ``start`` (:class:`envstep.Frame`)."""
        t = (start + np.arange(self._dist_table.size + 1)) * self.dt
        self._ref_table[:] = self.scenario.reference.derivatives(t, self.order)
        self._dist_table[:] = self.scenario.disturbance(t[:-1])
        self._ints[envstep.BASE] = start

    def refill(self) -> None:
        """The tables' window for the next step (the compiled step said REFILL)."""
        self._table_at(int(self._ints[envstep.CLOCK]), self.frame_skip)

    def _table_at(self, i: int, k: int) -> int:
        """The row of physics step ``i`` in the tables, with steps ``i .. i + k`` in them."""
        at = i - int(self._ints[envstep.BASE])
        if at < 0 or at + k > self._dist_table.size:
            self._fill_tables(i)
            at = 0
        return at

    @staticmethod
    def _per_second(unit: str, k: int) -> str:
        if k == 0 or not unit:
            return unit if k == 0 else ("1/s" if k == 1 else f"1/s^{k}")
        return f"{unit}/s" if k == 1 else f"{unit}/s^{k}"

    def _control_unit(self) -> str:
        from tspend.plants import registry

        return registry.domain_of(self.scenario.plant.kind).labels.control.unit

    # -- the gymnasium interface ------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode where a run starts (``plant.x0``, plus ``init_noise``).

        ``seed`` seeds the env's ``np_random`` and is the run's seed of the episode (the
        measurement effects' noise stream draws from it, as a run's does); without one,
        the first reset uses the constructor's ``seed`` (default ``run.seed``) and later
        ones a seed drawn from ``np_random``.
        """
        from tspend.loop import simulation
        from tspend.loop.effects import Measurement, needs_hook, needs_plant_wrapper

        if seed is None and not self._seeded:
            seed = self._first_seed
        super().reset(seed=seed)
        if seed is None:
            seed = int(self.np_random.integers(0, 2**31 - 1))
        self._seeded = True
        self.run_seed = int(seed)
        scn = self.scenario
        if needs_plant_wrapper(scn.effects):
            # the effects keep their own state (rate limit, a scheduled change): start afresh
            self.plant = simulation.build_plant(scn)
            self._renderer = None
        x0 = self.x0
        if np.any(self.init_noise > 0):
            x0 = x0 + self.np_random.uniform(-self.init_noise, self.init_noise)
        self.plant.reset(x0)
        self._hook = Measurement(scn.effects, self.plant, self.dt, self.run_seed) \
            if needs_hook(scn.effects) else None
        self._ints[envstep.CLOCK] = 0
        self._u = 0.0
        self._obs[:] = self._observe()
        out = self._obs.astype(np.float32) if self.normalize else self._obs.copy()
        return out, self._info("running", "")

    def step(self, action):
        """Hold ``action`` over ``frame_skip`` physics steps; the next observation, the
        reward, terminated (the task ended the run or it diverged), truncated (the
        scenario's duration reached) and info (``t``, ``status``, ``message``, ``u``)."""
        u = self.applied_action(action)
        self._u = u
        if self.frame is not None:
            f = self.frame
            code, done, reward = envstep.env_step(f.ints, f.floats, u)
            if code == envstep.REFILL:
                self.refill()
                code, done, reward = envstep.env_step(f.ints, f.floats, u)
            status, message = self._status(code, done, u)
        else:
            status, message, reward = self._python_step(u)
        return self._outcome(status, message, reward)

    def applied_action(self, action: Any) -> float:
        """The actuator's command of an action: one finite number, clipped to the action
        space (and mapped from [-1, 1] onto the actuator's range when ``normalize``);
        ScenarioError otherwise."""
        if type(action) is np.ndarray and action.shape == (1,) and action.dtype.kind == "f":
            a = float(action[0])       # the common case, without building arrays
            bad = not math.isfinite(a)
        else:
            try:
                arr = np.asarray(action)
                if arr.dtype.kind not in "iuf":  # numpy would read "0.5" and b"1" as numbers
                    raise TypeError
                arr = arr.astype(float)
            except (TypeError, ValueError):
                raise ScenarioError(f"action {action!r:.80}: not a number") from None
            bad = arr.size != 1 or not np.isfinite(arr).all()
            a = float(arr.reshape(-1)[0]) if not bad else 0.0
        if bad:
            # a NaN or a vector would otherwise be clipped into a plausible force silently
            raise ScenarioError(f"action {action!r:.80}: expected one finite number (the "
                                f"action space is {self.action_space})")
        return self._scaled(min(max(a, self._a_lo), self._a_hi))

    def _scaled(self, a: float) -> float:
        if self.normalize:
            lo, hi = self.u_range
            return lo + 0.5 * (a + 1.0) * (hi - lo)
        return a

    def _status(self, code: int, done: int, u: float) -> tuple[str, str]:
        """(status, message) of a compiled step's outcome (:mod:`tspend.loop.envstep`)."""
        if code == envstep.RUNNING:
            return "running", ""
        if code == envstep.ENDED:
            full = self.frame.full
            return self.task.termination(full, self._ints[envstep.CLOCK] * self.dt) or ("diverged", "")
        if code == envstep.NOT_FINITE:
            return "diverged", "the state is not finite"
        i = int(self._ints[envstep.CLOCK])
        if code == envstep.BAD_INPUT:
            from tspend.plants.mujoco_plant import refuse_huge_input

            try:
                d = float(self._dist_table[self._table_at(i, 1)])
                refuse_huge_input(self.plant.name, u, d, i * self.dt)
            except DivergenceError as exc:
                return "diverged", f"the plant failed ({exc})"
        return "diverged", f"the plant failed ({self.plant.instability(i * self.dt)})"

    def _python_step(self, u: float) -> tuple[str, str, float]:
        """The step through ``plant.step`` (effects, measurement hooks, ODE plants)."""
        i0 = int(self._ints[envstep.CLOCK])
        k = min(self.frame_skip, self.horizon - i0)
        at = self._table_at(i0, max(k, 0))
        dist = self._dist_table[at:at + max(k, 0)]
        status, message = "running", ""
        done = 0
        for j in range(k):
            try:
                self.plant.step(u, float(dist[j]), self.dt)
            except (ArithmeticError, ValueError, DivergenceError) as exc:
                status, message = "diverged", f"the plant failed ({exc})"
                break
            done += 1
            full = self.plant.full_state()
            if not np.all(np.isfinite(full)):
                status, message = "diverged", "the state is not finite"
                break
            if self.task.ended(full):
                status, message = self.task.termination(full, (i0 + j + 1) * self.dt) or \
                    ("diverged", "")
                break
        self._ints[envstep.CLOCK] = i0 + done
        if status == "diverged":
            return status, message, 0.0
        self._obs[:] = self._observe()
        w = self.reward_weights
        return status, message, envstep.reward_of(self._obs, len(self.task.names),
                                                  self._view_index, self._tracking,
                                                  self._wrap_flags, float(w.alive),
                                                  float(w.control), float(self.u_scale),
                                                  u, done * self.dt)

    def _outcome(self, status: str, message: str, reward: float):
        terminated = status != "running"
        # a diverged step keeps the last finite observation: gymnasium wants one in the space
        truncated = not terminated and int(self._ints[envstep.CLOCK]) >= self.horizon
        if truncated:
            status = "completed"
        out = self._obs.astype(np.float32) if self.normalize else self._obs.copy()
        return out, float(reward), terminated, truncated, self._info(status, message)

    def render(self):
        """The scene as an (height, width, 3) uint8 array (``render_mode="rgb_array"``)."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass "
                                  "render_mode='rgb_array' to gymnasium.make")
            return None
        renderer = self._open_renderer()
        data = self._mj_data()
        # follow the machine along its rail: the camera looks at its base body
        self._camera.lookat[:] = data.xpos[self._root_body] + self._look_offset
        renderer.update_scene(data, camera=self._camera)
        return renderer.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # -- for controllers and tests ---------------------------------------------------
    @property
    def t(self) -> float:
        """The time of the current sample (s)."""
        return int(self._ints[envstep.CLOCK]) * self.dt

    def controller_observation(self, obs: np.ndarray | None = None) -> Observation:
        """The :class:`~tspend.controllers.base.Observation` a controller gets for the env's
        observation ``obs`` (default: the current one), as the runner would build it."""
        obs = self._obs if obs is None else np.asarray(obs, dtype=float)
        N = len(self.task.names)
        state = obs[:N]
        return Observation(self.t, state, state[self.task.view_index].copy(), obs[N:],
                           self.task.names, self.task.constraints)

    def layout(self) -> list[tuple[str, str]]:
        """``(name, unit)`` of each observation entry."""
        return list(zip(self.observation_names, self.observation_units))

    # -- internals ---------------------------------------------------------------------
    def _observe(self) -> np.ndarray:
        full = self.plant.full_state()
        t = int(self._ints[envstep.CLOCK]) * self.dt
        ref = self._ref_table[self._table_at(int(self._ints[envstep.CLOCK]), 0)].copy()
        if self._hook is not None:
            # the runner's per-sample hook: the view as measured; it may shape ref in place
            x = full[self.task.view_index]
            full[self.task.view_index] = self._hook(t, x, ref)
        return np.concatenate((full, ref))

    def _info(self, status: str, message: str) -> dict[str, Any]:
        info = {"t": self.t, "status": status, "message": message, "u": self._u,
                "state": dict(zip(self.state_columns, self._obs[:len(self.state_columns)].tolist())),
                "u_unit": self.action_unit}
        if self.normalize:
            # a = -1 is the actuator's lo, a = +1 its hi (in u_unit)
            info["action_scale"] = {"lo": self.u_range[0], "hi": self.u_range[1],
                                    "unit": self.action_unit}
        return info

    def _mj_data(self) -> Any:
        data = getattr(self.plant, "data", None)  # EffectsPlant forwards to the MuJoCo plant
        if data is None:
            raise RenderError(f"scenario {self.scenario.name}: plant {self.plant.name} has "
                              f"no MuJoCo model to render (render a *_mujoco scenario)")
        return data

    def _open_renderer(self) -> Any:
        import mujoco

        data = self._mj_data()
        model = self.plant.model
        if self._renderer is None:
            try:
                self._renderer = mujoco.Renderer(model, self.height, self.width)
            except Exception as exc:  # no GL context: mujoco raises several kinds
                raise RenderError(f"cannot render: no OpenGL backend ({type(exc).__name__}: "
                                  f"{exc}); set MUJOCO_GL=egl (GPU or Mesa's EGL) or "
                                  f"MUJOCO_GL=osmesa") from None
            # frame the moving machine, not the world (the cart-pole's rail is 60 m long):
            # the bodies below the first joint's body, their geoms' bounding spheres
            root = int(model.jnt_bodyid[0]) if model.njnt else 0
            below = {root} | {b for b in range(model.nbody) if self._descends(model, b, root)}
            geoms = [g for g in range(model.ngeom) if int(model.geom_bodyid[g]) in below]
            base = data.xpos[root]
            lo = min((data.geom_xpos[g] - model.geom_rbound[g] for g in geoms),
                     key=lambda v: v[2], default=base)
            hi = max((data.geom_xpos[g] + model.geom_rbound[g] for g in geoms),
                     key=lambda v: v[2], default=base)
            radius = max([float(np.linalg.norm(data.geom_xpos[g] - base) + model.geom_rbound[g])
                          for g in geoms] or [1.0])
            cam = mujoco.MjvCamera()
            mujoco.mjv_defaultFreeCamera(model, cam)
            cam.distance = 2.2 * radius
            cam.azimuth, cam.elevation = 90.0, -8.0
            self._camera = cam
            self._root_body = root
            self._look_offset = np.array([0.0, 0.0, 0.5 * (lo[2] + hi[2]) - base[2]])
        return self._renderer

    @staticmethod
    def _descends(model: Any, body: int, root: int) -> bool:
        while body > 0:
            body = int(model.body_parentid[body])
            if body == root:
                return True
        return False


def register_all() -> list[str]:
    """Register ``tspend/<scenario>-v0`` for every scenario found (idempotent); the ids."""
    from tspend.scenario import available_scenarios

    ids = []
    for path in available_scenarios():
        name = path.stem
        eid = env_id(name)
        if eid not in gymnasium.registry:
            gymnasium.register(id=eid, entry_point="tspend.gym:TspendEnv",
                               vector_entry_point="tspend.gym.vector:TspendVectorEnv",
                               kwargs={"scenario": name}, disable_env_checker=False)
        ids.append(eid)
    return ids


register_all()


def autoreset_mode_of(value: Any) -> "gymnasium.vector.AutoresetMode":
    """A vector env's ``autoreset_mode`` (the CPU's and the MJX's): next step or same step
    (ScenarioError, one line, for anything else)."""
    from gymnasium.vector import AutoresetMode

    try:
        mode = AutoresetMode(value)
    except ValueError:
        raise ScenarioError(f"autoreset_mode {value!r}: allowed: NextStep, SameStep") from None
    if mode not in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP):
        raise ScenarioError(f"autoreset_mode {mode.value}: allowed: NextStep, SameStep")
    return mode

