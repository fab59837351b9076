"""The MJX backend (tspend/mjx) against the CPU backend, its oracle.

MJX steps the same MuJoCo models in JAX (float64 here); the CPU backend's runs are the
reference: a sweep's rows (status, rmse, rmse_ss within 1e-6 relative, the same columns)
and the vector env's observations (within 1e-9), rewards and terminations after the same
actions.  Small batches and short horizons: each distinct loop costs one XLA compile
(10-60 s on a small CPU), which the persistent cache (~/.cache/tspend/jax) keeps.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

pytest.importorskip("jax")
pytest.importorskip("mujoco.mjx")

import tspend  # noqa: E402
from tspend.runtime.errors import ScenarioError  # noqa: E402
from tspend.scenario import load_scenario, override  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")


def _rows(scenario, seeds, backend, tmp_path=None):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return tspend.sweep(scenario, seeds=seeds, controllers="lqr", jobs=1, record="none",
                            backend=backend)


@pytest.mark.parametrize("scenario, seeds, duration", [
    ("pendulum_mujoco_randomized", "0:4", None),
    # the whole 10 s run (its [randomize]-free machine at every seed)
    ("double_cartpole_mujoco", "0:4", None),
])
def test_mjx_sweep_rows_agree_with_the_cpu_sweep(scenario, seeds, duration):
    scn = load_scenario(scenario)
    cpu = _rows(scn, seeds, "cpu")
    mjx = _rows(scn, seeds, "mjx")
    assert list(mjx.columns) == list(cpu.columns)
    assert len(mjx) == len(cpu) == int(seeds.split(":")[1]) - int(seeds.split(":")[0])
    assert list(mjx["seed"]) == list(cpu["seed"])
    assert list(mjx["status"]) == list(cpu["status"])
    for key in ("rmse", "rmse_ss", "max_abs_e", "control_energy", "max_abs_u"):
        np.testing.assert_allclose(mjx[key].to_numpy(float), cpu[key].to_numpy(float),
                                   rtol=1e-6, err_msg=key)
    drawn = [c for c in cpu.columns if c.startswith(("drawn.", "plant."))]
    for c in drawn:
        np.testing.assert_allclose(mjx[c].to_numpy(float), cpu[c].to_numpy(float), rtol=0, err_msg=c)


def test_mjx_sweep_refuses_what_it_cannot_run():
    with pytest.raises(ScenarioError, match="no JAX form"):
        tspend.sweep("pendulum_mujoco", seeds="0:2", controllers="mpc", backend="mjx")
    with pytest.raises(ScenarioError, match="not a MuJoCo machine"):
        tspend.sweep("ex3_pendulum_ode", seeds="0:2", controllers="lqr", backend="mjx")
    with pytest.raises(ScenarioError, match="backend"):
        tspend.sweep("pendulum_mujoco", seeds="0:2", controllers="lqr", backend="gpu")


def _vector_envs(name, n, **kw):
    gymnasium = pytest.importorskip("gymnasium")
    import tspend.gym  # noqa: F401

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cpu = gymnasium.make_vec(f"tspend/{name}-v0", num_envs=n,
                                 vectorization_mode="vector_entry_point", **kw)
        mjx = gymnasium.make_vec(f"tspend/{name}-v0", num_envs=n,
                                 vectorization_mode="vector_entry_point", backend="mjx", **kw)
    return cpu, mjx


@pytest.mark.parametrize("name, overrides", [
    ("pendulum_mujoco", {}),
    # a fall angle just above x0's: episodes end, autoreset and start again within 100 steps
    ("pendulum_mujoco", {"task.fall_angle": 0.12}),
    ("double_cartpole_mujoco", {}),
])
def test_mjx_vector_env_steps_as_the_cpu_vector_env(name, overrides):
    cpu, mjx = _vector_envs(name, 8, overrides=overrides)
    assert type(mjx).__name__ == "MjxVectorEnv"
    o_cpu, _ = cpu.reset(seed=3)
    o_mjx, _ = mjx.reset(seed=3)
    np.testing.assert_array_equal(o_mjx, o_cpu)
    rng = np.random.default_rng(0)
    # the actuator's whole range where episodes are to end, else gentle pushes
    hi = cpu.single_action_space.high if overrides else np.minimum(cpu.single_action_space.high, 40.0)
    ended = 0
    for _ in range(100):
        a = rng.uniform(-1.0, 1.0, size=(8, 1)) * hi
        c, m = cpu.step(a), mjx.step(a)
        np.testing.assert_allclose(m[0], c[0], rtol=0, atol=1e-9)
        np.testing.assert_allclose(m[1], c[1], rtol=1e-12, atol=1e-15)
        np.testing.assert_array_equal(m[2], c[2])
        np.testing.assert_array_equal(m[3], c[3])
        assert list(m[4]["status"]) == list(c[4]["status"])
        ended += int(c[2].sum())
    if overrides:
        assert ended > 0   # the autoreset was exercised
    cpu.close()
    mjx.close()


def test_brax_env_is_the_gym_env_as_pure_functions():
    pytest.importorskip("brax")
    import jax
    import jax.numpy as jnp

    from tspend.gym import TspendEnv
    from tspend.mjx.brax_env import BraxEnv

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = BraxEnv("pendulum_mujoco", control_period=0.02, action_scale=100.0)
        cpu = TspendEnv("pendulum_mujoco", control_period=0.02)
    step = jax.jit(env.step)
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    obs, _ = cpu.reset()
    np.testing.assert_array_equal(np.asarray(state.obs), obs)
    rng = np.random.default_rng(1)
    for _ in range(10):
        a = rng.uniform(-1.0, 1.0)
        state = step(state, jnp.array([a]))
        obs, r, term, trunc, _ = cpu.step(np.array([100.0 * a]))
        np.testing.assert_allclose(np.asarray(state.obs), obs, rtol=0, atol=1e-9)
        np.testing.assert_allclose(float(state.reward), r, rtol=1e-12)
        assert bool(state.done) == (term or trunc)
    # vmap: four envs from their own keys, stepped at once
    states = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), 4))
    states = jax.jit(jax.vmap(env.step))(states, jnp.zeros((4, 1)))
    assert states.obs.shape == (4, env.observation_size) and np.isfinite(states.reward).all()


@pytest.mark.parametrize("policy", ["pendulum_mujoco", "double_cartpole_mujoco"])
def test_onnx_graph_in_jax_is_onnxruntimes(policy):
    ort = pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")
    import jax

    from tspend.mjx.onnx_jax import onnx_function
    from tspend.shipped import data_root as project_root

    path = project_root() / "models" / "policies" / f"{policy}.onnx"
    fn, params, dtype = onnx_function(path)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    width = session.get_inputs()[0].shape[-1]
    obs = np.random.default_rng(0).normal(scale=0.5, size=(32, width)).astype(dtype)
    want = session.run(None, {session.get_inputs()[0].name: obs})[0]
    got = np.asarray(jax.jit(fn)(params, obs))
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-4 * np.abs(want).max())
