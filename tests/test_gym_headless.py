"""The gym env on a machine without a display, its normalised spaces, and its names.

Oracles: gymnasium's own env checker in a process with no display and no MUJOCO_GL, the
actuator's range (where -1 and +1 must land), and the names of ``RunResult.to_pandas()``.
"""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

from cli_harness import ROOT  # noqa: E402
from tspend.runtime.gl import choose_headless_gl  # noqa: E402


def test_an_off_screen_backend_is_chosen_only_without_a_display() -> None:
    assert choose_headless_gl({"MUJOCO_GL": "glfw"}) == "glfw"          # the user's stays
    assert choose_headless_gl({"DISPLAY": ":0"}) == ""                  # a display: MuJoCo's
    env: dict[str, str] = {}
    chosen = choose_headless_gl(env)
    if sys.platform.startswith("linux"):
        assert chosen in ("egl", "osmesa", "") and env.get("MUJOCO_GL", "") == chosen


def test_check_env_passes_headless_without_being_told() -> None:
    code = ("import gymnasium, tspend.gym; from gymnasium.utils.env_checker import check_env; "
            "check_env(gymnasium.make('tspend/pendulum_mujoco-v0', render_mode='rgb_array').unwrapped); "
            "env = gymnasium.make('tspend/pendulum_mujoco-v0', render_mode='rgb_array'); "
            "env.reset(seed=0); f = env.render(); print(f.shape, f.dtype, int(f.std() > 0))")
    environ = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY",
                                                                 "WAYLAND_DISPLAY", "PYOPENGL_PLATFORM")}
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=environ, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.split()[-1] == "1"          # a frame with something drawn in it


def test_normalised_spaces_map_onto_the_actuators_range() -> None:
    import tspend.gym  # noqa: F401

    env = gymnasium.make("tspend/pendulum_mujoco-v0", normalize=True)
    assert env.action_space.dtype == np.float32 and env.observation_space.dtype == np.float32
    assert float(env.action_space.low[0]) == -1.0 and float(env.action_space.high[0]) == 1.0
    obs, info = env.reset(seed=0)
    assert obs.dtype == np.float32 and env.observation_space.contains(obs)
    lo, hi = info["action_scale"]["lo"], info["action_scale"]["hi"]
    raw = env.unwrapped.plant.inputs[0]
    assert (lo, hi) == (raw.lo, raw.hi) and info["action_scale"]["unit"] == raw.unit
    for a, u in ((-1.0, lo), (1.0, hi), (0.0, 0.5 * (lo + hi))):
        env.reset(seed=0)
        _, _, _, _, info = env.step(np.array([a], dtype=np.float32))
        assert info["u"] == pytest.approx(u)


def test_the_info_names_states_as_the_export_and_metrics_do() -> None:
    import tspend
    import tspend.gym  # noqa: F401

    env = gymnasium.make("tspend/pendulum_mujoco-v0")
    _, info = env.reset(seed=0)
    frame = tspend.run("pendulum_mujoco", duration=0.01).to_pandas()
    assert set(info["state"]) <= set(frame.columns) and "hinge_rad" in info["state"]
    assert info["state"]["hinge_rad"] == pytest.approx(env.unwrapped.plant.full_state()[1])
