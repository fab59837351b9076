"""The ``policy`` kind on the committed ONNX policy (models/policies/pendulum_mujoco.onnx):
through the CLI as a user types it, and against onnxruntime evaluated directly on the gym
env's observations (the env and the runner build the same rows)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

onnxruntime = pytest.importorskip("onnxruntime")
gymnasium = pytest.importorskip("gymnasium")

import tspend  # noqa: E402
from cli_harness import ROOT, tspend as tspend_cli  # noqa: E402
from tspend.gym import TspendEnv  # noqa: E402

POLICY = ROOT / "models" / "policies" / "pendulum_mujoco.onnx"


def test_the_scenario_names_the_committed_policy() -> None:
    scn = tspend.load_scenario("pendulum_mujoco")
    assert dict(scn.controllers)["policy"].path == "models/policies/pendulum_mujoco.onnx"
    assert POLICY.is_file()
    card = json.loads(POLICY.with_suffix(".json").read_text())
    assert card["timesteps"] > 0 and card["reward_curve"] and "stable_baselines3" in card["versions"]


def test_policy_kind_runs_through_the_cli(tmp_path: Path) -> None:
    res = tspend_cli("run", "pendulum_mujoco", "--controller", "policy", "--duration", "2",
                     "--metrics", "m.json", "--no-record", cwd=tmp_path)
    assert res.status == 0, res.err
    metrics = json.loads((tmp_path / "m.json").read_text())
    assert metrics["status"] == "completed"
    assert metrics["controller"]["kind"] == "policy"
    assert metrics["controller"]["settings"]["path"] == "models/policies/pendulum_mujoco.onnx"


def test_the_run_applies_what_onnxruntime_computes_on_the_envs_observation() -> None:
    """The env driven by the graph itself, evaluated here: the same states as the run."""
    duration = 1.0
    result = tspend.run("pendulum_mujoco", controller="policy", duration=duration)
    assert result.status == "completed"
    period = result.controller.sample_period
    assert period > 0.0
    sess = onnxruntime.InferenceSession(str(POLICY), providers=["CPUExecutionProvider"])
    env = TspendEnv("pendulum_mujoco", control_period=period,
                    overrides={"run.duration": duration})
    obs, _ = env.reset(seed=1)
    states, us = [], []
    while True:
        u = float(sess.run(None, {"obs": obs[None].astype(np.float32)})[0][0, 0])
        states.append(obs[:4].copy())
        us.append(u)
        obs, _, term, trunc, _ = env.step(np.array([u]))
        if term or trunc:
            break
    every = env.frame_skip
    np.testing.assert_allclose(np.array(states), result.history["state"][::every], atol=1e-9)
    np.testing.assert_allclose(np.array(us), result.history["u"][::every], rtol=1e-6)
    # held in between: zero-order hold over the period
    assert np.all(result.history["u"][1:every] == result.history["u"][0])


@pytest.mark.parametrize("path, message", [
    ("nowhere.onnx", "no such file"),
    ("scenarios/pendulum_mujoco.toml", "not an ONNX model"),
])
def test_a_bad_path_is_one_line_and_exit_2(tmp_path: Path, path: str, message: str) -> None:
    res = tspend_cli("run", "pendulum_mujoco", "--controller", "policy", "--duration", "1",
                     "--metrics", "m.json", "--set", f"controllers.policy.path={path}",
                     cwd=tmp_path)
    assert res.status == 2
    line = res.one_error_line()
    assert message in line and "controllers.policy.path" in line
    assert list(tmp_path.iterdir()) == []        # nothing written


def test_a_policy_of_another_machine_is_refused(tmp_path: Path) -> None:
    res = tspend_cli("run", "furuta_mujoco", "--controller", "policy", "--duration", "1",
                     "--set", f"controllers.policy.path={POLICY}", "--no-record", cwd=tmp_path)
    assert res.status == 2
    assert "trained on plant kind cartpole_mujoco" in res.one_error_line()
