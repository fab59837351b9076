"""The gym reward never pays for ending an episode early: every step survived earns more
than nothing, on every registered env, under constant extreme and zero actions (issue 44,
part A)."""

from __future__ import annotations

import math

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

import tspend.gym  # noqa: E402
from tspend.runtime.errors import ScenarioError  # noqa: E402
from tspend.gym import RewardWeights, TspendEnv, env_id  # noqa: E402
from tspend.scenario import available_scenarios  # noqa: E402

#: steps per episode tried (0.02 s each where the env's dt divides it): long enough for a
#: pushed cart-pole to end, short enough for every env on two cores
MAX_STEPS = 150
NAMES = [p.stem for p in available_scenarios()]


def _episode(env, u: float, steps: int = MAX_STEPS) -> tuple[float, list[float], list[str]]:
    env.reset(seed=0)
    rewards, statuses = [], []
    for _ in range(steps):
        _, r, terminated, truncated, info = env.step(np.array([u]))
        rewards.append(float(r))
        statuses.append(info["status"])
        if terminated or truncated:
            break
    return float(sum(rewards)), rewards, statuses


def _env(name: str):
    try:
        return gymnasium.make(env_id(name), control_period=0.02).unwrapped
    except ScenarioError:  # a dt that does not divide 20 ms: the scenario's own period
        return gymnasium.make(env_id(name)).unwrapped


def _extremes(env) -> tuple[float, float]:
    lo, hi = float(env.action_space.low[0]), float(env.action_space.high[0])
    # an unbounded actuator (an ODE plant): a push far beyond what the task needs
    return (lo if math.isfinite(lo) else -1e3), (hi if math.isfinite(hi) else 1e3)


@pytest.mark.parametrize("name", NAMES)
def test_every_step_survived_pays_on_every_env(name):
    env = _env(name)
    lo, hi = _extremes(env)
    for u in (lo, 0.0, hi):
        _, rewards, statuses = _episode(env, u)
        for r, status in zip(rewards, statuses):
            # a step that diverged earns exactly 0; every other step more than 0 and at
            # most alive * T
            assert (r == 0.0) if status == "diverged" else (0.0 < r <= env.control_period + 1e-12), \
                (name, u, r, status)
    env.close()


@pytest.mark.parametrize("name", ["pendulum_mujoco", "double_cartpole_mujoco"])
def test_full_force_either_way_earns_less_than_doing_nothing(name):
    env = gymnasium.make(env_id(name), control_period=0.02).unwrapped
    lo, hi = _extremes(env)
    horizon = int(round(env.scenario.run.duration / env.control_period))
    zero, _, z_status = _episode(env, 0.0, horizon)
    for u in (lo, hi):
        pushed, rewards, status = _episode(env, u, horizon)
        # the push ends the episode first (the premise of the case)
        assert len(rewards) < len(z_status) and status[-1] != "completed"
        assert pushed < zero, (name, u, pushed, zero)
    env.close()


def test_the_reward_is_the_documented_formula():
    env = TspendEnv("pendulum_mujoco", control_period=0.02,
                    reward={"alive": 2.0, "tracking": (3.0, 0.5), "control": 0.25})
    env.reset(seed=0)
    obs, r, *_ = env.step(np.array([4.0]))
    names = env.observation_names
    n = len(env.task.view)
    e = [obs[names.index(v)] - obs[len(names) - n - 1 + k] for k, v in enumerate(env.task.view)]
    e[0] = (e[0] + math.pi) % (2 * math.pi) - math.pi
    c = 3.0 * e[0] ** 2 + 0.5 * e[1] ** 2 + 0.25 * (4.0 / env.u_scale) ** 2
    assert r == pytest.approx(0.02 * 2.0 / (1.0 + c), rel=1e-12)


@pytest.mark.parametrize("weights, message", [
    ({"alive": 0.0}, "reward.alive: must be > 0"),
    ({"alive": -1.0}, "reward.alive: must be > 0"),
    ({"control": -1.0}, "reward.control: must be >= 0"),
    ({"tracking": (1.0, -2.0)}, "reward.tracking: every weight must be >= 0"),
    ({"alive": float("nan")}, "reward.alive: must be finite"),
    ({"alvie": 1.0}, "reward: unknown key"),
])
def test_weights_that_would_pay_for_ending_early_are_refused(weights, message):
    with pytest.raises(ScenarioError, match=message):
        TspendEnv("pendulum_mujoco", reward=weights)
    if "alvie" not in weights:
        with pytest.raises(ScenarioError, match=message):
            RewardWeights(**weights)
