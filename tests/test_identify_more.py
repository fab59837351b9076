"""Identification beyond the cart-pole's m, l, M (docs/identify.md): the articulated
machines through their derived equations (recovery from records MuJoCo itself simulates),
sensor offsets, dry friction refused with its reason, unidentifiable articulated sets
refused naming what the data fix, and the bootstrap's intervals against the curvature's."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pandas as pd
import pytest

from tspend.cli.main import main
from tspend.studies import identify as ident
from tspend.studies.identify_model import load_model
from tests.test_identify import CARTPOLE, mujoco_record

ROOT = Path(__file__).resolve().parents[1]
DOUBLE = ROOT / "models" / "double_cartpole.xml"


@pytest.fixture(scope="module")
def double(tmp_path_factory) -> tuple[str, str, dict]:
    """A 5 ms copy of the double cart-pole (the nominal machine) and a true machine whose
    lower link is heavier and stiffer to turn (inertia about its COM), the upper link's
    centre of mass lower and the lower hinge damped."""
    d = tmp_path_factory.mktemp("double")
    spec = mujoco.MjSpec.from_file(str(DOUBLE))
    spec.option.timestep = 0.005
    (d / "nominal.xml").write_text(spec.to_xml())
    # a rod's two transverse inertias move together (MuJoCo's triangle inequality); only
    # the one about the hinge's axis (y: inertia_2) acts on the planar motion
    truth = {"link1.mass": 0.56, "link2.ipos_z": 0.36, "hinge1.damping": 0.01,
             "link1.inertia_1": 0.0115, "link1.inertia_2": 0.0115}
    load_model(str(d / "nominal.xml")).write(truth, d / "true.xml")
    return str(d / "nominal.xml"), str(d / "true.xml"), truth


def hanging_record(path: str, T: float = 2.5) -> pd.DataFrame:
    """MuJoCo steps the chain open loop, hanging (stable) and swinging under a multisine
    push on the cart."""
    m = mujoco.MjModel.from_xml_path(path)
    d = mujoco.MjData(m)
    d.qpos[:] = [0.0, np.pi - 0.3, 0.2]
    n = int(round(T / m.opt.timestep))
    t = np.arange(n) * m.opt.timestep
    f = np.array([0.4, 0.9, 1.7, 2.9])
    u = 3.0 * np.sin(2 * np.pi * np.multiply.outer(t, f) + np.arange(4.0)).sum(1)
    q = np.empty((n, 3))
    for i in range(n):
        q[i] = d.qpos
        d.ctrl[0] = u[i]
        mujoco.mj_step(m, d)
    return pd.DataFrame({"t_s": t, "slider_m": q[:, 0], "hinge1_rad": q[:, 1],
                         "hinge2_rad": q[:, 2], "u": u})


def test_double_cartpole_parameters_recovered_and_written(double, tmp_path):
    """Mass, inertia, centre of mass and damping of a MuJoCo-simulated chain come back exactly (the
    derived equations are MuJoCo's own: RK4 on both sides), the identified model predicts
    the held-back part to round-off where the nominal one misses by centimetres, and the
    calibrated MJCF compiles to the true machine's parameter vector."""
    nominal, true, truth = double
    hanging_record(true).to_csv(tmp_path / "r.csv", index=False)
    model = load_model(nominal)
    assert model.domain == "articulated"
    rec = ident.read_record(tmp_path / "r.csv", model)
    names = tuple(k for k in truth if k != "link1.inertia_1")
    fit = ident.fit(model, rec, names, segment_s=0.4)
    for k in names:
        assert fit.values[k] == pytest.approx(truth[k], rel=1e-7), k
    for c in ("slider", "hinge1", "hinge2"):
        assert fit.rms_validation[c] < 1e-8
        assert fit.rms_validation_nominal[c] > 1e3 * fit.rms_validation[c]
    changes = model.write({**fit.values, "link1.inertia_1": 0.0115}, tmp_path / "cal.xml")
    assert any(c.startswith("link1.mass (mass of body link1, kg): 0.5 -> 0.56") for c in changes)
    text = (tmp_path / "cal.xml").read_text()
    assert "hinge1.damping (viscous damping of joint hinge1, N m s/rad)" in text
    got, want = load_model(str(tmp_path / "cal.xml")).nominal, load_model(true).nominal
    for k in want:
        assert got[k] == pytest.approx(want[k], rel=1e-6, abs=1e-9), k


def test_sensor_offset_is_fitted_and_a_slider_offset_refused(tmp_path, capsys):
    """A constant bias on the measured hinge angle is found beside the pole's mass (the
    record is MuJoCo's with 0.02 rad added); a cart's offset changes no motion on a
    frictionless rail (translation invariance), so it is refused."""
    df = mujoco_record(CARTPOLE, T=3.0)
    df["theta_rad"] += 0.02
    df.to_csv(tmp_path / "r.csv", index=False)
    model = load_model(CARTPOLE)
    rec = ident.read_record(tmp_path / "r.csv", model)
    fit = ident.fit(model, rec, ("m", "hinge.offset"), segment_s=0.5)
    assert fit.values["hinge.offset"] == pytest.approx(0.02, abs=1e-8)
    assert fit.values["m"] == pytest.approx(1.0, rel=1e-7)
    status = main(["identify", str(tmp_path / "r.csv"), "--model", CARTPOLE, "--params",
                   "m,slider.offset", "--segment", "0.5"])
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert status == 2 and "slider.offset" in line and "does not depend" in line, line


def test_frictionloss_refused_naming_why(double, tmp_path, capsys):
    nominal, true, _ = double
    hanging_record(true, T=1.2).to_csv(tmp_path / "r.csv", index=False)
    status = main(["identify", str(tmp_path / "r.csv"), "--model", nominal, "--params",
                   "hinge1.frictionloss", "--out", str(tmp_path / "c.xml")])
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert status == 2 and "frictionloss" in line and "constraint solver" in line, line
    assert not (tmp_path / "c.xml").exists()


def test_unidentifiable_articulated_set_refused_naming_three_combinations(double, tmp_path, capsys):
    """Cart mass, lower link's mass, centre of mass and inertia: the motion fixes the total
    mass m0 + m1, the first moment m1 c1 and the inertia about the hinge I1 + m1 c1^2:
    three combinations of four parameters."""
    nominal, true, _ = double
    hanging_record(true, T=1.2).to_csv(tmp_path / "r.csv", index=False)
    status = main(["identify", str(tmp_path / "r.csv"), "--model", nominal, "--params",
                   "cart.mass,link1.mass,link1.ipos_z,link1.inertia_2", "--segment", "0.4",
                   "--out", str(tmp_path / "c.xml")])
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert status == 2 and "not identifiable" in line and "only 3 combinations" in line, line
    assert not (tmp_path / "c.xml").exists()


def hanging_cartpole(path: str, T: float, seed: int) -> pd.DataFrame:
    """MuJoCo steps the cart-pole open loop from hanging under a multisine push (the
    pole swings through every segment); white noise of 1 mrad / 1 mm on the positions."""
    m = mujoco.MjModel.from_xml_path(path)
    d = mujoco.MjData(m)
    h, s = m.joint("hinge").qposadr[0], m.joint("slider").qposadr[0]
    d.qpos[h] = np.pi - 0.5
    n = int(round(T / m.opt.timestep))
    t = np.arange(n) * m.opt.timestep
    u = 15.0 * np.sin(2 * np.pi * np.multiply.outer(t, [0.3, 0.7, 1.3, 2.1]) + np.arange(4.0)).sum(1)
    q = np.empty((n, 2))
    for i in range(n):
        q[i] = d.qpos[h], d.qpos[s]
        d.ctrl[0] = u[i]
        mujoco.mj_step(m, d)
    rng = np.random.default_rng(seed)
    return pd.DataFrame({"t_s": t, "theta_rad": q[:, 0] + 1e-3 * rng.standard_normal(n),
                         "cart_x_m": q[:, 1] + 1e-3 * rng.standard_normal(n), "u_N": u})


def test_bootstrap_spread_agrees_with_the_curvature_and_is_seeded(tmp_path):
    """White noise: the segment bootstrap's spread and the Gauss-Newton std are two
    estimates of one spread (within a factor 2), the estimate lies within 3 of them of the
    truth, the interval is the replicates' percentiles, and the same seed gives the same
    interval."""
    spec = mujoco.MjSpec.from_file(CARTPOLE)
    spec.option.timestep = 0.005                  # a coarser copy keeps the test quick
    (tmp_path / "cp5.xml").write_text(spec.to_xml())
    hanging_cartpole(str(tmp_path / "cp5.xml"), 3.0, 5).to_csv(tmp_path / "n.csv", index=False)
    model = load_model(str(tmp_path / "cp5.xml"))
    rec = ident.read_record(tmp_path / "n.csv", model)
    a = ident.fit(model, rec, ("m", "M"), segment_s=0.25, bootstrap=10,
                  rng=np.random.default_rng(1))
    assert a.uncertainty == "bootstrap" and a.replicates.shape == (10, 2)
    for k, truth in (("m", 1.0), ("M", 10.0)):
        ratio = a.std[k] / a.std_curvature[k]
        assert 0.5 < ratio < 2.0, (k, ratio)
        assert abs(a.values[k] - truth) < 3.0 * a.std[k], (k, a.values[k], a.std[k])
        col = a.replicates[:, a.names.index(k)]
        assert a.interval(k) == pytest.approx(tuple(np.percentile(col, [2.5, 97.5])))
    # the same seed, the same resampling: the same replicates, drawn in order
    b = ident.fit(model, rec, ("m", "M"), segment_s=0.25, bootstrap=3,
                  rng=np.random.default_rng(1))
    np.testing.assert_array_equal(a.replicates[:3], b.replicates)


def test_identify_finds_a_shipped_model_as_inspect_does(tmp_path, monkeypatch, capsys):
    """``--model models/cartpole.xml`` from a folder without models/ is the shipped model,
    as ``tspend inspect models/cartpole.xml`` finds it (issue 51, item 2: "no such file"
    from an installed wheel); what is then missing is the data, and the one line says so."""
    monkeypatch.chdir(tmp_path)
    assert main(["inspect", "models/cartpole.xml"]) == 0
    capsys.readouterr()
    status = main(["identify", "e3.csv", "--model", "models/cartpole.xml", "--params", "m"])
    err = capsys.readouterr().err
    assert status == 2 and "e3.csv" in err and "--model" not in err, err
