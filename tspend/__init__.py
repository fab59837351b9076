"""tspend: on-line T-S fuzzy modeling and robust adaptive control, a testbed.

The paper's structure, one module per concept: ``bspline`` (BMFs, eq. 1-5), ``rules``
(grid rule base and firing strengths, eq. 9-12), ``ts_model`` (T-S model and its second
type laws, eq. 14-16, 25-26), ``compensator`` (eq. 21-24, 27), ``control_law`` (eq. 18-19,
Lemma 1), ``controller`` (one controller sample), ``plants`` (analytic and MuJoCo),
``signals`` (references and disturbances), ``scenario`` (TOML), ``runner`` (closed loop),
``metrics``, ``recorder`` (Rerun), ``sweep`` (many runs, one table row each), ``cli``.

Python API::

    import tspend
    from tspend import load_scenario, override, run
    result = run(override(load_scenario("ex2_duffing"), **{"controller.eta": 0.2}))
    result.metrics["rmse_ss"], result.history["x"]
    table = tspend.sweep("ex2_duffing", seeds=range(20), controllers=["second_type", "first_type"])
"""

__version__ = "0.1.0"

from pathlib import Path as _Path

from tspend.runtime.jit import invalidate_stale_cache as _invalidate_stale_cache

# before any compiled function loads from numba's cache (see tspend/runtime/jit.py)
_invalidate_stale_cache(_Path(__file__).resolve().parent)

__all__ = ["__version__", "load_scenario", "override", "run", "build_plant", "build_controller",
           "sweep"]


def __getattr__(name: str):
    # keep `import tspend` light: MuJoCo, numba and Rerun load only when used
    if name in ("load_scenario", "override"):
        from tspend import scenario

        return getattr(scenario, name)
    if name in ("run", "build_plant", "build_controller"):
        from tspend.loop import simulation

        return getattr(simulation, name)
    if name in ("recorder", "sweep"):
        # `tspend.recorder.open_recording(...)`; the sweep module is callable: tspend.sweep(...)
        import importlib

        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'tspend' has no attribute {name!r}")
