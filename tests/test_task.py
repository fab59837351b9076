"""The task: the controller's Observation, and runs ended by a fall, a rail, a joint limit
or a state bound.

Crossing times are checked against a tight ``solve_ivp`` of the paper's cart-pole ODE
(tests/cartpole_oracle.py, written independently of tspend's equations) with an event on
the crossing: the run reports the first sample at or after it, so within one sample.
Observations are checked against MuJoCo's own ``d.joint(name).qpos / qvel``.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from cartpole_oracle import ReferenceCartPole
from cli_harness import tspend
from tspend.controllers.base import Controller, Observation
from tspend.runtime.errors import ScenarioError
from tspend.loop.simulation import Prepared, build_plant, prepare, run, scenario_task
from tspend.scenario import load_scenario, override
from tspend.config.signals import NoDisturbance
from tspend.task import EXIT_TERMINATED, TERMINATIONS

ROOT = Path(__file__).resolve().parents[1]
SHORT_RAIL = str(ROOT / "tests" / "models" / "cartpole_short_rail.xml")
DT = 1e-3
# the short-rail model's limits and ctrlrange are departures from the paper's ODE, warned about
pytestmark = pytest.mark.filterwarnings("ignore::tspend.runtime.errors.ModelWarning")


class Constant(Controller):
    """u held at a constant; records every observation it is given."""

    kind = "constant_test"
    order = 2

    def __init__(self, u: float = 0.0, plant=None) -> None:
        self.u, self.plant = u, plant
        self.diag = np.zeros(0)
        self.seen: list[Observation] = []
        self.mujoco_seen: list[dict[str, tuple[float, float]]] = []

    def reset(self, rng: np.random.Generator) -> None:
        self.seen.clear()

    def step(self, obs: Observation, dt: float) -> float:
        self.seen.append(Observation(obs.t, obs.state.copy(), obs.x.copy(), obs.ref.copy(),
                                     obs.names))
        if self.plant is not None and len(self.mujoco_seen) < 50:
            d = self.plant.data
            self.mujoco_seen.append({j: (float(d.joint(j).qpos[0]), float(d.joint(j).qvel[0]))
                                     for j in ("slider", "hinge")})
        return self.u


def cartpole(kind: str = "cartpole_ode", duration: float = 3.0, **more) -> object:
    """The default cart-pole scenario on backend ``kind``, no disturbance."""
    s = load_scenario("pendulum_mujoco" if kind == "cartpole_mujoco" else "ex3_pendulum_ode")
    s = override(s, **{"run.duration": duration, **more})
    return replace(s, disturbance=NoDisturbance())


def run_constant(scenario, u: float, record_mujoco: bool = False, compiled: bool = True):
    plant = build_plant(scenario)
    ctrl = Constant(u, plant if record_mujoco else None)
    task = scenario_task(scenario, plant)
    return run(scenario, prepared=Prepared(scenario, plant, ctrl, task), compiled=compiled), ctrl


def crossing_time(x0: tuple[float, float], u: float, index: int, level: float) -> float:
    """When state ``index`` of the oracle's [theta, theta', x_c, x_c'] first reaches
    ``|level|``, with u held and no disturbance (DOP853, rtol 1e-12)."""
    oracle = ReferenceCartPole()
    event = lambda t, s: abs(s[index]) - level  # noqa: E731
    event.terminal, event.direction = True, 1.0
    sol = solve_ivp(lambda t, s: oracle._rhs(t, s, u, 0.0), (0.0, 20.0),
                    [x0[0], x0[1], 0.0, 0.0], method="DOP853", rtol=1e-12, atol=1e-13,
                    events=event)
    assert sol.t_events[0].size == 1
    return float(sol.t_events[0][0])


def ended_at(result) -> float:
    """The time of the run's last sample (the one that crossed)."""
    return (result.end.steps_done - 1) * result.scenario.run.dt


@pytest.mark.parametrize("kind", ["cartpole_ode", "cartpole_mujoco"])
def test_a_pole_released_from_0_3_rad_falls_when_the_ode_says(kind: str) -> None:
    s = cartpole(kind, duration=10.0, **{"plant.x0": [0.3, 0.0]})
    result, _ = run_constant(s, 0.0)
    assert result.status == "fell"
    t_fall = crossing_time((0.3, 0.0), 0.0, 0, math.pi / 2)
    assert t_fall <= ended_at(result) < t_fall + DT
    assert f"fell at t = {ended_at(result):.4f} s: |hinge|" in result.end.message
    assert "exceeds fall_angle 1.571 rad" in result.end.message
    # outputs kept up to the end, the crossing sample included
    assert result.history["x"].shape[0] == result.end.steps_done
    assert abs(result.history["x"][-1, 0]) > math.pi / 2 > abs(result.history["x"][-2, 0])


def test_fall_angle_from_the_task_table_and_zero_turns_it_off() -> None:
    s = cartpole("cartpole_ode", duration=4.0, **{"plant.x0": [0.3, 0.0], "task.fall_angle": 0.6})
    result, _ = run_constant(s, 0.0)
    assert result.status == "fell"
    t = crossing_time((0.3, 0.0), 0.0, 0, 0.6)
    assert t <= ended_at(result) < t + DT
    off = cartpole("cartpole_ode", duration=1.0, **{"plant.x0": [0.3, 0.0], "task.fall_angle": 0.0})
    assert run_constant(off, 0.0)[0].status == "completed"


def test_a_limited_slide_joint_is_the_rail() -> None:
    s = cartpole("cartpole_mujoco", duration=3.0, **{"plant.model": SHORT_RAIL,
                                                      "plant.x0": [0.0, 0.0]})
    plant = build_plant(s)
    assert plant.joints[0].range == (-0.25, 0.25) and plant.inputs[0].hi == 100.0
    result, _ = run_constant(s, 20.0)
    assert result.status == "rail_end", result.end.message
    t = crossing_time((0.0, 0.0), 20.0, 2, 0.25)
    assert t <= ended_at(result) < t + DT
    assert f"rail_end at t = {ended_at(result):.4f} s: slider = 0.25" in result.end.message
    assert "m is beyond the end of its range [-0.25, 0.25] m" in result.end.message


def test_another_limited_joint_ends_the_run_joint_limit() -> None:
    s = cartpole("cartpole_mujoco", duration=3.0, **{"plant.model": SHORT_RAIL,
                                                      "plant.x0": [0.3, 0.0]})
    result, _ = run_constant(s, 0.0)
    assert result.status == "joint_limit", result.end.message
    t = crossing_time((0.3, 0.0), 0.0, 0, 0.5)
    assert t <= ended_at(result) < t + DT
    # joint_limits = false leaves the ranges to MuJoCo's constraints: the pole stops there
    free = cartpole("cartpole_mujoco", duration=1.5, **{
        "plant.model": SHORT_RAIL, "plant.x0": [0.3, 0.0], "task.joint_limits": False})
    assert run_constant(free, 0.0)[0].status == "completed"


def test_effects_rail_overrides_the_slide_range_on_the_ode() -> None:
    s = cartpole("cartpole_ode", duration=3.0, **{"plant.x0": [0.0, 0.0], "effects.rail": 0.1,
                                                   "task.fall_angle": 0.0})
    result, _ = run_constant(s, 20.0)
    assert result.status == "rail_end"
    t = crossing_time((0.0, 0.0), 20.0, 2, 0.1)
    assert t <= ended_at(result) < t + DT
    assert "|slider| = 0.1" in result.end.message
    assert "m exceeds the rail's half-length (effects.rail = 0.1 m)" in result.end.message


def test_a_state_bound_ends_the_run_at_the_first_sample_beyond_it() -> None:
    s = override(load_scenario("ex2_duffing"), **{"run.duration": 3.0,
                                                  "task.state_bounds.x2": 0.8})
    result = run(s, controller="pd")
    assert result.status == "state_bound", result.end.message
    x2 = result.history["x"][:, 1]
    assert abs(x2[-1]) > 0.8 and np.all(np.abs(x2[:-1]) <= 0.8)
    assert "|x2| =" in result.end.message and "task.state_bounds.x2 = 0.8" in result.end.message


@pytest.mark.parametrize("kind", ["cartpole_ode", "cartpole_mujoco"])
def test_compiled_and_generic_loops_end_at_the_same_sample(kind: str) -> None:
    # the paper's controller holds the pole but lets the cart drift: a bound on the cart
    s = cartpole(kind, duration=6.0, **{"task.state_bounds.slider": 0.5})
    a, b = run(s), run(s, compiled=False)
    assert a.status == b.status == "state_bound", a.end.message
    assert a.end.steps_done == b.end.steps_done and a.end.message == b.end.message
    for key in a.history:
        np.testing.assert_array_equal(a.history[key], b.history[key], err_msg=key)


def test_the_observation_holds_the_named_full_state_mujoco_reads() -> None:
    s = cartpole("cartpole_mujoco", duration=0.05)
    result, ctrl = run_constant(s, 3.0, record_mujoco=True)
    assert result.status == "completed"
    for obs, joints in zip(ctrl.seen, ctrl.mujoco_seen):
        assert obs.names == ("slider", "hinge", "slider_dot", "hinge_dot")
        for name, (q, v) in joints.items():
            assert obs.get(name) == q and obs.get(f"{name}_dot") == v
        np.testing.assert_array_equal(obs.x, [obs.get("hinge"), obs.get("hinge_dot")])
    assert ctrl.seen[10].t == pytest.approx(10 * DT, abs=1e-15)
    # the cart moved: the full state is not just the view
    assert ctrl.seen[-1].get("slider") > 0.0
    with pytest.raises(KeyError):
        ctrl.seen[0].get("elbow")


def test_the_ode_names_its_state_after_the_mjcf_and_takes_its_ranges() -> None:
    s = cartpole("cartpole_mujoco", **{"plant.model": SHORT_RAIL})
    ode = build_plant(s, "cartpole_ode")
    mj = build_plant(s)
    assert ode.state_names == mj.state_names == ("slider", "hinge", "slider_dot", "hinge_dot")
    assert ode.joints == mj.joints
    assert ode.parameters()["M"] == pytest.approx(mj.parameters()["M"])
    np.testing.assert_allclose(ode.full_state(), mj.full_state(), atol=1e-15)


@pytest.mark.parametrize("changes, key", [
    ({"task.view": ["hinge", "elbow_dot"]}, "task.view: no state named 'elbow_dot'"),
    ({"task.view": ["hinge"]}, "task.view: must name 2 states"),
    ({"task.state_bounds.cart": 1.0}, "task.state_bounds: no state named 'cart'"),
    ({"task.state_bounds.slider": -1.0}, "task.state_bounds.slider: must be > 0"),
    ({"task.fall_angle": -0.1}, "task.fall_angle"),
    ({"task.falls": 1.0}, "task.falls: unknown key"),
])
def test_bad_task_tables_are_one_line_errors(changes: dict, key: str) -> None:
    with pytest.raises(ScenarioError, match=key.replace("(", r"\(")):
        prepare(cartpole("cartpole_ode", **changes))


def test_a_fall_angle_on_a_plant_without_a_pole_is_an_error() -> None:
    s = override(load_scenario("ex2_duffing"), **{"task.fall_angle": 1.0})
    with pytest.raises(ScenarioError, match="task.fall_angle: plant duffing has no pole"):
        prepare(s)


def test_the_cli_exits_4_with_the_status_and_outputs(tmp_path: Path) -> None:
    assert EXIT_TERMINATED == 4 and "rail_end" in TERMINATIONS
    r = tspend("run", "pendulum_mujoco", "--controller", "pd", "--duration", "4",
               "--set", f"plant.model={json.dumps(SHORT_RAIL)}", "--set", "task.fall_angle=0",
               "--metrics", "m.json", "--out", "r.rrd", cwd=tmp_path, timeout=300)
    assert r.status == 4, r.err
    assert "rail_end at t = " in r.err and "slider = " in r.err
    metrics = json.loads((tmp_path / "m.json").read_text())
    assert metrics["status"] == "rail_end" and metrics["steps"] < 4000
    assert (tmp_path / "r.rrd").stat().st_size > 0
    bad = tspend("run", "ex2_duffing", "--set", "task.view=['x1', 'x9']", cwd=tmp_path)
    assert bad.status == 2
    assert "task.view: no state named 'x9'" in bad.one_error_line()
