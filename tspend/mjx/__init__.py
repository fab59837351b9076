"""The MJX backend: N closed loops of a scenario stepped at once by MuJoCo's JAX engine.

MJX (``mujoco.mjx``) steps a MuJoCo model in JAX, so ``jax.vmap`` runs thousands of
machines in one call on an accelerator (or on JAX's CPU backend, where everything here is
tested).  This package gives tspend's machines, tasks and controllers that form
(docs/accelerator.md):

* :mod:`tspend.mjx.machines`: the machines of a scenario at N seeds, each the one the CPU
  backend builds at that seed (the scenario's ``[randomize]`` drawn by
  :mod:`tspend.plants.randomize`, the model compiled by the CPU plant), batched into one
  ``mjx.Model`` whose differing fields carry a leading env axis; the task's bounds, the
  reference and disturbance tables;
* :mod:`tspend.mjx.control`: the controller kinds that have a JAX form (those whose law
  is written once over an array namespace, :mod:`tspend.runtime.law`, and
  ``policy``), designed on the CPU as the CPU backend designs them;
* :mod:`tspend.mjx.sweep`: ``tspend sweep --backend mjx``: the closed loops in one
  ``jax.lax.scan``, each run's samples folded into the CPU's own metrics
  (:class:`tspend.loop.metrics.MetricsAccumulator`), one row per seed with the CPU
  sweep's columns;
* :mod:`tspend.mjx.vector_env`: ``gymnasium.make_vec(..., backend="mjx")``;
* :mod:`tspend.mjx.brax_env`: a functional env in brax's form (``reset(rng)``,
  ``step(state, action)``, jit- and vmap-able).

Precision: float64 by default (``jax_enable_x64``: the MJX step then agrees with CPU
MuJoCo to about 1e-16); ``precision="float32"`` trades that for speed on an accelerator
(the departure measured in docs/accelerator.md).  JAX holds the choice per process.

Needs ``pip install 'tspend[mjx]'`` (jax, mujoco-mjx, onnx).
"""

from __future__ import annotations

from tspend.runtime.errors import ScenarioError

__all__ = ["PRECISIONS", "require", "set_precision"]

#: the floating-point types a backend run may use
PRECISIONS = ("float64", "float32")


def require() -> None:
    """ScenarioError in one line when JAX or MJX is missing."""
    try:
        import jax  # noqa: F401
        _import_mjx_quietly()
    except ImportError as exc:
        raise ScenarioError(f"the mjx backend needs JAX and MuJoCo MJX ({exc.name or exc} is "
                            f"missing): pip install 'tspend[mjx]'") from None
    _require_device()


def _require_device() -> None:
    """ScenarioError in one line when JAX has no device to run on (``JAX_PLATFORMS=cuda``
    on a machine without a GPU: JAX's own error is an empty AssertionError)."""
    import os

    import jax

    try:
        jax.devices()
        jax.devices("cpu")   # the machines are built there (tspend.mjx.machines)
    except Exception as exc:  # noqa: BLE001 - whatever JAX raises for a platform it lacks
        asked = os.environ.get("JAX_PLATFORMS", "")
        reason = " ".join(str(exc).split())[:200] or "its platform could not be started"
        raise ScenarioError(f"the mjx backend: JAX has no device to run on"
                            + (f" with JAX_PLATFORMS={asked!r}" if asked else "")
                            + f" ({reason}); the mjx backend needs JAX's CPU device, and a GPU "
                              f"only where one and its jax build are installed: unset "
                              f"JAX_PLATFORMS or set it to 'cpu' or 'cuda,cpu'") from None


def _import_mjx_quietly() -> None:
    """Import MuJoCo MJX without its two lines "Failed to import warp: ..." and "Failed to
    import mujoco_warp: ..." (printed on stdout at its first import when NVIDIA Warp is not
    installed, in every sweep and env): tspend steps MJX's JAX implementation, never the
    Warp one, so the lines say nothing about a tspend run (issue 51). Only that import's
    stdout is held; an ImportError still propagates."""
    import contextlib
    import io
    import sys

    if "mujoco.mjx" in sys.modules:
        return
    with contextlib.redirect_stdout(io.StringIO()):
        from mujoco import mjx  # noqa: F401


def set_precision(precision: str = "float64") -> str:
    """Set JAX's float width for what follows (``jax_enable_x64``); the numpy dtype name.

    JAX's flag is per process: arrays made before a change keep their width, so each
    backend object sets it when it is built and before each call it compiles."""
    require()
    if precision not in PRECISIONS:
        raise ScenarioError(f"precision {precision!r}: allowed: {', '.join(PRECISIONS)}")
    import jax

    x64 = precision == "float64"
    if jax.config.jax_enable_x64 != x64:
        # what JAX traced under the other width stays in its caches, and a program traced
        # now would call into it with the wrong types (MJX's RK4 did)
        jax.clear_caches()
        jax.config.update("jax_enable_x64", x64)
    _persistent_cache(jax)
    return precision


def _persistent_cache(jax) -> None:
    """Keep XLA's compiled programs on disk (an MJX closed loop compiles in 10-40 s; the
    next process loads it in under a second): JAX_COMPILATION_CACHE_DIR when set, else
    ~/.cache/tspend/jax; TSPEND_JAX_CACHE=0 turns it off."""
    import os
    from pathlib import Path

    if os.environ.get("TSPEND_JAX_CACHE", "1") == "0" or jax.config.jax_compilation_cache_dir:
        return
    where = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "tspend" / "jax"
    try:
        where.mkdir(parents=True, exist_ok=True)
    except OSError:
        return   # a read-only home: compile every time
    jax.config.update("jax_compilation_cache_dir", str(where))
