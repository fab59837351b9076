"""``mpc`` keeps the task's constraint set (``[task.constraints]``) in its OCP."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from mpc_plans import run_keeping_plans
from tspend import load_scenario, override, run
from tspend.cli.main import main
from tspend.loop.simulation import build_controller


def build(scenario, kind):
    """The kind as the runner builds it: designed on the nominal machine."""
    return build_controller(scenario, kind=kind)


warnings.simplefilter("ignore")

#: a soft box on the cart tighter than the travel the pole's sine needs (0.76 m in 3 s)
BOX = {"task.constraints.box.slider": {"lo": -0.6, "hi": 0.6}}
#: a velocity-dependent row: where the cart would be 0.3 s on at its speed, and the force
ROW = {"task.constraints.linear.ahead": {"terms": {"slider": 1.0, "slider_dot": 0.3,
                                                  "force": 1e-4}, "min": -0.5, "max": 0.5}}


def _scenario(**changes):
    return override(load_scenario("pendulum_mujoco"),
                    **{"run.duration": 3.0, "controllers.mpc.horizon": 15, **changes})


@pytest.mark.parametrize("solver", ["auto", "daqp"])
def test_a_soft_box_on_the_cart_is_kept_only_when_it_is_in_the_ocp(solver):
    bare = run(_scenario(**BOX, **{"controllers.mpc.constraints": False}), controller="mpc")
    kept = run(_scenario(**BOX, **{"controllers.mpc.solver": solver}), controller="mpc")
    assert bare.status == kept.status == "completed"
    # without the rows the cart leaves the box; with them never (0.05 m margin kept)
    assert bare.metrics["constraints"]["slider"]["samples_outside"] > 100
    assert kept.metrics["constraints"]["slider"]["samples_outside"] == 0
    assert np.abs(kept.history["state"][:, 0]).max() <= 0.6
    assert kept.metrics["counters"]["solve_failures"] == 0
    assert kept.controller.soft_names == ("slider",)
    assert kept.controller.qp_solver == ("hpipm" if solver == "auto" else solver)


def test_a_linear_row_holds_on_every_predicted_stage(monkeypatch):
    s = _scenario(**ROW, **{"run.duration": 1.5})
    r, plans = run_keeping_plans(monkeypatch, s)
    assert r.status == "completed" and len(plans) == 75
    c = r.controller
    C, D, b, _ = c.rows
    # the row as declared, in the model's state order (b: tightened by nothing)
    np.testing.assert_allclose(C, [[1.0, 0.0, 0.3, 0.0], [-1.0, 0.0, -0.3, 0.0]])
    np.testing.assert_allclose(D, [1e-4, -1e-4])
    np.testing.assert_allclose(b, [0.5, 0.5])
    active = 0
    for S, U, _, _ in plans:
        # stages 1..N-1 (stage 0's state is the measurement, x_N the terminal cost's)
        y = S[0, 1:-1] + 0.3 * S[2, 1:-1] + 1e-4 * U[1:]
        assert np.all(np.abs(y) <= 0.5 + 1e-6)
        active += int(np.any(np.abs(y) > 0.5 - 1e-6))
    assert active > 10     # the row binds: the test can fail
    # measured along the run: the row holds on the machine too (slack never needed)
    assert r.metrics["constraints"]["ahead"]["max_depth"] < 1e-3


def test_sqp_with_rows_converges_to_ipopts_solution_of_the_same_ocp():
    # the linear row and the hard box on the cart's speed (less the margin) are (M3)'s
    # slack rows: both schemes solve one OCP, compared at a state where both are active
    s = _scenario(**ROW, **{"task.constraints.box.slider_dot": {"lo": -0.5, "hi": 0.5,
                                                                "hard": True},
                            "controllers.mpc.horizon": 10, "controllers.mpc.tolerance": 1e-10})
    ipopt = build(override(s, **{"controllers.mpc.scheme": "ipopt"}), "mpc")
    sqp = build(override(s, **{"controllers.mpc.scheme": "sqp",
                               "controllers.mpc.sqp_iterations": 40}), "mpc")
    assert ipopt.soft_names == sqp.soft_names == ("slider_dot", "ahead")
    np.testing.assert_allclose(sqp.rows[2], [0.45, 0.45, 0.5, 0.5])
    state, ref = np.array([0.3, -0.05, 0.4, 0.0]), np.array([0.0, 0.0, 0.0])
    u_i, ok_i, _ = ipopt.solve(state, ref)
    u_s, ok_s, _ = sqp.solve(state, ref)
    assert ok_i and ok_s and sqp.diag[3] < 40
    S, U = ipopt.plan_states, ipopt.plan_inputs
    y = S[0, 1:-1] + 0.3 * S[2, 1:-1] + 1e-4 * U[1:]
    assert np.isclose(y.max(), 0.5, atol=1e-6)                  # the row is active
    assert np.isclose(S[2, 1:-1].max(), 0.45, atol=1e-6)        # and the speed's box
    assert np.all(ipopt.plan_slacks < 1e-6) and np.all(sqp.plan_slacks < 1e-6)
    np.testing.assert_allclose(sqp.plan_inputs, ipopt.plan_inputs, atol=1e-4 * 2000.0)
    np.testing.assert_allclose(sqp.plan_states, ipopt.plan_states, atol=1e-5)


def test_the_compiled_solvers_cache_key_includes_the_constraints(monkeypatch, tmp_path):
    monkeypatch.setenv("TSPEND_CACHE_DIR", str(tmp_path))

    def objects():
        return sorted(p.name for p in (tmp_path / "mpc").glob("*.so"))

    a = build(_scenario(**BOX), "mpc")
    first = objects()
    build(_scenario(**BOX), "mpc")
    assert objects() == first and a.rti.compiled      # the same set: the same object
    build(_scenario(**{"task.constraints.box.slider": {"lo": -0.5, "hi": 0.5}}), "mpc")
    second = objects()
    assert len(second) == len(first) + 1               # another box: another object
    build(_scenario(), "mpc")
    assert len(objects()) == len(second) + 1           # none: another again


def test_qrqp_with_soft_rows_is_one_line_exit_2(capsys):
    assert main(["run", "pendulum_mujoco", "--controller", "mpc", "--no-record",
                 "--duration", "0.01", "--set", "controllers.mpc.solver=\"qrqp\"",
                 "--set", "task.constraints.box.slider={lo=-0.6, hi=0.6}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "controllers.mpc.solver" in err[0] and "hpipm" in err[0], err


def test_a_damaged_compiled_solver_is_rebuilt_not_loaded(monkeypatch, tmp_path):
    import warnings

    from tspend.runtime.cache import SIDECAR, binary_problem

    monkeypatch.setenv("TSPEND_CACHE_DIR", str(tmp_path))
    build(_scenario(**BOX), "mpc")
    objects = sorted((tmp_path / "mpc").glob("*.so"))
    assert objects and all((o.parent / (o.name + SIDECAR)).is_file() for o in objects)
    good = {o: o.read_bytes() for o in objects}
    # garbage in one, another's bytes in a second (both keep their names)
    objects[0].write_bytes(b"\x7fELF garbage" * 100)
    if len(objects) > 1:
        objects[1].write_bytes(good[objects[0]])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        a = build(_scenario(**BOX), "mpc")
    said = [str(w.message) for w in caught if "rebuilt" in str(w.message)]
    assert len(said) == min(2, len(objects)) and "checksum" in said[0], said
    assert a.rti.compiled
    for o in objects:
        key = o.stem.rsplit("_", 1)[1]
        assert binary_problem(o, key) is None and o.read_bytes() == good[o]
