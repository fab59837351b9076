"""tspend compare: runs through the sweep, statistics recomputed from its Parquet table."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("tspend.sweep")

from tspend.cli.main import main  # noqa: E402


def test_compare_prints_table_and_json_that_follow_the_runs(tmp_path, capsys):
    out, js = tmp_path / "runs.parquet", tmp_path / "cmp.json"
    status = main(["compare", "ex3_pendulum_ode", "--controller", "second_type,first_type",
                   "--seeds", "0:4", "--duration", "0.5", "--jobs", "1", "--metrics", str(js),
                   "--out", str(out), "--metric", "rmse,tv_u_per_s", "--resamples", "500"])
    assert status == 0
    text = capsys.readouterr().out
    assert "### ex3_pendulum_ode" in text and "| second_type vs first_type | rmse | 4 |" in text
    runs = pd.read_parquet(out)
    assert len(runs) == 8 and set(runs["status"]) == {"completed"}
    doc = json.loads(js.read_text())
    assert doc["seeds"] == [0, 1, 2, 3]
    for rec in doc["summary"]:
        v = runs.loc[runs.controller == rec["controller"], rec["metric"]]
        assert rec["median"] == pytest.approx(np.median(v), rel=1e-12)
    pair = next(p for p in doc["pairs"] if p["metric"] == "rmse")
    a = runs[runs.controller == "second_type"].sort_values("seed")["rmse"].to_numpy()
    b = runs[runs.controller == "first_type"].sort_values("seed")["rmse"].to_numpy()
    assert pair["median_difference"] == pytest.approx(np.median(a - b), rel=1e-12)
    assert pair["wins"] == float((a < b).sum() + 0.5 * (a == b).sum())


@pytest.mark.parametrize("argv, message", [
    (["--controller", "second_type,nope"], "unknown kind"),
    (["--controller", "second_type"], "at least two"),
    (["--metric", "speed"], "unknown metric"),
    (["--seeds", "5:2"], "--seeds"),
])
def test_bad_input_exits_2_before_anything_runs(tmp_path, capsys, argv, message):
    out = tmp_path / "runs.parquet"
    assert main(["compare", "ex2_duffing", "--out", str(out)] + argv) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()
