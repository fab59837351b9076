"""Identification (tspend identify, tspend.studies.identify): recovery of known parameters
from records MuJoCo itself simulates (an independent simulation of the MJCF), the
uncertainty's coverage, refusal of unidentifiable sets and bad data, the calibrated MJCF."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pandas as pd
import pytest

from tspend.cli.main import main
from tspend.controllers.excitation import ExcitationSettings, design_signal, excitation
from tspend.plants import mjcf
from tspend.studies import identify as ident
from tspend.studies.identify_model import load_model

ROOT = Path(__file__).resolve().parents[1]
CARTPOLE = str(ROOT / "models" / "cartpole.xml")


def mujoco_record(path: str, T: float = 4.0, amp: float = 20.0, seed: int = 0) -> pd.DataFrame:
    """MuJoCo steps the model open loop under a multisine force (held over each step)."""
    m = mujoco.MjModel.from_xml_path(path)
    d = mujoco.MjData(m)
    n = int(round(T / m.opt.timestep))
    t = np.arange(n) * m.opt.timestep
    rng = np.random.default_rng(seed)
    f = np.linspace(0.3, 3.0, 6)
    u = amp * np.sin(2 * np.pi * np.multiply.outer(t, f) + rng.uniform(0, 6.28, 6)).sum(1) / 3
    hinge = m.joint("hinge").qposadr[0]
    slide = m.joint("slider").qposadr[0]
    q = np.empty((n, 2))
    for i in range(n):
        q[i] = d.qpos[hinge], d.qpos[slide]
        d.ctrl[0] = u[i]
        mujoco.mj_step(m, d)
    return pd.DataFrame({"t_s": t, "theta_rad": q[:, 0], "cart_x_m": q[:, 1], "u_N": u})


@pytest.fixture(scope="module")
def truth(tmp_path_factory) -> tuple[str, dict]:
    """A cart-pole whose pole and cart masses differ from models/cartpole.xml's."""
    d = tmp_path_factory.mktemp("ident")
    values = {"m": 1.12, "M": 9.3}
    load_model(CARTPOLE).write(values, d / "true.xml")
    return str(d / "true.xml"), values


def test_written_mjcf_compiles_and_carries_the_values(truth):
    path, values = truth
    model = mujoco.MjModel.from_xml_path(path)
    facts = mjcf.read_facts(model, "slider", "hinge", "force", path)
    assert facts.pole_mass == pytest.approx(values["m"], rel=1e-12)
    assert facts.cart_mass == pytest.approx(values["M"], rel=1e-12)
    text = Path(path).read_text()
    assert "m (pole mass, kg): 1 -> 1.12" in text and "M (cart mass, kg): 10 -> 9.3" in text
    assert load_model(path).nominal["m"] == pytest.approx(1.12)


def test_recovers_known_parameters_from_a_noiseless_mujoco_record(truth, tmp_path):
    path, values = truth
    mujoco_record(path).to_csv(tmp_path / "r.csv", index=False)
    model = load_model(CARTPOLE)                      # starts from the nominal 1 and 10 kg
    rec = ident.read_record(tmp_path / "r.csv", model)
    fit = ident.fit(model, rec, ("m", "M"), segment_s=0.5)
    for k, v in values.items():
        assert fit.values[k] == pytest.approx(v, rel=1e-6)
    assert all(v < 1e-8 for v in fit.rms_validation.values())
    assert fit.rms_validation["hinge"] < 1e-3 * fit.rms_validation_nominal["hinge"]


def test_the_interval_covers_the_truth_on_noisy_records(truth, tmp_path):
    """Three noise draws: each truth within 3 reported std, and the reported std matches
    the spread of the estimates (the Gauss-Newton covariance is the estimator's)."""
    path, values = truth
    clean = mujoco_record(path, T=3.0)
    model = load_model(CARTPOLE)
    z, ests, stds = [], [], []
    for seed in range(3):
        rng = np.random.default_rng(seed)
        df = clean.copy()
        for c in ("theta_rad", "cart_x_m"):
            df[c] = df[c] + 1e-3 * rng.standard_normal(len(df))
        df.to_csv(tmp_path / f"n{seed}.csv", index=False)
        rec = ident.read_record(tmp_path / f"n{seed}.csv", model)
        fit = ident.fit(model, rec, ("m", "M"), segment_s=1.0)
        z += [(fit.values[k] - values[k]) / fit.std[k] for k in values]
        ests.append(fit.values["m"])
        stds.append(fit.std["m"])
        assert fit.noise_std["hinge"] == pytest.approx(1e-3, rel=0.1)
    assert max(abs(v) for v in z) < 3.0, z
    assert 0.0 < np.mean(stds) < 0.05 * values["m"]


def run_cli(capsys, *args) -> tuple[int, str]:
    status = main(["identify", *map(str, args)])
    err = capsys.readouterr().err.strip().splitlines()
    return status, err[-1] if err else ""


def test_m_M_and_gear_together_are_refused_naming_the_ratios(truth, tmp_path, capsys):
    path, _ = truth
    mujoco_record(path, T=3.0).to_csv(tmp_path / "r.csv", index=False)
    status, line = run_cli(capsys, tmp_path / "r.csv", "--model", CARTPOLE, "--params",
                           "m,M,gear", "--out", tmp_path / "fit.xml")
    assert status == 2
    assert "not identifiable" in line and "m/gear" in line and "M/gear" in line, line
    assert not (tmp_path / "fit.xml").exists()


@pytest.mark.parametrize("problem, edit, words", [
    ("short", lambda df: df.iloc[:50], "too short"),
    ("time", lambda df: df.assign(t_s=df.t_s.where(df.index != 100, 0.0)), "not increasing at row"),
    ("nan", lambda df: df.assign(theta_rad=df.theta_rad.where(df.index != 7)), "NaN"),
    ("column", lambda df: df.drop(columns=["cart_x_m"]), "no position of 'slider' column"),
    ("constant input", lambda df: df.assign(u_N=0.0), "excites nothing"),
])
def test_bad_data_is_one_line_and_exit_2(problem, edit, words, tmp_path, capsys):
    df = edit(mujoco_record(CARTPOLE, T=0.6))
    df.to_csv(tmp_path / "bad.csv", index=False)
    status, line = run_cli(capsys, tmp_path / "bad.csv", "--model", CARTPOLE, "--params", "m",
                           "--out", tmp_path / "fit.xml")
    assert status == 2 and words in line, line
    assert not (tmp_path / "fit.xml").exists()


def test_export_names_of_either_vocabulary_are_read(tmp_path):
    df = mujoco_record(CARTPOLE, T=0.5).rename(columns={"theta_rad": "hinge_rad",
                                                        "cart_x_m": "slider_m"})
    df.to_csv(tmp_path / "r.csv", index=False)
    rec = ident.read_record(tmp_path / "r.csv", load_model(CARTPOLE))
    assert rec.columns["position:hinge"] == "hinge_rad"
    assert rec.columns["position:slider"] == "slider_m"


@pytest.mark.parametrize("signal", ["multisine", "chirp", "prbs"])
def test_excitation_stays_within_its_amplitude_and_starts_quietly(signal):
    s = ExcitationSettings(signal=signal, amplitude=2.5, f_min_hz=0.2, f_max_hz=4.0)
    t = np.arange(0.0, 30.0, 1e-3)
    e = excitation(s, t)
    assert np.max(np.abs(e)) <= 2.5 + 1e-9
    assert np.all(e[t < s.start_s] == 0.0)
    late = e[t > s.start_s + s.ramp_s]
    assert np.max(np.abs(late)) > 0.6 * 2.5 and abs(np.mean(late)) < 0.2 * 2.5


@pytest.mark.parametrize("signal", ["multisine", "chirp", "prbs"])
def test_the_designed_signal_gives_each_sample_what_the_whole_signal_has(signal):
    """A controller evaluates the signal designed for a 2 s run one sample at a time; the
    samples are the excitation computed at once over 3 s (past the horizon: prbs draws its
    bits anew, and a longer draw begins with the shorter's bits)."""
    s = ExcitationSettings(signal=signal, amplitude=2.0, f_min_hz=0.5, f_max_hz=20.0,
                           start_s=0.1, ramp_s=0.2)
    t = np.arange(0.0, 3.0, 1e-3)
    designed = design_signal(s, 2.0)
    one_by_one = np.array([float(designed.at(x)) for x in t])
    # the multisine's own independent sum (no design): lines, Schroeder phases, the peak
    f = np.geomspace(0.5, 20.0, s.n_freq)
    k = np.arange(1, s.n_freq + 1)
    lines = np.sin(2 * np.pi * np.multiply.outer(np.maximum(t - 0.1, 0), f)
                   - np.pi * k * (k - 1) / s.n_freq).sum(-1)
    whole = excitation(s, t)
    np.testing.assert_allclose(one_by_one, whole, rtol=0, atol=1e-12)
    if signal == "multisine":
        # one scale, 1 / the peak, wherever the clip at the amplitude did not act
        ratio = whole / (2.0 * lines)
        unclipped = (t > 0.3) & (np.abs(lines) > 1) & (np.abs(whole) < 2.0 - 1e-9)
        assert unclipped.sum() > 2000 and np.ptp(ratio[unclipped]) < 1e-12
    if signal == "prbs":  # the bits of 1.9 s at 40 per second, not of the whole 3 s
        assert 76 <= designed.bits.size <= 77
        assert np.all(np.abs(whole[t > 0.3]) == 2.0)


@pytest.mark.parametrize("extra, words", [
    (("--segment", "1e-9"), "--segment 1e-09: shorter than 10 samples"),
    (("--uncertainty", "bootstrap", "--bootstrap", "1000000000"), "from 1 to 10000"),
    (("--seed", "-1"), "--seed: must be an integer from 0"),
    (("--fix", "M=-5"), "--fix M=-5: must be >= 0 (cart mass, kg)"),
    (("--fix", "gear=0"), "--fix gear=0: must not be 0"),
    (("--validation", "1e-6", "--segment", "0.3", "--figure", "fig.png"), "no validation windows"),
])
def test_bad_numbers_are_refused_and_nothing_of_the_users_is_replaced(extra, words, tmp_path,
                                                                      capsys):
    mujoco_record(CARTPOLE, T=1.0).to_csv(tmp_path / "r.csv", index=False)
    for name in ("cal.xml", "fit.json", "fig.png"):
        (tmp_path / name).write_text(f"the user's {name}\n")
    status = main(["identify", str(tmp_path / "r.csv"), "--model", CARTPOLE, "--params", "m",
                   "--out", str(tmp_path / "cal.xml"), "--metrics", str(tmp_path / "fit.json"),
                   *[str(tmp_path / a) if a == "fig.png" else a for a in extra]])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and words in err[0], err
    for name in ("cal.xml", "fit.json", "fig.png"):
        assert (tmp_path / name).read_text() == f"the user's {name}\n"


def test_the_figure_of_a_one_joint_machine_is_drawn(tmp_path):
    from types import SimpleNamespace

    from tspend.cli.identify import fit_figure

    t = np.linspace(0.0, 1.0, 11)[None, :]
    trace = {"t": t, "head": 2, "measured": np.zeros((1, 1, 11)),
             "predicted": np.zeros((1, 1, 11)), "predicted_nominal": np.ones((1, 1, 11))}
    fit_figure(SimpleNamespace(validation_trace=trace),
               SimpleNamespace(dof=1, state_names=("hinge", "hinge_dot")), tmp_path / "f.png")
    assert (tmp_path / "f.png").read_bytes()[:4] == b"\x89PNG"


def test_excite_touches_no_file_of_the_users_and_names_no_temporary_file(tmp_path, capsys,
                                                                        monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / ".x.toml.check.toml").write_text("the user's\n")
    assert main(["excite", "ex2_duffing", "--out", "x.toml"]) == 0   # an unbounded input
    assert (tmp_path / ".x.toml.check.toml").read_text() == "the user's\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == [".x.toml.check.toml", "x.toml"]
    kept = (tmp_path / "x.toml").read_text()
    capsys.readouterr()
    for extra, words in ((("--f-max", "1e6"), "at most 10000 times --f-min"),
                         (("--f-max", "600"), "above 500 Hz, half the rate")):
        assert main(["excite", "pendulum_mujoco", "--out", "x.toml", *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0] and "trial.toml" not in err[0], err
    assert (tmp_path / "x.toml").read_text() == kept
