"""The Python API in the field's habits: ``tspend.run(name | path | Scenario, controller=,
seed=, overrides=)``, ``RunResult.to_pandas()`` with units and ``.plot()``, and a light
``import tspend``."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import tspend
from cli_harness import ROOT


def test_import_tspend_loads_no_heavy_module() -> None:
    code = ("import sys, tspend; tspend.__version__; "
            "print(','.join(m for m in ('mujoco', 'numba', 'rerun', 'matplotlib', 'scipy') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "", f"import tspend loaded {out}"


def test_run_takes_a_name_a_path_or_a_scenario_alike() -> None:
    changes = {"run.duration": 0.5, "controllers.pd.bandwidth": 5.0}
    by_name = tspend.run("ex2_duffing", controller="pd", seed=3, overrides=changes)
    by_path = tspend.run(ROOT / "scenarios" / "ex2_duffing.toml", controller="pd", seed=3,
                         overrides=changes)
    scn = tspend.override(tspend.load_scenario("ex2_duffing"),
                          **{**changes, "run.seed": 3})
    by_object = tspend.run(scn, controller="pd")
    assert by_name.scenario.run.seed == 3 and by_name.scenario.run.duration == 0.5
    assert by_name.controller.kind == "pd" and by_name.status == "completed"
    for other in (by_path, by_object):
        assert other.metrics["rmse"] == by_name.metrics["rmse"]
        np.testing.assert_array_equal(other.history["u"], by_name.history["u"])
    # the override reached the controller: the PD gains are (s + 5)^2's
    np.testing.assert_allclose(by_name.controller.k, [25.0, 10.0])


def test_run_rejects_a_bad_override_with_one_line() -> None:
    from tspend.runtime.errors import ScenarioError

    with pytest.raises(ScenarioError) as exc:
        tspend.run("ex2_duffing", overrides={"run.durration": 1.0})
    assert "\n" not in str(exc.value) and "durration" in str(exc.value)


def test_to_pandas_names_units_and_matches_the_history() -> None:
    res = tspend.run("ex3_pendulum_ode", controller="lqr", duration=0.3)
    frame = res.to_pandas()
    # the model's names with the unit at the end, as tspend export writes them
    assert frame.index.name == "t_s" and len(frame) == 300
    np.testing.assert_array_equal(frame.index.to_numpy(), res.history["t"])
    np.testing.assert_array_equal(frame[["hinge_rad", "hinge_dot_rad_s"]].to_numpy(),
                                  res.history["x"])
    np.testing.assert_array_equal(frame["u_N"].to_numpy(), res.history["u"])
    assert {"ref_rad", "ref_dot_rad_s", "ref_ddot_rad_s2", "e_hinge_rad", "slider_m"} <= set(
        frame.columns)
    assert not any(" " in c or "[" in c for c in frame.columns)
    with pytest.warns(FutureWarning):
        plain = res.to_pandas(units=False)  # the old keys, one more release
    assert {"x1", "x2", "r", "u"} <= set(plain.columns)


def test_plot_draws_the_papers_panels_from_the_history() -> None:
    pytest.importorskip("matplotlib")
    res = tspend.run("ex2_duffing", duration=0.3)
    fig = res.plot()
    axes = fig.get_axes()
    assert len(axes) == 3  # x1 and r, x2 and r', u
    for i in range(2):
        lines = {ln.get_label(): ln.get_ydata() for ln in axes[i].get_lines()}
        np.testing.assert_array_equal(lines["second_type"], res.history["x"][:, i])
        np.testing.assert_array_equal(lines[f"reference r{chr(39) * i}"], res.history["ref"][:, i])
    np.testing.assert_array_equal(axes[2].get_lines()[0].get_ydata(), res.history["u"])
