"""The compiled env step and the batched vector env (tspend/loop/envstep.py,
tspend/gym/vector.py).

Oracles: the env's own Python step (``plant.step`` per physics step, the tables looked up
per step), which the compiled step must equal bit for bit, and N single envs in
gymnasium's own ``SyncVectorEnv``, which the vector env must equal bit for bit, with
terminations, truncations, autoresets and ``[randomize]`` machines."""

from __future__ import annotations

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

import tspend.gym  # noqa: E402,F401
from gymnasium.vector import AutoresetMode  # noqa: E402
from tspend.runtime.errors import ScenarioError  # noqa: E402
from tspend.gym import TspendEnv  # noqa: E402
from tspend.gym.vector import TspendVectorEnv  # noqa: E402


def _episode_steps(env, actions, seed):
    """Observations, rewards, flags and statuses of ``actions`` from ``reset(seed)``,
    resetting (without a seed) when an episode ends."""
    out = [env.reset(seed=seed)[0]]
    rewards, flags, statuses = [], [], []
    for a in actions:
        obs, r, term, trunc, info = env.step(np.array([a]))
        out.append(obs)
        rewards.append(r)
        flags.append((term, trunc))
        statuses.append((info["status"], info["message"]))
        if term or trunc:
            out.append(env.reset()[0])
    return np.array(out), np.array(rewards), flags, statuses


@pytest.mark.parametrize("scenario, duration", [("pendulum_mujoco_randomized", 0.8),
                                                ("double_cartpole_mujoco", 0.4)])
def test_compiled_step_equals_the_python_step(scenario, duration, monkeypatch) -> None:
    # a small tables' window, so that episodes cross several of them
    monkeypatch.setattr(TspendEnv, "table_window", 64)
    kwargs = dict(control_period=0.01, init_noise=0.05, overrides={"run.duration": duration})
    fast, slow = TspendEnv(scenario, **kwargs), TspendEnv(scenario, **kwargs)
    assert fast.frame is not None
    slow.frame = None                      # the Python step (plant.step)
    # small pushes (episodes run to their end), then large ones, one way mostly (the pole
    # falls or the cart reaches the rail's end)
    hi = min(float(fast.action_space.high[0]), 1000.0)
    rng = np.random.default_rng(0)
    actions = np.concatenate((rng.uniform(-0.01, 0.01, 170), rng.uniform(-0.3, 1.0, 230))) * hi
    a, b = _episode_steps(fast, actions, 3), _episode_steps(slow, actions, 3)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert a[2] == b[2] and a[3] == b[3]
    ends = {s for s, _ in a[3]}
    assert "completed" in ends and ends - {"running", "completed"}, ends  # both kinds of end


def test_the_tables_hold_what_the_signals_give_per_step() -> None:
    env = TspendEnv("pendulum_mujoco_randomized", control_period=0.02)
    scn = env.scenario
    for i in (0, 1, 777, 4095, 4096, 9001):
        at = env._table_at(i, 1)
        t = np.array([i * env.dt])
        np.testing.assert_array_equal(env._ref_table[at], scn.reference.derivatives(t, env.order)[0])
        assert env._dist_table[at] == scn.disturbance(t)[0]


def _singles(scenario, n, base, mode=AutoresetMode.NEXT_STEP, **kwargs):
    overrides = kwargs.pop("overrides", {})
    return gymnasium.vector.SyncVectorEnv(
        [lambda i=i: TspendEnv(scenario, overrides={**overrides, "run.seed": base + i}, **kwargs)
         for i in range(n)], autoreset_mode=mode)


@pytest.mark.parametrize("normalize, mode", [(False, AutoresetMode.NEXT_STEP),
                                             (True, AutoresetMode.NEXT_STEP),
                                             (False, AutoresetMode.SAME_STEP)])
def test_vector_env_equals_single_envs_bit_for_bit(normalize, mode) -> None:
    scenario, n, base = "pendulum_mujoco_randomized", 5, 11
    kwargs = dict(control_period=0.02, init_noise=0.1, normalize=normalize,
                  overrides={"run.duration": 0.6})
    vec = gymnasium.make_vec(f"tspend/{scenario}-v0", num_envs=n,
                             vectorization_mode="vector_entry_point", seed=base,
                             autoreset_mode=mode, threads=3, **kwargs)
    ref = _singles(scenario, n, base, mode, **kwargs)
    assert isinstance(vec.unwrapped, TspendVectorEnv) and vec.unwrapped.compiled
    assert vec.unwrapped.threads == 3          # three shares, two of them on the pool
    # each machine drawn at its own seed
    masses = {e.plant.parameters().get("m") for e in vec.unwrapped.envs}
    assert len(masses) == n
    rng = np.random.default_rng(5)
    # envs 0 and 1 nudged (they run to the duration), the others pushed one way mostly
    scale = (1.0 if normalize else 2000.0) * np.array([[0.01], [0.01], [1.0], [1.0], [1.0]])
    o1, _ = vec.reset(seed=3)
    o2, _ = ref.reset(seed=3)
    np.testing.assert_array_equal(o1, o2)
    ended = resets = 0
    for _ in range(70):
        act = (scale * rng.uniform(-0.3, 1.0, (n, 1))).astype(vec.action_space.dtype)
        a, b = vec.step(act), ref.step(act)
        for x, y in zip(a[:4], b[:4]):
            assert x.dtype == y.dtype
            np.testing.assert_array_equal(x, y)
        if mode == AutoresetMode.SAME_STEP and "final_obs" in b[4]:
            for i in np.flatnonzero(b[4]["_final_obs"]):
                np.testing.assert_array_equal(a[4]["final_obs"][i], b[4]["final_obs"][i])
        ended += int(a[2].sum())
        resets += int(a[3].sum())
        assert set(a[4]["status"][a[2]]) <= {"fell", "rail_end", "joint_limit", "state_bound",
                                             "diverged"}
    assert ended and resets            # terminations, truncations and autoresets were met
    vec.close()
    ref.close()


def test_vector_env_seeds_and_bad_actions() -> None:
    vec = TspendVectorEnv("pendulum_mujoco", num_envs=2, control_period=0.02, init_noise=0.05)
    a, _ = vec.reset(seed=[4, 9])
    b, _ = vec.reset(seed=4)
    assert np.array_equal(a[0], b[0]) and not np.array_equal(a[1], b[1])   # 4 then 5
    with pytest.raises(ScenarioError, match="2 finite numbers"):
        vec.step(np.array([[np.nan], [0.0]]))
    with pytest.raises(ScenarioError, match="num_envs"):
        TspendVectorEnv("pendulum_mujoco", num_envs=0)


def test_a_machine_without_the_compiled_step_is_stepped_alike() -> None:
    """Sensor noise needs the runner's per-sample hook: stepped through TspendEnv.step."""
    kwargs = dict(control_period=0.01, overrides={"run.duration": 0.3})
    vec = TspendVectorEnv("pendulum_sensor_noise", num_envs=2, seed=2, **kwargs)
    ref = _singles("pendulum_sensor_noise", 2, 2, **kwargs)
    assert not vec.compiled
    np.testing.assert_array_equal(vec.reset(seed=1)[0], ref.reset(seed=1)[0])
    for k in range(40):
        act = np.full((2, 1), 5.0 * np.sin(k))
        for x, y in zip(vec.step(act)[:4], ref.step(act)[:4]):
            np.testing.assert_array_equal(x, y)


def test_vector_env_renders_env_0() -> None:
    import os

    os.environ.setdefault("MUJOCO_GL", "egl")
    vec = TspendVectorEnv("pendulum_mujoco", num_envs=2, render_mode="rgb_array", width=64,
                          height=48, init_noise=0.3)
    vec.reset(seed=0)
    try:
        frame = vec.render()
    except tspend.gym.RenderError:
        pytest.skip("no GL backend on this machine")
    assert frame.shape == (48, 64, 3) and frame.dtype == np.uint8
    assert frame.std() > 5                    # not a blank frame
    assert vec.envs[0].render_mode == "rgb_array" and vec.envs[1].render_mode is None
    vec.close()
