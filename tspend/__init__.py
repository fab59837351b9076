"""tspend: on-line T-S fuzzy modeling and robust adaptive control, a testbed.

The paper's structure, one module per concept: ``bspline`` (BMFs, eq. 1-5), ``rules``
(grid rule base and firing strengths, eq. 9-12), ``ts_model`` (T-S model and its second
type laws, eq. 14-16, 25-26), ``compensator`` (eq. 21-24, 27), ``control_law`` (eq. 18-19,
Lemma 1), ``controller`` (one controller sample), ``plants`` (analytic and MuJoCo),
``signals`` (references and disturbances), ``scenario`` (TOML), ``runner`` (closed loop),
``metrics``, ``recorder`` (Rerun), ``sweep`` (many runs, one table row each), ``cli``.

Python API::

    import tspend
    result = tspend.run("pendulum_mujoco", controller="lqr", seed=3,
                        overrides={"run.duration": 5.0})
    result.metrics["rmse_ss"]; result.to_pandas(); result.plot()
    table = tspend.sweep("ex2_duffing", seeds=range(20), controllers=["second_type", "first_type"])
    sys = tspend.linearize("pendulum_mujoco")  # a python-control StateSpace at the upright

``import tspend`` is light: MuJoCo, numba, Rerun and matplotlib load when first used.
"""

__version__ = "0.1.0"

from pathlib import Path as _Path

from tspend.runtime.gl import choose_headless_gl as _choose_headless_gl
from tspend.runtime.jit import invalidate_stale_cache as _invalidate_stale_cache

# before MuJoCo is imported: an off-screen GL backend where there is no display
_choose_headless_gl()

# before any compiled function loads from numba's cache (see tspend/runtime/jit.py)
_invalidate_stale_cache(_Path(__file__).resolve().parent)

__all__ = ["__version__", "load_scenario", "override", "run", "build_plant", "build_controller",
           "sweep", "linearize"]


def run(scenario="pendulum_mujoco", controller: str | None = None, seed: int | None = None,
        overrides: dict | None = None, duration: float | None = None, **options):
    """Run one closed loop and return its :class:`~tspend.loop.simulation.RunResult`.

    Parameters
    ----------
    scenario : str, path or Scenario
        A scenario name (``tspend list``), a path to a ``.toml`` file, or a
        :class:`~tspend.config.Scenario` (from :func:`load_scenario`).
    controller : str, Controller class or instance, optional
        A kind (``"lqr"``; ``tspend run --controller help`` lists them), a plug-in spec
        (``"my_file.py:MyController"``, ``"package.module:Class"``, ``"__main__:MyController"``
        for a class of the running script), a :class:`~tspend.controllers.base.Controller`
        subclass (``controller=MyController``, built with the scenario as its plug-in
        kind would be) or an instance (run as it is, after its ``reset``); default: the
        scenario's own.
    seed : int, optional
        Overrides ``run.seed``.
    overrides : dict, optional
        Dotted scenario keys to values, validated like the file:
        ``{"run.duration": 5.0, "controllers.lqr.R": 0.01}``.
    duration : float, optional
        Overrides ``run.duration`` (s).
    **options
        Passed on to :func:`tspend.loop.simulation.run` (``sinks``, ``keep_history``,
        ``plant_kind``, ...).

    Returns
    -------
    RunResult
        ``.metrics``, ``.status``, ``.history``, ``.to_pandas()``, ``.plot()``.

    Raises
    ------
    tspend.runtime.errors.ScenarioError
        any bad input: no such scenario, an unknown controller kind or plug-in that
        cannot be loaded, an invalid override, seed or duration, an unknown option, a
        model that cannot be built.  Every error is a :class:`tspend.runtime.errors.TspendError`.
    tspend.runtime.errors.DivergenceError
        never: a run that diverges returns, with ``status`` ``"diverged"``.
    """
    from collections.abc import Mapping

    from tspend.config import Scenario
    from tspend.runtime.errors import ScenarioError
    from tspend.loop import simulation
    from tspend.scenario import load_scenario, override

    unknown = sorted(set(options) - _RUN_OPTIONS)
    if unknown:
        raise ScenarioError(f"run(): unknown option(s) {', '.join(map(repr, unknown))}; allowed: "
                            f"{', '.join(sorted(_RUN_OPTIONS))}")
    if overrides is not None and not isinstance(overrides, Mapping):
        raise ScenarioError(f"overrides: expected a dict of dotted keys to values, got "
                            f"{type(overrides).__name__}")
    if controller is not None and not isinstance(controller, str):
        from tspend.controllers import python_object_spec

        controller = python_object_spec(controller)  # a class, a factory or an instance
    if "block_size" in options:
        size = options["block_size"]
        if isinstance(size, bool) or not isinstance(size, int) or not 1 <= size <= 10**7:
            raise ScenarioError(f"block_size: expected an integer from 1 to 10^7, got {size!r}")
    if "sinks" in options:
        sinks = options["sinks"]
        if isinstance(sinks, (str, bytes)) or not all(
                callable(getattr(s, m, None)) for s in sinks for m in ("start", "block", "finish")):
            raise ScenarioError("sinks: expected a sequence of sinks (start, block, finish)")
    if controller is not None:
        from tspend.controllers import load

        load(controller)  # a plug-in's [controllers.KIND] table is then known to the reader
    scn = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    changes = dict(overrides or {})
    if seed is not None:
        changes["run.seed"] = seed
    if duration is not None:
        changes["run.duration"] = duration
    if changes:
        scn = override(scn, **changes)
    return simulation.run(scn, controller=controller, **options)


#: keyword options run() passes on to tspend.loop.simulation.run
_RUN_OPTIONS = frozenset({"sinks", "keep_history", "plant_kind", "block_size", "stop",
                          "prepared", "compiled"})


def __getattr__(name: str):
    # keep `import tspend` light: MuJoCo, numba and Rerun load only when used
    if name in ("load_scenario", "override"):
        from tspend import scenario

        return getattr(scenario, name)
    if name in ("build_plant", "build_controller"):
        from tspend.loop import simulation

        return getattr(simulation, name)
    if name == "linearize":
        from tspend.studies.linearize import linearize

        return linearize
    if name in ("recorder", "sweep"):
        # `tspend.recorder.open_recording(...)`; the sweep module is callable: tspend.sweep(...)
        import importlib

        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'tspend' has no attribute {name!r}")
