"""``tspend.linearize`` against independent derivatives (issue 21).

* the MuJoCo pendulum's unstable pole against central differences of ``mj_forward``
  written here, directly on ``models/cartpole.xml`` (and against the pole of the
  hand-derived linearisation of (C1)-(C2));
* the MuJoCo and the analytic linearisation of one machine agree, on the cart-pole and
  on the Furuta pendulum, at the upright and at a moving state (where the analytic
  side takes its central-difference path);
* names from the domain; bad input is a one-line ScenarioError.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest

control = pytest.importorskip("control")

import tspend
from tspend import load_scenario
from tspend.runtime.errors import ScenarioError
from tspend.plants import registry

ROOT = Path(__file__).resolve().parents[1]


def _mj_forward_A(path: Path, step: float = 1e-5) -> np.ndarray:
    """The oracle: A of [qpos, qvel] at zero from mj_forward's qacc, by central
    differences with a step of its own (nothing of tspend)."""
    model = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(model)
    nq, nv = model.nq, model.nv

    def qacc(qpos, qvel):
        data.qpos[:], data.qvel[:], data.ctrl[:] = qpos, qvel, 0.0
        mujoco.mj_forward(model, data)
        return data.qacc.copy()

    A = np.zeros((nq + nv, nq + nv))
    A[:nq, nq:] = np.eye(nv)
    z = np.zeros(nq)
    for i in range(nq):
        e = np.zeros(nq)
        e[i] = step
        A[nq:, i] = (qacc(z + e, z) - qacc(z - e, z)) / (2 * step)
        A[nq:, nq + i] = (qacc(z, z + e) - qacc(z, z - e)) / (2 * step)
    return A


def test_mujoco_pendulums_unstable_pole_matches_mj_forward_differences():
    sys_ = tspend.linearize("pendulum_mujoco")
    assert isinstance(sys_, control.StateSpace) and sys_.isctime()
    ours = max(p.real for p in sys_.poles())
    oracle = max(np.linalg.eigvals(_mj_forward_A(ROOT / "models" / "cartpole.xml")).real)
    assert ours > 1.0  # the inverted pendulum is unstable
    assert abs(ours - oracle) <= 1e-3 * abs(oracle)
    # and the hand-derived pole of (C1)-(C2), the paper's machine: sqrt((M+m) m g l / det)
    M, m, l, g = 10.0, 1.0, 3.0, 9.8
    det = (M + m) * 4.0 / 3.0 * m * l * l - (m * l) ** 2
    assert ours == pytest.approx(math.sqrt((M + m) * m * g * l / det), rel=1e-6)


def test_names_come_from_the_domain():
    sys_ = tspend.linearize("pendulum_mujoco")
    assert sys_.state_labels == ["slider", "hinge", "slider_dot", "hinge_dot"]
    assert sys_.input_labels == ["force"]        # the MJCF's actuator
    assert sys_.output_labels == ["hinge"]       # the task's tracked output
    np.testing.assert_array_equal(sys_.C, [[0.0, 1.0, 0.0, 0.0]])
    fur = tspend.linearize("furuta_ode")
    assert fur.state_labels == ["arm", "pendulum", "arm_dot", "pendulum_dot"]
    assert fur.output_labels == ["pendulum"]


@pytest.mark.parametrize("scenario", ["pendulum_mujoco", "furuta_mujoco"])
@pytest.mark.parametrize("at", [None, {"hinge": 0.2, "slider_dot": 0.5, "hinge_dot": -0.3}])
def test_mujoco_and_analytic_linearisations_of_one_machine_agree(scenario, at):
    plant = registry.build(load_scenario(scenario))
    twin = registry.domain_of(plant.name).ode_of(plant)  # the ODE of the compiled model
    if at is not None and "furuta" in scenario:
        at = {"pendulum": 0.2, "arm_dot": 0.5, "pendulum_dot": -0.3}
    mj, ode = tspend.linearize(plant, at=at), tspend.linearize(twin, at=at)
    assert mj.state_labels == ode.state_labels
    scale_A, scale_B = np.abs(ode.A).max(), np.abs(ode.B).max()
    np.testing.assert_allclose(mj.A, ode.A, atol=1e-6 * scale_A)
    np.testing.assert_allclose(mj.B, ode.B, atol=1e-6 * scale_B)
    np.testing.assert_allclose(np.sort_complex(mj.poles()), np.sort_complex(ode.poles()),
                               rtol=1e-5, atol=1e-6)


def test_at_moves_the_operating_point():
    up = tspend.linearize("ex3_pendulum_ode")
    down = tspend.linearize("ex3_pendulum_ode", at={"hinge": math.pi})
    assert max(p.real for p in up.poles()) > 1.0
    assert max(p.real for p in down.poles()) < 1e-9  # hanging: no unstable pole
    same = tspend.linearize("ex3_pendulum_ode", at=np.array([0.0, math.pi, 0.0, 0.0]))
    np.testing.assert_array_equal(same.A, down.A)


@pytest.mark.parametrize("args, match", [
    (("no_such_scenario",), "no_such_scenario"),
    ((3.5,), "a scenario name"),
    (("ex3_pendulum_ode", {"theta": 0.1}), "no state named 'theta'"),
    (("ex3_pendulum_ode", [0.0, 0.1]), "4 entries"),
    (("ex3_pendulum_ode", [0.0, math.nan, 0.0, 0.0]), "not finite"),
    (("ex3_pendulum_ode", "up"), "4 entries|numbers"),
])
def test_bad_input_is_one_clear_line(args, match):
    with pytest.raises(ScenarioError, match=match) as err:
        tspend.linearize(*args)
    assert "\n" not in str(err.value)


def test_missing_python_control_is_a_clear_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "control", None)  # import control -> ImportError
    with pytest.raises(ScenarioError, match=r"python-control, a dependency of tspend .*: pip install control"):
        tspend.linearize("ex3_pendulum_ode")


@pytest.mark.parametrize("scenario", ["pendulum_mujoco", "furuta_mujoco"])
def test_lqr_full_design_is_lqr_on_the_linearisation(scenario):
    # the kind designs on the domain's exact Jacobian; on these models (no friction) it is
    # MuJoCo's own linearisation, and its gain is control.lqr on the StateSpace
    from tspend.loop.simulation import build_controller

    ctrl = build_controller(load_scenario(scenario), kind="lqr")
    sys_ = tspend.linearize(scenario)
    np.testing.assert_allclose(ctrl.A, sys_.A, atol=1e-9 * np.abs(sys_.A).max())
    np.testing.assert_allclose(ctrl.B, sys_.B, atol=1e-9 * np.abs(sys_.B).max())
    K, _, _ = control.lqr(sys_, ctrl.Q, ctrl.R)
    np.testing.assert_allclose(ctrl.K, np.ravel(K), rtol=1e-6)
