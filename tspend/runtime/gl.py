"""Which OpenGL backend MuJoCo renders with, chosen before MuJoCo is imported.

MuJoCo's Python bindings read ``MUJOCO_GL`` once, when ``mujoco`` is first imported
(``glfw`` by default, which needs a display). On a machine without one (no ``DISPLAY`` or
``WAYLAND_DISPLAY``, a server, CI) tspend picks an off-screen backend instead: EGL when
its library is found, else OSMesa, so that rendering (the gym env's ``rgb_array``,
tools/screenshots.py) works without being told. A ``MUJOCO_GL`` the user set is never
changed.
"""

from __future__ import annotations

import ctypes.util
import os
import sys

__all__ = ["choose_headless_gl"]


def choose_headless_gl(environ: "os._Environ[str] | dict[str, str]" = os.environ) -> str:
    """Set ``MUJOCO_GL`` in ``environ`` for a machine without a display (module docstring)
    and return the backend in force ("" when MuJoCo's own default stays)."""
    if environ.get("MUJOCO_GL"):
        return environ["MUJOCO_GL"]
    if not sys.platform.startswith("linux") or environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY"):
        return ""
    for backend, library in (("egl", "EGL"), ("osmesa", "OSMesa")):
        if ctypes.util.find_library(library):
            environ["MUJOCO_GL"] = backend
            return backend
    return ""
