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
        assert png.with_suffix(".pdf").read_bytes()[:5] == b"%PDF-"
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
                                "x1_first_type", "x2_first_type", "abs_e1_second_type",
                                "abs_e1_first_type"]
    np.testing.assert_array_equal(track["abs_e1_first_type"], np.abs(h1["x"][::10, 0] - h2["ref"][::10, 0]))


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
                 "--metric", "rmse_ss"]) == 0
    assert (tmp_path / "f" / "runs_box_rmse_ss.png").stat().st_size > 0
    before = (tmp_path / "f" / "runs_box_rmse_ss.png").read_bytes()
    assert main(["figures", "box", str(path), "--out", str(tmp_path / "f")]) == 2
    assert "exists" in capsys.readouterr().err
    assert (tmp_path / "f" / "runs_box_rmse_ss.png").read_bytes() == before
    assert main(["figures", "heatmap", str(path), "--x", "controller.gamma", "--y", "nope",
                 "--out", str(tmp_path / "g")]) == 2
    assert main(["figures", "box", str(path), "--metric", "speed"]) == 2


def test_box_plot_fits_a_paper_column_and_counts_runs_that_are_not_data(tmp_path, monkeypatch):
    """Issue 24: 3.5 in wide, every text >= 8 pt (read from the matplotlib figure); runs
    that diverged or fell are markers in the band above the axes, not points among the
    data; PNG, PDF and CSV written, the CSV's plotted rows being exactly what is drawn."""
    from matplotlib.collections import PathCollection
    from matplotlib.text import Text

    t = sweep_table()
    one = t[(t["controller.eta"] == 0.1) & (t["controller.gamma"] == 2.0)].drop(
        columns=["controller.eta", "controller.gamma"]).reset_index(drop=True)
    one.loc[0, "status"] = "fell"          # a second_type run that ended early: not data
    kept = {}
    save = figures.Figures.save

    def keep(self, fig, data, name):
        kept["fig"] = fig
        return save(self, fig, data, name)

    monkeypatch.setattr(figures.Figures, "save", keep)
    png = figures.box_figure(figures.Figures(tmp_path), one, "rmse_ss", "box")
    for suffix, magic in ((".png", PNG_MAGIC), (".pdf", b"%PDF-")):
        assert png.with_suffix(suffix).read_bytes()[:len(magic)] == magic
    assert not list(tmp_path.glob("*partial*"))
    fig = kept["fig"]
    assert fig.get_size_inches()[0] == pytest.approx(figures.COLUMN_WIDTH_IN)
    texts = [x for x in fig.findobj(Text) if x.get_visible() and x.get_text().strip()]
    assert texts and min(x.get_fontsize() for x in texts) >= 8.0
    box = read_csv(tmp_path / "box.csv")
    ax = fig.axes[0]
    # the points drawn inside the axes are exactly the CSV's plotted rows
    drawn = np.concatenate([c.get_offsets()[:, 1] for c in ax.collections
                            if isinstance(c, PathCollection) and c.get_offset_transform() == ax.transData])
    plotted = box[box["plotted"]]
    np.testing.assert_array_equal(np.sort(drawn), np.sort(plotted["value"].to_numpy()))
    assert set(box.loc[~box["plotted"], "status"]) == {"fell", "diverged"}
    assert "fell" not in set(plotted["status"]) and np.isfinite(plotted["value"]).all()
    # the counts are written beside their markers
    counts = [x.get_text() for x in ax.texts]
    assert counts.count("1") == 2
