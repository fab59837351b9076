"""The gymnasium environment (tspend/gym/__init__.py): checked by gymnasium's own env checker and
vector envs, and against the runner: the env driven by the ``pd`` controller retraces
``tspend.run(..., controller="pd")`` sample for sample."""

from __future__ import annotations

import os

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

import tspend  # noqa: E402
import tspend.gym  # noqa: E402
from tspend.runtime.errors import ScenarioError  # noqa: E402
from tspend.gym import RenderError, TspendEnv, env_id  # noqa: E402
from tspend.loop import simulation  # noqa: E402
from tspend.scenario import available_scenarios, load_scenario, override  # noqa: E402

ID = "tspend/pendulum_mujoco-v0"


def test_every_scenario_is_registered() -> None:
    names = [p.stem for p in available_scenarios()]
    assert names and all(env_id(n) in gymnasium.registry for n in names)
    assert gymnasium.registry[ID].kwargs == {"scenario": "pendulum_mujoco"}


def test_check_env_passes() -> None:
    from gymnasium.utils.env_checker import check_env

    env = gymnasium.make(ID)
    check_env(env.unwrapped)
    env.close()


def test_layout_and_action_space_come_from_the_plant_and_task() -> None:
    env = TspendEnv("pendulum_mujoco")
    assert env.observation_names == ("slider", "hinge", "slider_dot", "hinge_dot",
                                     "r", "r'", "r''")
    assert env.observation_units == ("m", "rad", "m/s", "rad/s", "rad", "rad/s", "rad/s^2")
    # the MJCF's motor: ctrlrange -2000 2000
    assert env.action_space.low[0] == -2000.0 and env.action_space.high[0] == 2000.0
    obs, _ = env.reset()
    scn = load_scenario("pendulum_mujoco")
    assert obs[1] == scn.plant.x0[0]          # the hinge starts at plant.x0
    assert obs[4] == 0.0 and obs[5] == pytest.approx(scn.reference.amplitude)  # r(0), r'(0)


def test_zero_force_terminates_before_the_duration() -> None:
    env = gymnasium.make(ID, control_period=0.02)
    env.reset(seed=0)
    steps, term, trunc = 0, False, False
    while not (term or trunc):
        _, _, term, trunc, info = env.step(np.zeros(1))
        steps += 1
    horizon = env.unwrapped.horizon // env.unwrapped.frame_skip
    assert term and not trunc and info["status"] == "fell"
    assert steps < horizon
    # it fell when the hinge left the task's fall angle (pi/2 for the cart-pole)
    assert abs(env.unwrapped.plant.full_state()[1]) > np.pi / 2
    env.close()


def test_holding_the_pole_runs_to_truncation() -> None:
    env = TspendEnv("pendulum_mujoco", control_period=0.05, overrides={"run.duration": 1.0})
    env.reset(seed=0)
    ctrl = simulation.prepare(env.scenario, controller="pd").controller
    n = 0
    while True:
        _, r, term, trunc, info = env.step([ctrl.step(env.controller_observation(), 0.05)])
        n += 1
        if term or trunc:
            break
    assert trunc and not term and info["status"] == "completed" and n == 20
    assert env.t == pytest.approx(1.0)


def test_env_driven_by_pd_retraces_the_run() -> None:
    """The same plant, reference, disturbance and controller: the env's states equal the
    run's recorded full state at every sample (the run: the compiled loop)."""
    duration = 3.0
    result = tspend.run("pendulum_mujoco", controller="pd", duration=duration)
    assert result.status == "completed"
    states, us = result.history["state"], result.history["u"]

    env = gymnasium.make(ID, overrides={"run.duration": duration})
    u_env = env.unwrapped
    assert u_env.frame_skip == 1
    ctrl = simulation.prepare(u_env.scenario, controller="pd").controller
    ctrl.reset(np.random.default_rng(1))
    obs, _ = env.reset(seed=1)
    N = len(u_env.task.names)
    got_x, got_u = [], []
    while True:
        u = ctrl.step(u_env.controller_observation(), u_env.dt)
        got_x.append(obs[:N].copy())
        got_u.append(u)
        obs, _, term, trunc, _ = env.step(np.array([u]))
        if term or trunc:
            break
    assert trunc and not term
    got_x, got_u = np.array(got_x), np.array(got_u)
    assert got_x.shape == states.shape
    np.testing.assert_allclose(got_x, states, rtol=0, atol=1e-9)
    np.testing.assert_allclose(got_u, us, rtol=1e-9, atol=1e-9)
    frame = result.to_pandas()
    np.testing.assert_allclose(got_x[:, 1], frame.iloc[:, 0].to_numpy(), atol=1e-9)


def test_reset_seed_reproduces_an_episode() -> None:
    def episode(env, seed):
        obs, _ = env.reset(seed=seed)
        out = [obs]
        for k in range(30):
            obs, *_ = env.step(np.array([50.0 * np.sin(k)]))
            out.append(obs)
        return np.array(out)

    env = TspendEnv("pendulum_mujoco", control_period=0.02, init_noise=0.05)
    a, b, c = episode(env, 7), episode(env, 7), episode(env, 8)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a[0], c[0])       # the seed draws the start


def test_sensor_noise_is_drawn_from_the_seed() -> None:
    env = TspendEnv("pendulum_sensor_noise", control_period=0.01)
    first = [env.reset(seed=s)[0][1] for s in (3, 3, 4)]
    assert first[0] == first[1] != first[2]


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_make_vec(mode: str) -> None:
    envs = gymnasium.make_vec(ID, num_envs=2, vectorization_mode=mode,
                              control_period=0.02)
    try:
        obs, _ = envs.reset(seed=[1, 2])
        assert obs.shape == (2, 7)
        obs2, rew, term, trunc, _ = envs.step(np.zeros((2, 1)))
        assert obs2.shape == (2, 7) and rew.shape == (2,) and not term.any()
        single = TspendEnv("pendulum_mujoco", control_period=0.02)
        single.reset(seed=1)
        np.testing.assert_array_equal(obs2[0], single.step(np.zeros(1))[0])
    finally:
        envs.close()


def test_bad_options_are_one_line_scenario_errors() -> None:
    from tspend.runtime.errors import ScenarioError

    with pytest.raises(ScenarioError, match="whole multiple"):
        TspendEnv("pendulum_mujoco", control_period=0.0015)
    with pytest.raises(ScenarioError, match="render_mode"):
        TspendEnv("pendulum_mujoco", render_mode="human")


def _egl() -> bool:
    if os.environ.get("MUJOCO_GL", "egl") != "egl":
        return True
    try:
        import mujoco

        mujoco.GLContext(8, 8).free()
        return True
    except Exception:
        return False


def test_render_rgb_array() -> None:
    os.environ.setdefault("MUJOCO_GL", "egl")
    if not _egl():
        pytest.skip("no EGL on this machine")
    env = gymnasium.make(ID, render_mode="rgb_array", width=160, height=120)
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (120, 160, 3) and frame.dtype == np.uint8
    assert frame.std() > 5          # not a blank frame
    env.close()


def test_render_without_a_mujoco_model_is_a_clear_error() -> None:
    env = TspendEnv("ex2_duffing", render_mode="rgb_array")
    env.reset(seed=0)
    with pytest.raises(RenderError, match="no MuJoCo model"):
        env.render()


@pytest.mark.parametrize("action", [np.array([np.nan]), np.array([1.0, 2.0]), "push"])
def test_a_bad_action_is_refused_not_clipped(action) -> None:
    env = TspendEnv("pendulum_mujoco")
    env.reset(seed=0)
    with pytest.raises(ScenarioError, match="action"):
        env.step(action)
