"""Test-session settings that must precede the first ``import mujoco``, and fixtures
shared by several test modules."""

import os

import pytest

# MuJoCo picks its OpenGL backend when it is imported; CI has no display, and EGL (Mesa's
# or a GPU's) is what renders headless here (the gym env's rgb_array, check_env's render)
os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture
def paths(monkeypatch):
    """The loop each run took, in order ("compiled" or "generic")."""
    import tspend.loop.runner as runner_module

    taken: list[str] = []
    real = runner_module.ClosedLoop._loop

    def spy(self, sinks):
        try:
            return real(self, sinks)
        finally:
            taken.append(self.path)

    monkeypatch.setattr(runner_module.ClosedLoop, "_loop", spy)
    return taken
