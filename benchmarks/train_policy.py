"""Train a PPO policy on a tspend gym env and export it as ONNX for the ``policy`` kind.

    nice python benchmarks/train_policy.py pendulum_mujoco --seed 1

Needs the ``train`` extra (stable-baselines3, torch) and ``rl`` (onnxruntime, for the
check at the end).  Writes ``models/policies/<scenario>.onnx`` and, beside it,
``<scenario>.json`` (how it was made: steps, seed, wall time, the reward curve, the
library versions, the command) and ``<scenario>.md`` (the same, for people).

What is trained (docs/gym.md, "The committed policy"):

* the env ``tspend/<scenario>-v0`` with ``control_period`` (default 20 ms: short episodes
  in env steps) and ``init_noise`` on ``plant.x0`` (the policy sees more than one start);
* the policy sees the task's view and the reference (``hinge, hinge_dot, r, r', r''`` on
  the cart-pole), not the cart: the cart drifts freely and the task does not ask for it,
  so its position would only take the policy out of what it was trained on;
* actions in [-1, 1], scaled by ``--u-max`` (N) to the actuator: PPO's Gaussian starts
  near unit spread, which on the actuator's +/-2000 N would throw the pole;
* observation normalisation (VecNormalize's running mean and variance), the selection
  of the entries, the clip to [-1, 1] and the scaling are all baked into the exported
  graph, which takes the env's full observation and returns the force in newtons.

The ONNX graph is built by hand from the actor's weights (``onnx.helper``): the
deterministic action is the mean, ``tanh`` MLP then a linear head.  During training the
policy is evaluated every ``--eval-every`` steps on one deterministic episode of
``--eval-duration`` s (no init noise); the best so far is what is exported.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import shlex
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def selection(env, inputs: str = "view") -> list[int]:
    """The observation entries the policy sees: the task's view and the reference
    (``view``), or the plant's whole state (``full``: a double cart-pole is balanced on
    both links and the cart, which the view of the lower link does not show)."""
    u = env.unwrapped
    N = len(u.task.names)
    if inputs == "full":
        return list(range(N))
    return [int(j) for j in u.task.view_index] + list(range(N, N + u.order + 1))


def sb3_vector(venv, idx: list[int], u_max: float):
    """A gymnasium vector env (``SAME_STEP`` autoreset) as a stable-baselines3 VecEnv:
    the policy's entries of the observation, actions in [-1, 1] meaning +/-u_max, the
    episodes' returns and lengths in ``info["episode"]`` (as SB3's Monitor writes them)."""
    import gymnasium
    from stable_baselines3.common.vec_env import VecEnv

    class Adapter(VecEnv):
        def __init__(self) -> None:
            n = venv.num_envs
            super().__init__(n, gymnasium.spaces.Box(-np.inf, np.inf, shape=(len(idx),)),
                             gymnasium.spaces.Box(-1.0, 1.0, shape=(1,)))
            self.idx = np.asarray(idx)
            self._seed: int | None = None
            self._return, self._length = np.zeros(n), np.zeros(n, dtype=np.int64)
            self._actions = np.zeros((n, 1))

        def reset(self):
            obs, _ = venv.reset(seed=self._seed)
            self._seed = None
            self._return[:], self._length[:] = 0.0, 0
            return obs[:, self.idx]

        def step_async(self, actions) -> None:
            self._actions = np.clip(np.asarray(actions, dtype=float).reshape(-1, 1), -1, 1)

        def step_wait(self):
            obs, reward, term, trunc, info = venv.step(self._actions * u_max)
            self._return += reward
            self._length += 1
            done = term | trunc
            infos: list[dict] = [{} for _ in range(self.num_envs)]
            for i in np.flatnonzero(done):
                infos[i] = {"terminal_observation": info["final_obs"][i][self.idx],
                            "TimeLimit.truncated": bool(trunc[i] and not term[i]),
                            "episode": {"r": float(self._return[i]),
                                        "l": int(self._length[i]), "t": 0.0}}
                self._return[i], self._length[i] = 0.0, 0
            return obs[:, self.idx], reward.astype(np.float32), done, infos

        def seed(self, seed=None):
            self._seed = seed
            return [None if seed is None else seed + i for i in range(self.num_envs)]

        def close(self) -> None:
            venv.close()

        def get_attr(self, name, indices=None):
            return [getattr(venv, name)] * self.num_envs

        def set_attr(self, name, value, indices=None) -> None:
            raise AttributeError(name)

        def env_method(self, name, *args, indices=None, **kwargs):
            raise AttributeError(name)

        def env_is_wrapped(self, wrapper_class, indices=None):
            return [False] * self.num_envs

    return Adapter()


def make_env(scenario: str, period: float, init_noise: list[float], u_max: float,
             duration: float | None, inputs: str = "view", reward=None):
    import gymnasium
    from gymnasium.wrappers import TransformObservation

    import tspend.gym  # noqa: F401  (registers the ids)

    overrides = {"run.duration": duration} if duration else None
    env = gymnasium.make(f"tspend/{scenario}-v0", control_period=period,
                         init_noise=tuple(init_noise), overrides=overrides, reward=reward)
    idx = selection(env, inputs)
    space = gymnasium.spaces.Box(-np.inf, np.inf, shape=(len(idx),), dtype=np.float64)
    env = TransformObservation(env, lambda o: o[idx], space)
    # the policy acts in [-1, 1] and means +/-u_max newtons
    env = gymnasium.wrappers.TransformAction(
        env, lambda a: np.clip(np.asarray(a, dtype=float), -1.0, 1.0) * u_max,
        gymnasium.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float64))
    return env


class Actor:
    """The deterministic actor as plain arrays: select, normalise, MLP, clip, scale."""

    def __init__(self, model, vecnorm, idx: list[int], u_max: float) -> None:
        import torch

        pol = model.policy
        layers = [m for m in pol.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear)]
        self.W = [m.weight.detach().cpu().numpy().astype(np.float32) for m in layers]
        self.b = [m.bias.detach().cpu().numpy().astype(np.float32) for m in layers]
        self.W.append(pol.action_net.weight.detach().cpu().numpy().astype(np.float32))
        self.b.append(pol.action_net.bias.detach().cpu().numpy().astype(np.float32))
        rms = vecnorm.obs_rms
        self.mean = rms.mean.astype(np.float32)
        self.scale = (1.0 / np.sqrt(rms.var + vecnorm.epsilon)).astype(np.float32)
        self.clip = float(vecnorm.clip_obs)
        self.idx = np.asarray(idx, dtype=np.int64)
        self.u_max = float(u_max)

    def __call__(self, obs: np.ndarray) -> float:
        h = np.clip((obs[self.idx].astype(np.float32) - self.mean) * self.scale,
                    -self.clip, self.clip)
        for W, b in zip(self.W[:-1], self.b[:-1]):
            h = np.tanh(W @ h + b)
        a = self.W[-1] @ h + self.b[-1]
        return float(np.clip(a[0], -1.0, 1.0) * self.u_max)

    def onnx(self, width: int, metadata: dict[str, str]):
        """The graph: obs (batch, width) float32 -> action (batch, 1) float32, in newtons."""
        import onnx
        from onnx import TensorProto, helper, numpy_helper

        inits = [numpy_helper.from_array(self.idx, "idx"),
                 numpy_helper.from_array(self.mean, "mean"),
                 numpy_helper.from_array(self.scale, "scale"),
                 numpy_helper.from_array(np.float32(-self.clip), "lo"),
                 numpy_helper.from_array(np.float32(self.clip), "hi"),
                 numpy_helper.from_array(np.float32(-1.0), "m1"),
                 numpy_helper.from_array(np.float32(1.0), "p1"),
                 numpy_helper.from_array(np.array([self.u_max], dtype=np.float32), "u_max")]
        nodes = [helper.make_node("Gather", ["obs", "idx"], ["sel"], axis=1),
                 helper.make_node("Sub", ["sel", "mean"], ["centred"]),
                 helper.make_node("Mul", ["centred", "scale"], ["scaled"]),
                 helper.make_node("Clip", ["scaled", "lo", "hi"], ["h0"])]
        h = "h0"
        for k, (W, b) in enumerate(zip(self.W, self.b)):
            inits += [numpy_helper.from_array(W.T.copy(), f"W{k}"),
                      numpy_helper.from_array(b, f"b{k}")]
            nodes += [helper.make_node("MatMul", [h, f"W{k}"], [f"z{k}"]),
                      helper.make_node("Add", [f"z{k}", f"b{k}"], [f"a{k}"])]
            if k < len(self.W) - 1:
                nodes.append(helper.make_node("Tanh", [f"a{k}"], [f"h{k + 1}"]))
                h = f"h{k + 1}"
        last = f"a{len(self.W) - 1}"
        nodes += [helper.make_node("Clip", [last, "m1", "p1"], ["unit"]),
                  helper.make_node("Mul", ["unit", "u_max"], ["action"])]
        graph = helper.make_graph(
            nodes, "tspend_policy",
            [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", width])],
            [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", 1])],
            inits)
        model = helper.make_model(graph, producer_name="tspend benchmarks/train_policy.py",
                                  opset_imports=[helper.make_opsetid("", 17)])
        model.ir_version = 8
        for key, value in metadata.items():
            entry = model.metadata_props.add()
            entry.key, entry.value = key, value
        onnx.checker.check_model(model)
        return model


def evaluate(actor: Actor, scenario: str, period: float, duration: float) -> dict:
    """One deterministic episode from ``plant.x0``: its return, length and the rms
    tracking error of the view's first entry over the second half (rmse_ss's window)."""
    import tspend.gym

    env = tspend.gym.TspendEnv(scenario, control_period=period,
                               overrides={"run.duration": duration})
    obs, _ = env.reset(seed=0)
    N = len(env.task.names)
    out, errs, ret = 0, [], 0.0
    while True:
        e = obs[env.task.view_index[0]] - obs[N]
        if env.t >= 0.5 * duration:
            errs.append(e)
        obs, r, term, trunc, info = env.step(np.array([actor(obs)]))
        ret += r
        out += 1
        if term or trunc:
            break
    env.close()
    rmse = math.sqrt(float(np.mean(np.square(errs)))) if errs else math.inf
    return {"return": ret, "steps": out, "status": info["status"], "t_end": env.t,
            "rmse_ss_approx": rmse if info["status"] == "completed" else math.inf}


def _rank(result: dict) -> tuple[float, float, float]:
    """Which evaluation is better (smaller): a completed episode by its error, else the
    one that lasted longer, then the return."""
    return result["rmse_ss_approx"], -result.get("t_end", 0.0), -result["return"]


def card_markdown(card: dict, name: str) -> str:
    """The model card for people: how it was made, from the JSON beside it."""
    best = card["best"]
    lines = [f"# {name}: PPO policy for `{card['scenario']}`", "",
             "Made by `benchmarks/train_policy.py` (docs/gym.md); every number below is in "
             f"`{Path(name).with_suffix('.json').name}`.", "",
             f"- command: `{card['command']}`",
             f"- {card['algorithm']}, {card['timesteps']} timesteps, seed {card['seed']}, "
             f"wall time {card['wall_s']:.0f} s, {card['n_envs']} envs",
             f"- control period {card['control_period_s']} s; action 1 = {card['u_max_N']} N; "
             f"init noise on plant.x0 {card['init_noise']}; training episodes "
             f"{card['training_episode_s']} s",
             f"- inputs the policy uses: {', '.join(card['policy_inputs'])} (of the env's "
             f"full observation; normalisation baked into the graph)",
             f"- reward: `{card['reward']['formula']}` with alive = {card['reward']['alive']}, "
             f"tracking = {card['reward']['tracking']}, control = {card['reward']['control']}",
             f"- hyperparameters: {json.dumps(card['hyperparameters'])}",
             f"- versions: {json.dumps(card['versions'])}", "",
             f"Exported: the evaluation at {best.get('timesteps')} timesteps (the best of "
             f"{len(card['evaluations'])}): one deterministic {best.get('t_end', 0):.0f} s "
             f"episode, status {best.get('status')}, rms error over its second half "
             f"{best.get('rmse_ss_approx', float('nan')):.4g} rad (env samples).", "",
             "## Reward curve (mean episode return of the last 100 training episodes)", "",
             "| timesteps | wall s | mean return | mean length (steps) |",
             "| ---: | ---: | ---: | ---: |"]
    curve = card["reward_curve"]
    stride = max(1, len(curve) // 25)
    for row in curve[::stride] + ([curve[-1]] if curve and (len(curve) - 1) % stride else []):
        lines.append(f"| {row['timesteps']} | {row['wall_s']:.0f} | {row['ep_return_mean']:.2f} "
                     f"| {row['ep_length_mean']:.0f} |")
    lines += ["", "## Evaluations (deterministic, from plant.x0)", "",
              "| timesteps | status | t_end s | return | rmse (2nd half) rad |",
              "| ---: | --- | ---: | ---: | ---: |"]
    for e in card["evaluations"]:
        lines.append(f"| {e['timesteps']} | {e['status']} | {e['t_end']:.2f} | "
                     f"{e['return']:.2f} | {e['rmse_ss_approx']:.4g} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scenario", nargs="?", default="pendulum_mujoco")
    p.add_argument("--steps", type=int, default=300_000, help="PPO timesteps")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--period", type=float, default=0.02, help="control period (s)")
    p.add_argument("--u-max", type=float, default=100.0, help="force of action 1 (N)")
    p.add_argument("--init-noise", type=float, nargs="+", default=[0.15, 0.15])
    p.add_argument("--duration", type=float, default=20.0, help="training episode (s)")
    p.add_argument("--n-envs", type=int, default=4)
    p.add_argument("--eval-every", type=int, default=50_000)
    p.add_argument("--eval-duration", type=float, default=10.0)
    p.add_argument("--lr", type=float, default=1e-3, help="learning rate")
    p.add_argument("--gamma", type=float, default=0.98)
    p.add_argument("--n-steps", type=int, default=512, help="rollout per env")
    p.add_argument("--batch", type=int, default=128)
    p.add_argument("--log-std", type=float, default=-1.0, help="initial log std of actions")
    p.add_argument("--max-minutes", type=float, default=0.0, help="stop after (0: never)")
    p.add_argument("--out", type=Path, default=None, help="default models/policies/SCENARIO.onnx")
    p.add_argument("--reward", type=float, nargs="+", default=None,
                   metavar="W", help="alive, then tracking weights, then control (default: "
                   "tspend.gym.RewardWeights()); e.g. 10 10 0.1 0.1")
    p.add_argument("--inputs", choices=("view", "full"), default="view",
                   help="the policy sees the view and the reference, or the whole state")
    p.add_argument("--vector", choices=("monitor", "tspend", "sync"), default="monitor",
                   help="envs: SB3's DummyVecEnv of Monitor-wrapped envs (the committed "
                        "cart-pole policy's way), tspend's vector env, or gymnasium's "
                        "make_vec 'sync' (both through one adapter, SAME_STEP autoreset)")
    a = p.parse_args(argv)

    import onnx
    import stable_baselines3
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    import tspend.gym

    torch.set_num_threads(1)
    out = a.out or ROOT / "models" / "policies" / f"{a.scenario}.onnx"
    out.parent.mkdir(parents=True, exist_ok=True)

    def factory(rank: int):
        def make():
            return Monitor(make_env(a.scenario, a.period, a.init_noise, a.u_max, a.duration,
                                    a.inputs, weights))
        return make

    weights = tspend.gym.RewardWeights() if not a.reward else tspend.gym.RewardWeights(
        alive=a.reward[0], tracking=tuple(a.reward[1:-1]), control=a.reward[-1])
    probe = tspend.gym.TspendEnv(a.scenario, control_period=a.period)
    idx = selection(probe, a.inputs)
    if a.vector == "monitor":
        inner = DummyVecEnv([factory(i) for i in range(a.n_envs)])
    else:
        import gymnasium
        from gymnasium.vector import AutoresetMode

        options = dict(control_period=a.period, init_noise=tuple(a.init_noise), reward=weights,
                       overrides={"run.duration": a.duration} if a.duration else None)
        mode = {"tspend": "vector_entry_point", "sync": "sync"}[a.vector]
        extra = dict(autoreset_mode=AutoresetMode.SAME_STEP) if a.vector == "tspend" else \
            dict(vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP})
        inner = sb3_vector(gymnasium.make_vec(f"tspend/{a.scenario}-v0", num_envs=a.n_envs,
                                              vectorization_mode=mode, **extra, **options),
                           idx, a.u_max)
    venv = VecNormalize(inner, norm_obs=True, norm_reward=True, clip_obs=10.0, gamma=a.gamma)
    venv.seed(a.seed)
    names = probe.observation_names
    model = PPO("MlpPolicy", venv, seed=a.seed, n_steps=a.n_steps, batch_size=a.batch,
                n_epochs=10, gamma=a.gamma, gae_lambda=0.95, learning_rate=a.lr, ent_coef=0.0,
                clip_range=0.2,
                policy_kwargs=dict(net_arch=dict(pi=[64, 64], vf=[64, 64]),
                                   activation_fn=torch.nn.Tanh, log_std_init=a.log_std),
                verbose=0, device="cpu")

    started = time.perf_counter()
    curve: list[dict] = []
    evals: list[dict] = []
    best = {"rmse_ss_approx": math.inf, "return": -math.inf, "t_end": 0.0}
    metadata_base = {
        "tspend.scenario": a.scenario, "tspend.plant_kind": probe.scenario.plant.kind,
        "tspend.control_period": repr(probe.control_period),
        "tspend.observation_names": json.dumps(list(names)),
        "tspend.observation_units": json.dumps(list(probe.observation_units)),
        "tspend.view": json.dumps(list(probe.task.view)),
        "tspend.u_max": repr(a.u_max)}

    def export(actor: Actor, timesteps: int, result: dict) -> None:
        meta = dict(metadata_base, **{"tspend.timesteps": str(timesteps),
                                      "tspend.seed": str(a.seed)})
        tmp = out.with_suffix(".onnx.tmp")
        onnx.save(actor.onnx(len(names), meta), str(tmp))
        tmp.replace(out)

    class Progress(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.next_eval = a.eval_every

        def _on_rollout_end(self) -> None:
            buf = self.model.ep_info_buffer
            if buf:
                curve.append({"timesteps": int(self.num_timesteps),
                              "wall_s": round(time.perf_counter() - started, 1),
                              "ep_return_mean": float(np.mean([e["r"] for e in buf])),
                              "ep_length_mean": float(np.mean([e["l"] for e in buf]))})

        def _on_step(self) -> bool:
            if self.num_timesteps >= self.next_eval:
                self.next_eval += a.eval_every
                actor = Actor(self.model, venv, idx, a.u_max)
                result = evaluate(actor, a.scenario, a.period, a.eval_duration)
                result.update(timesteps=int(self.num_timesteps),
                              wall_s=round(time.perf_counter() - started, 1))
                evals.append(result)
                better = _rank(result) < _rank(best)
                if better:
                    best.clear()
                    best.update(result)
                    export(actor, int(self.num_timesteps), result)
                print(json.dumps(result), "best" if better else "", flush=True)
            if a.max_minutes and time.perf_counter() - started > 60 * a.max_minutes:
                print("stopping: --max-minutes reached", flush=True)
                return False
            return True

    model.learn(total_timesteps=a.steps, callback=Progress())
    wall = time.perf_counter() - started
    final = Actor(model, venv, idx, a.u_max)
    result = evaluate(final, a.scenario, a.period, a.eval_duration)
    result.update(timesteps=int(model.num_timesteps), wall_s=round(wall, 1))
    evals.append(result)
    if _rank(result) < _rank(best):
        best.clear()
        best.update(result)
        export(final, int(model.num_timesteps), result)

    # the exported graph against the numpy actor it was built from
    import onnxruntime

    sess = onnxruntime.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    probe.reset(seed=0)
    obs = probe.step(np.zeros(1))[0]
    onnx_u = float(sess.run(None, {"obs": obs[None].astype(np.float32)})[0][0, 0])

    card = {
        "scenario": a.scenario, "algorithm": "PPO (stable-baselines3)",
        "command": "nice python benchmarks/train_policy.py " + shlex.join(sys.argv[1:]
                                                                          if argv is None else argv),
        "timesteps": int(model.num_timesteps), "seed": a.seed, "wall_s": round(wall, 1),
        "control_period_s": a.period, "u_max_N": a.u_max, "init_noise": a.init_noise,
        "training_episode_s": a.duration, "n_envs": a.n_envs, "envs": a.vector,
        "inputs": a.inputs,
        "throughput_env_steps_per_s": round(int(model.num_timesteps) / wall, 1),
        "reward": {"formula": "T * alive / (1 + sum_i tracking_i e_i^2 + control (u/u_scale)^2)",
                   **weights.__dict__},
        "policy_inputs": [names[i] for i in idx],
        "hyperparameters": {"n_steps": a.n_steps, "batch_size": a.batch, "n_epochs": 10,
                            "gamma": a.gamma, "gae_lambda": 0.95, "learning_rate": a.lr,
                            "net_arch": [64, 64], "activation": "tanh",
                            "log_std_init": a.log_std,
                            "VecNormalize": {"norm_obs": True, "norm_reward": True,
                                             "clip_obs": 10.0}},
        "best": best, "evaluations": evals, "reward_curve": curve,
        "onnx_check": {"obs": obs.tolist(), "onnx_u": onnx_u},
        "versions": {"stable_baselines3": stable_baselines3.__version__,
                     "torch": torch.__version__, "onnx": onnx.__version__,
                     "onnxruntime": onnxruntime.__version__,
                     "python": platform.python_version()},
    }
    out.with_suffix(".json").write_text(json.dumps(card, indent=1) + "\n")
    out.with_suffix(".md").write_text(card_markdown(card, out.name))
    print(json.dumps(best))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
