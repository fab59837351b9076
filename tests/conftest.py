"""Test-session settings that must precede the first ``import mujoco``."""

import os

# MuJoCo picks its OpenGL backend when it is imported; CI has no display, and EGL (Mesa's
# or a GPU's) is what renders headless here (the gym env's rgb_array, check_env's render)
os.environ.setdefault("MUJOCO_GL", "egl")
