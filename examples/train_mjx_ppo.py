"""Train a policy for a tspend scenario with brax's PPO on MJX, export it to ONNX, and run it
on the CPU backend with the ``policy`` controller kind.

    python examples/train_mjx_ppo.py                       # a tiny budget: runs on a CPU
    python examples/train_mjx_ppo.py --timesteps 20000000 --envs 2048 --out pendulum.onnx

The environment is :class:`tspend.mjx.brax_env.BraxEnv` (the scenario's machine, task,
observation and reward, its physics stepped by MJX); the policy is brax's PPO network
(tanh layers, observations normalised), exported as the graph the ``policy`` kind runs:
[full state, r .. r^(n)] -> normalise -> MLP -> tanh -> times ``--action-scale``.  The
export is checked against brax's own deterministic policy on random observations before
it is written.  The default budget only shows that the pipeline runs (the policy is not
trained by it); a GPU trains the balance in minutes with the second command
(docs/accelerator.md).  Needs ``pip install 'tspend[mjx]' brax``.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import time
from pathlib import Path


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description="Train a tspend scenario with brax's PPO on MJX and "
                                            "export the policy to ONNX.")
    p.add_argument("--scenario", default="pendulum_mujoco",
                   help="the scenario to train on (default pendulum_mujoco)")
    p.add_argument("--timesteps", type=int, default=1024,
                   help="environment steps of training (default 1024: a smoke run on a CPU; "
                        "a GPU run takes 10^7 or more)")
    p.add_argument("--envs", type=int, default=8, help="environments stepped at once (default 8)")
    p.add_argument("--episode-steps", type=int, default=50,
                   help="env steps per training episode (default 50)")
    p.add_argument("--control-period", type=float, default=0.02,
                   help="seconds per env step, the action held over it (default 0.02)")
    p.add_argument("--action-scale", type=float, default=100.0,
                   help="the actuator's unit per unit of action (default 100, N on the cart-pole)")
    p.add_argument("--precision", choices=("float64", "float32"), default="float32",
                   help="MJX's float width (default float32, what a GPU trains in)")
    p.add_argument("--seed", type=int, default=0, help="PPO's seed (default 0)")
    p.add_argument("--out", default="mjx_policy.onnx",
                   help="the ONNX file to write (default mjx_policy.onnx; an existing file is "
                        "not overwritten)")
    p.add_argument("--check-run", type=float, default=1.0,
                   help="seconds of the scenario to run on the CPU with the exported policy "
                        "(default 1; 0: skip)")
    return p


def export_onnx(params, obs_size: int, action_scale: float, meta: dict, path: Path) -> bytes:
    """The deterministic policy of brax's PPO ``params`` (normaliser, policy MLP) as ONNX."""
    import numpy as np
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    normalizer, policy = params[0], params[1]
    mean = np.asarray(normalizer.mean, dtype=np.float32).reshape(-1)
    std = np.asarray(normalizer.std, dtype=np.float32).reshape(-1)
    layers = policy["params"]
    names = sorted(layers, key=lambda k: int(k.split("_")[-1]))
    inits = [numpy_helper.from_array(mean, "mean"), numpy_helper.from_array(std, "std"),
             numpy_helper.from_array(np.array([0], dtype=np.int64), "loc"),
             numpy_helper.from_array(np.array([action_scale], dtype=np.float32), "u_max")]
    nodes = [helper.make_node("Sub", ["obs", "mean"], ["centred"]),
             helper.make_node("Div", ["centred", "std"], ["h0"])]
    h = "h0"
    for i, name in enumerate(names):
        W = np.asarray(layers[name]["kernel"], dtype=np.float32)
        b = np.asarray(layers[name]["bias"], dtype=np.float32)
        inits += [numpy_helper.from_array(W, f"W{i}"), numpy_helper.from_array(b, f"b{i}")]
        nodes += [helper.make_node("MatMul", [h, f"W{i}"], [f"z{i}"]),
                  helper.make_node("Add", [f"z{i}", f"b{i}"], [f"a{i}"])]
        h = f"a{i}"
        if i < len(names) - 1:
            nodes.append(helper.make_node("Tanh", [h], [f"h{i + 1}"]))
            h = f"h{i + 1}"
    # the network outputs (loc, scale) of a tanh-normal: the deterministic action is tanh(loc)
    nodes += [helper.make_node("Gather", [h, "loc"], ["mean_action"], axis=1),
              helper.make_node("Tanh", ["mean_action"], ["unit"]),
              helper.make_node("Mul", ["unit", "u_max"], ["action"])]
    graph = helper.make_graph(
        nodes, "tspend_mjx_ppo",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", obs_size])],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", 1])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    for k, v in meta.items():
        model.metadata_props.append(onnx.StringStringEntryProto(key=k, value=str(v)))
    onnx.checker.check_model(model)
    return model.SerializeToString()


def _jax_compat(jax) -> None:
    """brax 0.14 calls jax.device_put_replicated, which JAX 0.10 removed: its drop-in
    (JAX's pmap migration notes), a copy of x per device stacked on a leading axis."""
    try:
        jax.device_put_replicated
    except AttributeError:
        import jax.numpy as jnp

        def device_put_replicated(x, devices):
            stacked = jax.tree_util.tree_map(lambda a: jnp.stack([jnp.asarray(a)] * len(devices)), x)
            return jax.device_put(stacked, devices[0]) if len(devices) == 1 else \
                jax.device_put_sharded([jax.tree_util.tree_map(lambda a: a[i], stacked)
                                        for i in range(len(devices))], devices)

        jax.device_put_replicated = device_put_replicated


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    out = Path(args.out)
    if out.exists():
        print(f"train_mjx_ppo: {out} exists; choose another --out", file=sys.stderr)
        return 2
    for name, value, low, high in (("--timesteps", args.timesteps, 1, 10**10),
                                   ("--envs", args.envs, 1, 1 << 16),
                                   ("--episode-steps", args.episode_steps, 1, 10**6)):
        if not low <= value <= high:
            print(f"train_mjx_ppo: {name} {value}: from {low} to {high}", file=sys.stderr)
            return 2
    import jax
    import numpy as np

    _jax_compat(jax)
    from brax.training.agents.ppo import networks as ppo_networks
    from brax.training.agents.ppo import train as ppo

    from tspend.mjx.brax_env import BraxEnv

    env = BraxEnv(args.scenario, control_period=args.control_period,
                  action_scale=args.action_scale, precision=args.precision)
    factory = functools.partial(ppo_networks.make_ppo_networks,
                                policy_hidden_layer_sizes=(32, 32),
                                value_hidden_layer_sizes=(64, 64), activation=jax.numpy.tanh)
    started = time.perf_counter()
    make_policy, params, metrics = ppo.train(
        environment=env, num_timesteps=args.timesteps, episode_length=args.episode_steps,
        num_envs=args.envs, batch_size=args.envs, num_minibatches=2, unroll_length=8,
        num_updates_per_batch=2, normalize_observations=True, learning_rate=3e-4,
        num_evals=2, num_eval_envs=args.envs, seed=args.seed, network_factory=factory)
    took = time.perf_counter() - started
    print(f"trained {args.timesteps} steps in {took:.1f} s on {jax.devices()[0].platform}; "
          f"eval reward {float(metrics.get('eval/episode_reward', float('nan'))):.4g}")

    template = env.template
    meta = {"tspend.scenario": args.scenario, "tspend.plant_kind": template.scenario.plant.kind,
            "tspend.control_period": template.control_period,
            "tspend.observation_names": json.dumps(list(template.observation_names)),
            "tspend.view": json.dumps(list(template.task.view)),
            "tspend.u_max": args.action_scale, "tspend.timesteps": args.timesteps,
            "tspend.seed": args.seed, "tspend.trainer": "brax PPO on MJX"}
    blob = export_onnx(params, env.observation_size, args.action_scale, meta, out)

    # the export against brax's own deterministic policy, before anything is written
    import onnxruntime

    session = onnxruntime.InferenceSession(blob, providers=["CPUExecutionProvider"])
    policy = make_policy(params, deterministic=True)
    obs = np.random.default_rng(0).normal(size=(16, env.observation_size)).astype(np.float32)
    want = np.array([float(policy(jax.numpy.asarray(o), jax.random.PRNGKey(0))[0][0])
                     for o in obs]) * args.action_scale
    got = session.run(None, {"obs": obs})[0].reshape(-1)
    gap = float(np.max(np.abs(got - want)))
    if not gap <= 1e-3 * args.action_scale:
        print(f"train_mjx_ppo: the ONNX export departs from brax's policy by {gap:.3g}; "
              f"nothing written", file=sys.stderr)
        return 1
    out.write_bytes(blob)
    print(f"wrote {out} (the export matches brax's policy to {gap:.2g})")

    if args.check_run > 0:
        import tspend
        from tspend.scenario import load_scenario, override

        scn = override(load_scenario(args.scenario), **{
            "run.duration": args.check_run, "controllers.policy.path": str(out.resolve())})
        result = tspend.run(scn, controller="policy", keep_history=False)
        print(f"the CPU policy kind ran it: {result.status}, rmse "
              f"{result.metrics['rmse']:.4g} over {args.check_run:g} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
