"""Real-world effects (issue 12): each shows its effect, and each is off by default.

Independent checks: the clipping and slew bounds themselves; scipy.stats for the noise
(normality and standard deviation of what the controller sees minus the true state);
MuJoCo's own mass matrix after a change of parameters; the two backends against each
other where the ODE expresses the effect exactly; finite differences of the shaped
reference.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from tspend import load_scenario, override, run
from tspend.cli.main import main
from tspend.config import EffectsConfig, ParameterChange
from tspend.studies.crosscheck_openloop import chirp_force, open_loop_compare
from cartpole_oracle import CartPoleParams, cartpole_ode_plant
from tspend.loop.effects import EffectsPlant, Measurement
from tspend.runtime.errors import ModelWarning
from tspend.scenario import available_scenarios
from tspend.loop.simulation import build_plant

NEW = {"pendulum_payload_step", "pendulum_sensor_noise", "pendulum_saturated",
       "pendulum_friction", "pendulum_finite_rail", "swingup_mujoco"}


def short(name: str, **changes) -> object:
    return override(load_scenario(name), **{"run.duration": 3.0, **changes})


def test_every_effect_is_off_in_the_shipped_paper_scenarios() -> None:
    for path in available_scenarios():
        scn = load_scenario(path)
        if scn.name in NEW:
            assert scn.effects.active or scn.plant.cart_damping > 0.0, scn.name
            continue
        assert scn.effects == EffectsConfig(), scn.name
        assert not scn.effects.active
        for key in ("cart_damping", "hinge_damping", "cart_friction", "hinge_friction", "J"):
            assert getattr(scn.plant, key, 0.0) == 0.0, (scn.name, key)


def test_zero_settings_change_nothing() -> None:
    """Zero noise, delay 0 and no limits give the plain run bit for bit (own noise stream)."""
    base = short("ex3_pendulum_ode")
    same = override(base, **{"effects.noise_std": [0.0, 0.0], "effects.delay": 0,
                             "effects.saturation": 0.0, "effects.rate_limit": 0.0})
    a, b = run(base), run(same)
    assert np.array_equal(a.history["u"], b.history["u"])


def test_saturation_and_rate_limit_bound_the_applied_force() -> None:
    scn = short("ex3_pendulum_ode", **{"effects.saturation": 30.0, "effects.rate_limit": 2000.0})
    r = run(scn)
    applied, u = r.history["extra/u_applied"], r.history["u"]
    assert np.abs(applied).max() <= 30.0
    assert np.abs(u).max() > 30.0                    # the controller asked for more
    assert np.abs(np.diff(applied)).max() <= 2000.0 * scn.run.dt * (1 + 1e-12)
    free = run(short("ex3_pendulum_ode"))
    assert r.metrics["rmse"] != free.metrics["rmse"]
    assert "extra/u_applied" not in free.history


def test_sensor_noise_has_the_configured_spread_and_its_own_stream() -> None:
    plant = cartpole_ode_plant()
    plant.reset(np.array([0.1, 0.0]))
    hook = Measurement(EffectsConfig(noise_std=(0.002, 0.03)), plant, 0.001, seed=5)
    x = plant.full_state()[[1, 3]]          # the view: hinge, hinge_dot
    seen = np.array([hook(0.0, x, np.zeros(3)) for _ in range(4000)]) - x
    for k, std in enumerate((0.002, 0.03)):
        assert stats.kstest(seen[:, k] / std, "norm").pvalue > 1e-3
    scn = short("ex3_pendulum_ode", **{"effects.noise_std": [0.002, 0.02]})
    noisy, clean = run(scn), run(short("ex3_pendulum_ode"))
    # noise too small to change x leaves the run bit for bit: the controller's draws do
    # not come from the noise stream
    tiny = run(short("ex3_pendulum_ode", **{"effects.noise_std": [1e-300, 1e-300]}))
    assert np.array_equal(tiny.history["u"], clean.history["u"])
    assert noisy.metrics["rmse"] != clean.metrics["rmse"]
    # metrics are on the true state: the recorded x is the plant's, not the noisy one
    assert np.abs(np.diff(noisy.history["x"][:, 0])).max() < 0.002


def test_measurement_delay_is_whole_samples() -> None:
    plant = cartpole_ode_plant()
    hook = Measurement(EffectsConfig(delay=3), plant, 0.001, seed=1)
    seen = [hook(0.0, np.array([float(k), 0.0]), np.zeros(3))[0] for k in range(8)]
    assert seen == [0.0, 0.0, 0.0, 0.0, 1.0, 2.0, 3.0, 4.0]
    r = run(short("ex3_pendulum_ode", **{"effects.delay": 2, "run.duration": 10.0}))
    plain = run(short("ex3_pendulum_ode", **{"run.duration": 10.0}))
    assert r.metrics["rmse_ss"] > 1.2 * plain.metrics["rmse_ss"]


def test_viscous_friction_same_on_both_backends() -> None:
    scn = override(load_scenario("pendulum_friction"),
                   **{"plant.cart_friction": 0.0, "plant.hinge_friction": 0.0})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ModelWarning)
        mj = build_plant(scn)
    ode = build_plant(scn, "cartpole_ode")
    assert ode.params.cart_damping == 5.0 and ode.params.hinge_damping == 0.5
    cmp = open_loop_compare(mj, ode, np.array([0.1, 0.0]),
                            lambda t: chirp_force(t, 100.0, 0.1, 2.0, 5.0), lambda t: 0.05,
                            5.0, 0.001)
    assert np.ptp(cmp.of_a("hinge")) > 1.0 and cmp.max_of("hinge") < 1e-8


def test_dry_friction_damps_a_swing_on_both_backends() -> None:
    """Hanging pole (theta = pi + 0.3) swinging freely: dry hinge friction takes energy out
    on both backends; MuJoCo's soft friction constraint and the ODE's tanh agree in kind."""
    def amplitude(friction: float, kind: str) -> float:
        scn = override(load_scenario("pendulum_friction"),
                       **{"plant.cart_damping": 0.0, "plant.hinge_damping": 0.0,
                          "plant.cart_friction": 0.0, "plant.hinge_friction": friction,
                          "plant.x0": [np.pi + 0.3, 0.0]})
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ModelWarning)
            plant = build_plant(scn, kind)
        for _ in range(8000):
            plant.step(0.0, 0.0, 0.001)
        th = []
        for _ in range(4000):
            plant.step(0.0, 0.0, 0.001)
            th.append(plant.full_state()[1] - np.pi)    # the hinge
        return float(np.ptp(th)) / 2
    for kind in ("cartpole_mujoco", "cartpole_ode"):
        assert amplitude(0.0, kind) > 0.29
        assert amplitude(2.0, kind) < 0.2
    assert amplitude(2.0, "cartpole_mujoco") == pytest.approx(amplitude(2.0, "cartpole_ode"),
                                                             abs=0.03)


def test_parameter_change_reaches_the_compiled_model_and_matches_the_ode() -> None:
    change = EffectsConfig(change=ParameterChange(at=1.0, m=3.0, l=2.0))
    scn = load_scenario("pendulum_mujoco")
    mj = EffectsPlant(build_plant(scn), change)
    ode = EffectsPlant(cartpole_ode_plant(mj.params), change)
    cmp = open_loop_compare(mj, ode, np.array([0.1, 0.0]),
                            lambda t: chirp_force(t, 100.0, 0.1, 2.0, 3.0), lambda t: 0.05,
                            3.0, 0.001)
    assert cmp.max_of("hinge") < 1e-8
    assert mj.params.m == 3.0 and mj.params.l == 2.0
    import mujoco

    full = np.zeros((2, 2))
    model = mj.inner.model                 # the wrapped MuJoCo plant's compiled model
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    mujoco.mj_fullM(model, data, full)
    assert full[0, 0] == pytest.approx(13.0) and abs(full[0, 1]) == pytest.approx(6.0)
    assert full[1, 1] == pytest.approx(4.0 / 3.0 * 3.0 * 4.0)
    # the closed loop feels it: the controller re-adapts after t = 10 s
    scn = override(load_scenario("pendulum_payload_step"), **{"run.duration": 12.0})
    r = run(scn)
    same = run(override(scn, **{"effects.change.at": 100.0}))
    t = r.history["t"]
    before, after = t < 10.0, (t > 10.0) & (t < 12.0)
    assert np.array_equal(r.history["u"][before], same.history["u"][before])
    # the heavier pole needs another force; the adaptive loop finds it and keeps tracking
    assert np.abs(r.history["u"][after] - same.history["u"][after]).max() > 5.0
    assert np.abs(r.history["e"][after, 0]).max() < 0.01


def test_finite_rail_ends_the_run_with_its_status_and_exit_code(tmp_path: Path) -> None:
    scn = override(load_scenario("pendulum_finite_rail"),
                   **{"effects.outer_loop.k_x": 0.0, "effects.outer_loop.k_v": 0.0})
    r = run(scn, plant_kind="cartpole_ode")
    assert r.status == "rail_end" and "exceeds the rail's half-length" in r.end.message
    assert abs(r.history["extra/cart_pos"][-1]) >= 8.0 - 0.1
    metrics = tmp_path / "m.json"
    code = main(["run", "pendulum_finite_rail", "--no-record", "--metrics", str(metrics),
                 "--set", "effects.outer_loop.k_x=0.0", "--set", "effects.outer_loop.k_v=0.0"])
    assert code == 4 and '"rail_end"' in metrics.read_text()


def test_outer_loop_keeps_the_cart_on_the_rail_with_a_smooth_reference() -> None:
    scn = load_scenario("pendulum_finite_rail")
    r = run(scn, plant_kind="cartpole_ode")
    assert r.status == "completed"
    cart = r.history["extra/cart_pos"]
    assert np.abs(cart).max() < 8.0
    ref, t = r.history["ref"], r.history["t"]
    # the shaped reference's derivatives are the derivatives of the shaped reference
    # (r'' has kinks where the lean command meets max_angle: compare all but those)
    for k, quantile in ((0, 1.0), (1, 0.99)):
        fd = np.gradient(ref[:, k], t)
        err = np.abs(fd[5:-5] - ref[5:-5, k + 1])
        assert np.quantile(err, quantile) < 1e-2 * np.abs(ref[:, k + 1]).max()
    plain = run(override(scn, **{"effects.rail": 0.0, "effects.outer_loop.k_x": 0.0,
                                 "effects.outer_loop.k_v": 0.0}), plant_kind="cartpole_ode")
    assert np.abs(plain.history["extra/cart_pos"]).max() > 20.0
