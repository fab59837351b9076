"""The compiled closed loop (tspend.loop.fastloop) against the generic Python loop.

The generic loop is the oracle: every key of every block, the snapshots, and how a run
ends must be the same, bit for bit, on each plant the compiled loop covers; where it does
not apply the generic loop must run.
"""

from __future__ import annotations

import numpy as np
import pytest

from tspend import load_scenario, override, run
from tspend.loop.runner import RunInterrupted, StopRequest
from tspend.loop.sinks import Block, InnerSnapshot, RunEnd, RunInfo

COVERED = ["ex1_nonaffine_case1", "ex2_duffing", "ex3_pendulum_ode", "third_order",
           "pendulum_mujoco"]


class Snapshots:
    """A sink that wants the controller's inner snapshots and keeps when they came."""

    wants_inner = True

    def __init__(self) -> None:
        self.seen: list[tuple[float, int, np.ndarray]] = []
        self.blocks: list[tuple[int, int]] = []

    def start(self, info: RunInfo) -> None:
        pass

    def block(self, block: Block) -> None:
        self.blocks.append((block.start, len(block.data["t"])))

    def inner(self, snap: InnerSnapshot) -> None:
        self.seen.append((snap.t, snap.step, snap.consequents.copy()))

    def finish(self, end: RunEnd) -> None:
        pass


def both(scenario, **kwargs):
    """The run on the compiled path and on the generic one, with their snapshot sinks."""
    out = []
    for compiled in (True, False):
        snaps = Snapshots()
        result = run(scenario, sinks=[snaps], compiled=compiled, **kwargs)
        out.append((result, snaps))
    return out


def assert_same_blocks(a, b) -> None:
    assert a.history.keys() == b.history.keys()
    for key in a.history:
        np.testing.assert_array_equal(a.history[key], b.history[key], err_msg=key, strict=True)


@pytest.mark.parametrize("name", COVERED)
def test_compiled_loop_equals_generic_loop_on_every_key(name, paths):
    scenario = override(load_scenario(name), **{"run.duration": 1.5})
    (fast, fast_snaps), (slow, slow_snaps) = both(scenario, block_size=400)
    assert paths == ["compiled", "generic"]
    assert fast.status == slow.status == "completed"
    assert_same_blocks(fast, slow)
    timing = {"wall_s", "controller_ms"}   # wall clock: the compiled loop does not time samples
    assert ({k: v for k, v in fast.metrics.items() if k not in timing}
            == {k: v for k, v in slow.metrics.items() if k not in timing})
    assert fast_snaps.blocks == slow_snaps.blocks
    # snapshots at the same samples, of the same adapted parameters
    assert [(t, k) for t, k, _ in fast_snaps.seen] == [(t, k) for t, k, _ in slow_snaps.seen]
    assert len(fast_snaps.seen) > 5
    for (_, _, p), (_, _, q) in zip(fast_snaps.seen, slow_snaps.seen):
        np.testing.assert_array_equal(p, q)
    # the plant ends where the generic loop left it
    np.testing.assert_array_equal(fast.plant.full_state(), slow.plant.full_state())
    assert fast.plant.extras() == slow.plant.extras()


@pytest.mark.parametrize("name,kind", [("pendulum_sensor_noise", None),   # per-sample hook
                                       ("pendulum_saturated", None),      # actuator effects
                                       ("ex2_duffing", "examples/custom_controller.py:SaturatedPD")])  # Python controller
def test_unsupported_loops_fall_back_to_the_generic_loop(name, kind, paths):
    scenario = override(load_scenario(name), **{"run.duration": 0.2})
    result = run(scenario, controller=kind)
    assert paths == ["generic"]
    assert result.status == "completed"


@pytest.mark.parametrize("name", ["ex2_duffing", "pendulum_mujoco"])
def test_divergence_is_reported_as_by_the_generic_loop(name, paths):
    # a control bound the controller's first transient exceeds
    scenario = override(load_scenario(name), **{"run.duration": 2.0,
                                                "run.control_bound": 0.5})
    (fast, _), (slow, _) = both(scenario, block_size=300)
    assert paths == ["compiled", "generic"]
    assert fast.status == slow.status == "diverged"
    assert "exceeds control_bound" in fast.end.message
    assert fast.end.message == slow.end.message
    assert fast.end.steps_done == slow.end.steps_done
    assert_same_blocks(fast, slow)


def test_a_plant_that_blows_up_keeps_the_same_samples():
    # Duffing from far away with a huge gain: x1^3 overflows within the run
    scenario = override(load_scenario("ex2_duffing"), **{"run.duration": 2.0,
                                                         "plant.x0": [1e80, 0.0]})
    (fast, _), (slow, _) = both(scenario)
    assert fast.status == slow.status == "diverged"
    assert fast.end.steps_done == slow.end.steps_done
    assert_same_blocks(fast, slow)


class StopAfterFirstBlock:
    def __init__(self, stop: StopRequest) -> None:
        self.stop = stop

    def start(self, info: RunInfo) -> None:
        pass

    def block(self, block: Block) -> None:
        self.stop.request("SIGTERM", 143)

    def inner(self, snap: InnerSnapshot) -> None:
        pass

    def finish(self, end: RunEnd) -> None:
        self.end = end


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("name", ["ex3_pendulum_ode", "pendulum_mujoco"])
def test_stop_request_ends_the_run_after_the_same_samples(name, compiled, paths):
    scenario = override(load_scenario(name), **{"run.duration": 1.0})
    stop = StopRequest()
    sink = StopAfterFirstBlock(stop)
    with pytest.raises(RunInterrupted) as caught:
        run(scenario, sinks=[sink], block_size=250, stop=stop, compiled=compiled)
    assert paths == ["compiled" if compiled else "generic"]
    assert caught.value.exit_status == 143
    assert caught.value.end.status == "interrupted"
    assert caught.value.end.steps_done == 250
