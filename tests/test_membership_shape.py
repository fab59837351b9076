"""Shape of adapted membership functions (issue 15): the measure, and the projection that keeps it."""

import numpy as np
import pytest
from scipy.signal import find_peaks

from tspend import load_scenario, override, run
from tspend.config import ControllerConfig
from tspend.controllers.paper.controller import make_controller
from tspend.controllers.paper.membership_shape import humps, membership_shape


def test_humps_agree_with_scipy_find_peaks():
    rng = np.random.default_rng(0)
    z = np.linspace(-1, 1, 401)
    for _ in range(100):
        centres = rng.uniform(-1, 1, rng.integers(1, 4))
        mu = sum(rng.uniform(0.2, 1.0) * np.exp(-((z - c) / rng.uniform(0.05, 0.3)) ** 2)
                 for c in centres)
        padded = np.concatenate([[0.0], mu, [0.0]])
        assert humps(mu, 1e-3) == len(find_peaks(padded, prominence=1e-3)[0])


def test_initial_sets_are_unimodal_and_ordered():
    c = make_controller(ControllerConfig())
    c.reset(np.random.default_rng(0))
    shape = membership_shape(c)
    assert shape["score"] == 1.0 and shape["unimodal"] == 1.0 and shape["ordered"] == 1.0
    peaks = [s["peak"] for s in shape["inputs"]["model/x_o1"]["sets"].values()]
    np.testing.assert_allclose(peaks, np.linspace(-np.pi / 4, np.pi / 4, 5), atol=0.02)


def test_a_bent_set_and_swapped_sets_are_flagged():
    c = make_controller(ControllerConfig())
    c.reset(np.random.default_rng(0))
    C = c.state.C_model
    C[1, 1] = [0.0, 0.9, 0.0, 0.0, 0.0, 0.0, 0.9, 0.0, 0.0]     # x_o2 NS: two humps
    C[0, [3, 4]] = C[0, [4, 3]].copy()                        # x_o1: PS and PB swapped
    shape = membership_shape(c)
    ns = shape["inputs"]["model/x_o2"]["sets"]["NS"]
    assert ns["humps"] == 2 and not ns["unimodal"]
    assert not shape["inputs"]["model/x_o1"]["ordered"]
    assert shape["score"] < 1.0


@pytest.fixture(scope="module")
def duffing_runs():
    base = load_scenario("ex2_duffing")
    return {mode: run(override(base, **{"controller.shape_projection": mode}))
            for mode in ("off", "unimodal")}


def test_duffing_bends_its_sets_without_the_projection(duffing_runs):
    shape = membership_shape(duffing_runs["off"].controller)
    sets = shape["inputs"]["model/x_o2"]["sets"]
    assert sets["NS"]["humps"] >= 2 and sets["Z"]["humps"] >= 2
    assert shape["score"] < 1.0


def test_the_projection_keeps_every_set_unimodal_and_ordered(duffing_runs):
    r = duffing_runs["unimodal"]
    assert r.status == "completed"
    shape = membership_shape(r.controller)
    assert shape["score"] == 1.0 and shape["ordered"] == 1.0
    # the control points moved (the sets still adapt) and the run still tracks
    initial = make_controller(r.scenario.controller)
    initial.reset(np.random.default_rng(0))
    assert not np.allclose(r.controller.state.C_model, initial.state.C_model)
    assert r.metrics["rmse_ss"] < 1e-2


def test_shape_projection_is_off_by_default():
    assert load_scenario("ex2_duffing").controller.shape_projection == "off"
    assert ControllerConfig().leakage_mode == "sigma"
