"""The MJX backend (tspend/mjx) against the CPU backend, its oracle.

MJX steps the same MuJoCo models in JAX (float64 here); the CPU backend's runs are the
reference: a sweep's rows (status, rmse, rmse_ss within 1e-6 relative, the same columns)
and the vector env's observations (within 1e-9), rewards and terminations after the same
actions.  Small batches and short horizons: each distinct loop costs one XLA compile
(10-60 s on a small CPU), which the persistent cache (~/.cache/tspend/jax) keeps.
"""

from __future__ import annotations

import copy
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
    # the draw exactly; the parameters as written into the model's fields (the CPU reads
    # them back from its compiled model: the same to rounding)
    for c in (c for c in cpu.columns if c.startswith(("drawn.", "plant."))):
        np.testing.assert_allclose(mjx[c].to_numpy(float), cpu[c].to_numpy(float),
                                   rtol=0 if c.startswith("drawn.") else 1e-13, err_msg=c)


#: every ending the CPU loop knows, each driven on both randomised machines (short runs):
#: completed, fell, rail_end, and a state MuJoCo finds non-finite or huge ("the plant
#: failed": a gain of 10^12 or a push of 5e9 makes qacc huge in the first step; a gain of
#: 10^7 makes u huge a few samples in, which MuJoCo would refuse).  The last number: the
#: rows' relative tolerance (1e-9; 1e-4 where the gain of 10^7 multiplies the backends'
#: 1e-16 round-off by some 10^10 in the three samples before u reaches 10^10: seed 2's ise
#: differed by 3e-6 on the machine this was written on and by 1.7e-5 on an AMD EPYC with the
#: same code and wheels, where XLA's and MuJoCo's builds pick other vector instructions; seeds
#: 0 and 1 by 1e-9.  The status and the step of the ending are compared exactly all the same)
ENDINGS = [
    ("pendulum_mujoco_randomized", "0:4", 0.3, {}, {"completed"}, 1e-9),
    ("pendulum_mujoco_randomized", "0:8", 0.3, {"effects.rail": 0.002, "task.fall_angle": 0.1},
     {"fell", "rail_end"}, 1e-9),
    ("pendulum_mujoco_randomized", "0:3", 0.05, {"randomize.gear.low": 1e7,
                                                 "randomize.gear.high": 2e7,
                                                 "task.fall_angle": 0.0}, {"diverged"}, 1e-4),
    ("pendulum_mujoco_randomized", "3:5", 0.05, {"randomize.gear.low": 1e12,
                                                 "randomize.gear.high": 2e12,
                                                 "task.fall_angle": 0.0}, {"diverged"}, 1e-9),
    ("double_cartpole_mujoco_randomized", "0:8", 0.3, {"task.fall_angle": 0.09},
     {"completed", "fell"}, 1e-9),
    ("double_cartpole_mujoco_randomized", "0:3", 0.1, {"plant.q0": [-2.49, 0.1, -0.05]},
     {"rail_end"}, 1e-9),
    ("double_cartpole_mujoco_randomized", "0:2", 0.05,
     {"disturbance.kind": "square", "disturbance.amplitude": 5e9, "disturbance.period": 0.2,
      "task.joint_limits": False, "task.fall_angle": 0.0}, {"diverged"}, 1e-9),
]


def _assert_rows_equal(mjx, cpu, rtol=1e-9):
    """Same columns, seeds, statuses, steps; every number within ``rtol`` relative (NaN
    where the CPU's is; the wall times aside)."""
    assert list(mjx.columns) == list(cpu.columns)
    assert list(mjx["seed"]) == list(cpu["seed"])
    assert list(mjx["status"]) == list(cpu["status"])
    assert list(mjx["steps"]) == list(cpu["steps"])
    import pandas as pd

    for c in cpu.columns:
        if c in ("wall_s", "job_s") or not pd.api.types.is_numeric_dtype(cpu[c]):
            continue
        a, b = cpu[c].to_numpy(float), mjx[c].to_numpy(float)
        np.testing.assert_allclose(b, a, rtol=rtol, atol=0, equal_nan=True, err_msg=c)


@pytest.mark.parametrize("scenario, seeds, duration, overrides, statuses, rtol", ENDINGS)
def test_mjx_sweep_rows_equal_the_cpu_rows_on_every_ending(scenario, seeds, duration,
                                                           overrides, statuses, rtol):
    scn = override(load_scenario(scenario), **{"run.duration": duration, **overrides})
    cpu = _rows(scn, seeds, "cpu")
    assert set(cpu["status"]) == statuses       # the case drives the endings it names
    _assert_rows_equal(_rows(scn, seeds, "mjx"), cpu, rtol)


@pytest.mark.parametrize("scenario", ["pendulum_mujoco_randomized",
                                      "double_cartpole_mujoco_randomized"])
def test_drawn_machines_are_each_seeds_cpu_build(scenario):
    """The machines written from the draw as arrays (tspend/mjx/drawn.py) against each
    seed's CPU build: every field MJX steps (the geoms' shapes aside: they only draw), the
    start state, the push per unit d, the metrics' parameters and draw."""
    import jax

    from tspend.mjx.machines import build_fleet, build_fleet_per_seed

    scn = load_scenario(scenario)
    seeds = [3, 4, 5, 6]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        drawn, cpu = build_fleet(scn, seeds), build_fleet_per_seed(scn, seeds)

    def leaves(fleet):
        flat = jax.tree_util.tree_flatten_with_path(fleet.model)[0]
        axes = jax.tree_util.tree_leaves(fleet.in_axes, is_leaf=lambda x: x is None)
        return {jax.tree_util.keystr(p): np.asarray(v) if a == 0 else
                np.broadcast_to(np.asarray(v), (len(seeds),) + np.shape(v))
                for (p, v), a in zip(flat, axes)}

    a, b = leaves(drawn), leaves(cpu)
    assert a.keys() == b.keys()
    shapes = ("geom_", "stat.meansize", "stat.extent", "stat.center")
    for k in a:
        if a[k].dtype.kind == "f" and not any(s in k for s in shapes):
            np.testing.assert_allclose(a[k], b[k], rtol=1e-13, atol=1e-300, err_msg=k)
    np.testing.assert_array_equal(drawn.qpos0, cpu.qpos0)
    np.testing.assert_array_equal(drawn.qvel0, cpu.qvel0)
    np.testing.assert_allclose(drawn.d_to_tau, cpu.d_to_tau, rtol=1e-14)
    for m, c in zip(drawn.machines, cpu.machines):
        assert m.drawn == c.drawn and list(m.parameters) == list(c.parameters)
        np.testing.assert_allclose(list(m.parameters.values()), list(c.parameters.values()),
                                   rtol=1e-13)


def test_a_sweep_batch_runs_on_the_device_without_a_transfer():
    import jax

    from tspend.loop.simulation import prepare
    from tspend.mjx import sweep as mjx_sweep
    from tspend.mjx.machines import build_fleet

    scn = override(load_scenario("pendulum_mujoco_randomized"), **{"run.duration": 0.02})
    fleet = build_fleet(scn, range(4))
    program = mjx_sweep.prepare_program(fleet, prepare(fleet.scenario, controller="lqr").controller)
    inputs = mjx_sweep.batch_inputs(fleet, np.arange(4), program)
    figures, end = mjx_sweep.run_batch(program.run, inputs)
    # one record per env, still on the device
    assert all(v.shape[0] == 4 for v in jax.tree_util.tree_leaves((figures, end)))
    assert all(isinstance(v, jax.Array) for v in jax.tree_util.tree_leaves((figures, end)))
    # the guard is armed: a host array handed to the program inside it is refused
    with pytest.raises(Exception, match="[Dd]isallowed"):
        mjx_sweep.run_batch(program.run, inputs[:3] + (np.asarray(inputs[3]),) + inputs[4:])


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


def _same_step(cpu, mjx, actions, obs_atol=1e-9, reward_tol=(1e-12, 1e-15)):
    """Step both vector envs with ``actions``; their results agree (observations within
    ``obs_atol``, rewards within ``reward_tol`` (relative, absolute), terminations,
    truncations, statuses equal)."""
    c, m = cpu.step(actions), mjx.step(actions)
    np.testing.assert_allclose(m[0], c[0], rtol=0, atol=obs_atol)
    np.testing.assert_allclose(m[1], c[1], rtol=reward_tol[0], atol=reward_tol[1])
    np.testing.assert_array_equal(m[2], c[2])
    np.testing.assert_array_equal(m[3], c[3])
    assert list(m[4]["status"]) == list(c[4]["status"])
    ended = np.asarray(c[2], dtype=bool)
    assert list(m[4]["message"][ended]) == list(c[4]["message"][ended])
    return c


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
        c = _same_step(cpu, mjx, a)
        ended += int(c[2].sum())
    if overrides:
        assert ended > 0   # the autoreset was exercised
    cpu.close()
    mjx.close()


def test_mjx_vector_env_in_float32_steps_as_the_cpu_vector_env():
    # float32 data met MJX's RK4 tableau in float64 (the fleet's build had turned JAX's
    # float64 on): the first step failed.  A float64 env built after it turns float64
    # on again; the float32 env still steps, within float32 rounding of the CPU env,
    # and ends where the CPU env ends
    gymnasium = pytest.importorskip("gymnasium")
    def make(n, **kw):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return gymnasium.make_vec("tspend/pendulum_mujoco-v0", num_envs=n,
                                     vectorization_mode="vector_entry_point",
                                     overrides={"task.fall_angle": 0.12}, **kw)

    f32 = make(4, backend="mjx", precision="float32")
    make(2, backend="mjx").close()
    cpu = make(4)
    np.testing.assert_array_equal(f32.reset(seed=3)[0], cpu.reset(seed=3)[0])
    rng = np.random.default_rng(0)
    ended = 0
    for _ in range(100):
        a = rng.uniform(-1.0, 1.0, size=(4, 1)) * cpu.single_action_space.high
        c = _same_step(cpu, f32, a, obs_atol=1e-5, reward_tol=(1e-5, 1e-8))
        ended += int(c[2].sum())
    assert ended > 0
    cpu.close()
    f32.close()


def test_mjx_vector_env_leaves_what_a_step_returned_as_it_was():
    # the step reads one packed array back and reuses its input buffer: what it handed
    # out (observations, rewards, endings, infos) must stay the caller's own, through
    # endings and restarts (SameStep writes the restarted envs' observations)
    # (gears of 10^11-10^12: every env ends at its first push, as in the diverged test)
    over = {"randomize.gear.low": 1e11, "randomize.gear.high": 1e12, "task.fall_angle": 0.0}
    _, mjx = _vector_envs("pendulum_mujoco_randomized", 4, overrides=over,
                          autoreset_mode="SameStep")
    mjx.reset(seed=0)
    rng = np.random.default_rng(3)
    kept = []
    for _ in range(6):
        out = mjx.step(rng.uniform(-1.0, 1.0, size=(4, 1)) * mjx.single_action_space.high)
        kept.append((out, copy.deepcopy(out)))
    assert any(o[2].any() for o, _ in kept)          # envs ended and restarted
    for out, then in kept:
        for now, was in zip(out[:4], then[:4]):
            np.testing.assert_array_equal(now, was)
        for key in ("u", "t", "status", "message"):
            assert list(out[4][key]) == list(then[4][key])
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


def test_mjx_vector_env_equals_the_cpu_one_through_an_ending_of_every_env():
    # randomised machines, a fall angle inside x0's range: every env falls, is reset and
    # runs again; rewards, terminations, truncations and observations as the CPU env's
    cpu, mjx = _vector_envs("pendulum_mujoco_randomized", 6,
                            overrides={"task.fall_angle": 0.11, "run.duration": 0.3})
    cpu.reset(seed=0)
    mjx.reset(seed=0)
    rng = np.random.default_rng(2)
    hi = cpu.single_action_space.high
    ended = np.zeros(6, dtype=int)
    for _ in range(320):          # past the 0.3 s horizon: at least a truncation each
        c = _same_step(cpu, mjx, rng.uniform(-1.0, 1.0, size=(6, 1)) * hi)
        ended += c[2] | c[3]
    assert (ended >= 1).all(), ended          # every env ended at least once
    cpu.close()
    mjx.close()


@pytest.mark.parametrize("autoreset_mode", ["NextStep", "SameStep"])
def test_mjx_vector_env_ends_a_diverged_env_as_the_cpu_one(autoreset_mode, tmp_path,
                                                          monkeypatch):
    monkeypatch.chdir(tmp_path)  # the CPU env's MuJoCo logs its warning to ./MUJOCO_LOG.TXT
    # gears of 10^11-10^12: the first push makes qacc huge, which MuJoCo's check finds (on
    # the CPU it resets the data; MJX's state would leave the finite numbers): every env
    # ends "diverged" with the plant's words, keeps its first observation, earns nothing
    # and starts again, on both backends alike (_same_step: messages too)
    over = {"randomize.gear.low": 1e11, "randomize.gear.high": 1e12, "task.fall_angle": 0.0}
    cpu, mjx = _vector_envs("pendulum_mujoco_randomized", 4, overrides=over,
                            autoreset_mode=autoreset_mode)
    first, _ = cpu.reset(seed=0)
    mjx.reset(seed=0)
    a = np.full((4, 1), 0.5) * cpu.single_action_space.high
    endings = 0
    for _ in range(3):                       # an ending, the autoreset, an ending again
        c = _same_step(cpu, mjx, a)
        if c[2].any():
            endings += 1
            assert c[2].all() and (c[1] == 0.0).all() and (c[4]["status"] == "diverged").all()
            assert all("MuJoCo found NaN, Inf or huge values" in w for w in c[4]["message"])
            np.testing.assert_array_equal(c[0], first)     # the last finite observation
    assert endings >= 2
    cpu.close()
    mjx.close()


def test_brax_env_draws_a_machine_per_env_and_steps_without_a_host_call():
    pytest.importorskip("brax")
    import jax
    import jax.numpy as jnp

    from tspend.mjx.brax_env import BraxEnv

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = BraxEnv("pendulum_mujoco_randomized", control_period=0.02, machines=16)
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 8))
    picked = np.asarray(states.info["machine"])
    assert len(set(picked.tolist())) > 1
    masses = np.array([np.asarray(env.machine(int(i)).body_mass) for i in picked])
    # different picks, different machines: the CPU's at those seeds
    assert len({tuple(m) for m in masses}) == len(set(picked.tolist()))
    assert not np.array_equal(np.asarray(states.obs[0]), np.asarray(states.obs[1])) or \
        picked[0] == picked[1]
    step = jax.jit(jax.vmap(env.step))
    actions = jax.device_put(jnp.zeros((8, 1), dtype=states.obs.dtype))
    # no callback in the step's program, and no transfer while it runs
    text = str(jax.make_jaxpr(jax.vmap(env.step))(states, actions))
    assert "callback" not in text
    step(states, actions)                      # compiled outside the guard
    with jax.transfer_guard("disallow"):
        states = step(states, actions)
        jax.block_until_ready(states)
    assert np.isfinite(np.asarray(states.reward)).all()


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
