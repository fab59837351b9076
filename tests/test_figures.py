"""tspend figures: the files exist, are PNGs, and their CSV data are the runs' arrays."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("matplotlib")

from tspend.studies import figures  # noqa: E402
from tspend.cli.main import main  # noqa: E402
from tspend.scenario import load_scenario, override  # noqa: E402
from tspend.loop.simulation import run  # noqa: E402

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def assert_png(path):
    from matplotlib.image import imread

    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC and len(data) > 5000
    img = imread(path)
    assert img.shape[0] > 200 and img.shape[1] > 300
    assert img[..., :3].std() > 0.01          # not a blank canvas


def read_csv(path):
    return pd.read_csv(path)


def test_paper_figures_match_independent_runs(tmp_path):
    out = figures.Figures(tmp_path)
    pngs = figures.paper_figures(out, seed=2, duration=0.5, every=10)
    assert len(pngs) == 6
    for png in pngs:
        assert_png(png)
        assert png.with_suffix(".csv").stat().st_size > 0
    # the same runs again, independently: the CSVs hold exactly their arrays
    scn = override(load_scenario("ex2_duffing"), **{"run.seed": 2, "run.duration": 0.5})
    capture = figures.SetsCapture()
    second = run(scn, sinks=[capture], controller="second_type")
    first = run(scn, controller="first_type")
    track = read_csv(tmp_path / "ex2_duffing_tracking.csv")
    h2, h1 = second.history, first.history
    np.testing.assert_array_equal(track["t"], h2["t"][::10])
    np.testing.assert_array_equal(track["r"], h2["ref"][::10, 0])
    np.testing.assert_array_equal(track["x1_second_type"], h2["x"][::10, 0])
    np.testing.assert_array_equal(track["x2_second_type"], h2["x"][::10, 1])
    np.testing.assert_array_equal(track["x2_first_type"], h1["x"][::10, 1])
    u = read_csv(tmp_path / "ex2_duffing_u.csv")
    np.testing.assert_array_equal(u["u_second_type"], h2["u"])
    np.testing.assert_array_equal(u["u_first_type"], h1["u"])
    sets = read_csv(tmp_path / "ex2_duffing_memberships.csv")
    x_o2 = sets[(sets["input"] == "x_o2") & (sets["term"] == "NS")]
    grid, curves = capture.last.model_sets[1][:2]
    np.testing.assert_array_equal(x_o2["z"], grid)
    np.testing.assert_array_equal(x_o2["mu_last"], curves[1])
    np.testing.assert_array_equal(x_o2["mu_first"], capture.first.model_sets[1][1][1])
    e1 = read_csv(tmp_path / "ex1_nonaffine_case1_tracking.csv")
    assert list(e1.columns) == ["t", "r", "r_dot", "x1_second_type", "x2_second_type",
                                "x1_first_type", "x2_first_type"]


def sweep_table():
    rng = np.random.default_rng(0)
    recs = []
    for kind, scale in (("second_type", 1.0), ("first_type", 3.0)):
        for eta in (0.01, 0.1):
            for gamma in (0.5, 1.0, 2.0):
                for seed in range(5):
                    st = "diverged" if (kind, eta, gamma, seed) == ("first_type", 0.1, 2.0, 4) \
                        else "completed"
                    recs.append({"scenario": "ex2_duffing", "controller.eta": eta,
                                 "controller.gamma": gamma, "seed": seed, "controller": kind,
                                 "status": st, "message": "",
                                 "rmse_ss": scale * eta * gamma * rng.lognormal(0, 0.3)})
    return pd.DataFrame.from_records(recs)


def test_box_and_heatmap_data_are_the_table(tmp_path):
    t = sweep_table()
    out = figures.Figures(tmp_path)
    one = t[(t["controller.eta"] == 0.1) & (t["controller.gamma"] == 2.0)].drop(
        columns=["controller.eta", "controller.gamma"])
    png = figures.box_figure(out, one, "rmse_ss", "box")
    assert_png(png)
    box = read_csv(tmp_path / "box.csv")
    assert len(box) == len(one)
    div = box[box["status"] == "diverged"]
    assert len(div) == 1 and np.isposinf(div["value"]).all()
    ok = box[box["status"] == "completed"].sort_values(["controller", "seed"])
    ref = one[one["status"] == "completed"].sort_values(["controller", "seed"])
    np.testing.assert_array_equal(ok["value"], ref["rmse_ss"])

    png = figures.heatmap_figure(out, t, "controller.gamma", "controller.eta", "rmse_ss", "heat")
    assert_png(png)
    heat = read_csv(tmp_path / "heat.csv")
    assert len(heat) == 2 * 2 * 3
    for r in heat.to_dict("records"):
        sel = t[(t.controller == r["controller"]) & (t["controller.eta"] == r["controller.eta"])
                & (t["controller.gamma"] == r["controller.gamma"])]
        v = np.where(sel.status == "diverged", np.inf, sel.rmse_ss)
        assert r["median"] == np.median(v)        # 5 values: the median is one of them
        assert r["diverged"] == (sel.status == "diverged").sum()


def test_cli_figures_never_replaces_a_file(tmp_path, capsys):
    t = sweep_table()
    path = tmp_path / "runs.parquet"
    t.to_parquet(path)
    assert main(["figures", "box", str(path), "--out", str(tmp_path / "f"),
                 "--metrics", "rmse_ss"]) == 0
    assert (tmp_path / "f" / "runs_box_rmse_ss.png").stat().st_size > 0
    before = (tmp_path / "f" / "runs_box_rmse_ss.png").read_bytes()
    assert main(["figures", "box", str(path), "--out", str(tmp_path / "f")]) == 2
    assert "exists" in capsys.readouterr().err
    assert (tmp_path / "f" / "runs_box_rmse_ss.png").read_bytes() == before
    assert main(["figures", "heatmap", str(path), "--x", "controller.gamma", "--y", "nope",
                 "--out", str(tmp_path / "g")]) == 2
    assert main(["figures", "box", str(path), "--metrics", "speed"]) == 2
