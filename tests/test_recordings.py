"""Recordings as a researcher reads them (issue 14), checked on the ``.rrd`` read back:
min/max aggregation on chattering series, the cross-check's verdict and differences,
no absolute path in any document, layouts for any controller."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np
import pytest
import pyarrow as pa
import rerun as rr
from rerun.chunk import RrdReader

import tspend
from tspend.cli.main import main
from tspend.recorder import read_scalar_series
from tspend.recorder.crosscheck import VERDICT, diff_entity, read_verdict
from tspend.recorder.series import series_specs
from tspend.controllers.paper.controller import paper_diagnostics


def static_components(path: Path) -> dict[str, dict[str, list]]:
    """entity -> component column name -> python values, for every static chunk."""
    out: dict[str, dict[str, list]] = {}
    for chunk in RrdReader(path).stream().filter(is_static=True).to_chunks():
        batch = chunk.to_record_batch()
        entity = out.setdefault(chunk.entity_path, {})
        for name in batch.schema.names:
            if ":" in name:
                entity[name] = batch.column(batch.schema.get_field_index(name)).to_pylist()
    return out


def documents(path: Path) -> dict[str, str]:
    return {entity: "".join(str(v) for row in cols["TextDocument:text"] for v in (row or []))
            for entity, cols in static_components(path).items() if "TextDocument:text" in cols}


@pytest.fixture(scope="module")
def default_run(tmp_path_factory) -> Path:
    rrd = tmp_path_factory.mktemp("rec") / "run.rrd"
    assert main(["run", "--duration", "1", "--out", str(rrd)]) == 0
    return rrd


@pytest.fixture(scope="module")
def crosscheck_run(tmp_path_factory) -> tuple[Path, dict]:
    tmp = tmp_path_factory.mktemp("cc")
    rrd, js = tmp / "cc.rrd", tmp / "cc.json"
    assert main(["crosscheck", "--duration", "1", "--open-loop-duration", "1",
                 "--json", str(js), "--out", str(rrd)]) == 0
    return rrd, json.loads(js.read_text())


def _policy(components: dict[str, list]) -> list:
    return [v for row in components.get("SeriesLines:aggregation_policy", []) for v in (row or [])]


def test_chattering_series_keep_their_extremes(default_run: Path) -> None:
    """u and every diagnostic declared ``chattering`` carry the MinMax aggregation policy;
    smooth series carry none (the viewer's default)."""
    statics = static_components(default_run)
    minmax = int(rr.components.AggregationPolicy.MinMax.value)
    chattering = {d.panel for d in paper_diagnostics(2) if d.chattering}
    for panel in chattering | {"control"}:
        assert _policy(statics[f"/series/{panel}"]) == [minmax], panel
    assert _policy(statics["/series/tracking"]) == []


def test_log_diagnostics_are_recorded_as_log10(default_run: Path) -> None:
    """V is declared ``log``: the series holds log10 V, and 10**it is V >= 0."""
    _, log_v = read_scalar_series(default_run, "series/lyapunov")
    assert np.all(np.isfinite(log_v)) and log_v.max() < 3.0
    names = [v for row in static_components(default_run)["/series/lyapunov"]["SeriesLines:names"] for v in row]
    assert names == ["log10 V"]


def test_no_document_refers_to_the_recording_machine(default_run: Path, crosscheck_run) -> None:
    """No path in any document exists on this machine as an absolute path."""
    cwd, root = str(Path.cwd().resolve()), str(Path(tspend.__file__).resolve().parents[1])
    for rrd in (default_run, crosscheck_run[0]):
        for entity, text in documents(rrd).items():
            assert root not in text and cwd not in text, entity
            for token in re.findall(r"(?<![\w.~])/[\w./-]+", text):
                assert not (len(token) > 1 and os.path.exists(token)), (entity, token)
    run = documents(default_run)["/info/run"]
    assert "models/cartpole.xml" in run  # the model is still named, relative to the repository


def test_crosscheck_verdict_equals_the_report(crosscheck_run) -> None:
    rrd, report = crosscheck_run
    docs = documents(rrd)
    verdict = docs["/" + VERDICT]
    assert ("PASS" if report["open_loop_ok"] else "FAIL") in verdict.splitlines()[0]
    figures = read_verdict(verdict)
    for key, value in report.items():
        if not isinstance(value, dict):
            assert figures[key] == value, key
    assert figures["tolerance"] == 1e-8


def test_crosscheck_differences_equal_the_reported_figures(crosscheck_run) -> None:
    """MuJoCo minus ODE, sample by sample: the recorded difference is exactly the two
    runs' recorded states subtracted, and its maximum is the report's figure."""
    rrd, report = crosscheck_run
    for key, column, figure in (("x1", 1, "closed_loop_max_dhinge"), ("x2", None, "closed_loop_max_dhinge_dot")):
        t, diff = read_scalar_series(rrd, diff_entity(key))
        assert t.size == 1000
        assert np.abs(diff).max() == report[figure]
    _, mj = read_scalar_series(rrd, "mujoco/series/tracking", 1)
    _, ode = read_scalar_series(rrd, "ode/series/tracking", 1)
    _, d1 = read_scalar_series(rrd, diff_entity("x1"))
    np.testing.assert_array_equal(d1, mj - ode)
    _, dc = read_scalar_series(rrd, diff_entity("cart_pos"))
    _, cmj = read_scalar_series(rrd, "mujoco/series/plant/cart_pos")
    _, code = read_scalar_series(rrd, "ode/series/plant/cart_pos")
    np.testing.assert_array_equal(dc, cmj - code)


def test_crosscheck_documents_describe_each_backend(crosscheck_run) -> None:
    docs = documents(crosscheck_run[0])
    assert 'kind = "cartpole_ode"' in docs["/ode/info/scenario"].split("overridden for this run")[1]
    assert "cartpole_mujoco" in docs["/mujoco/info/scenario"].splitlines()[0]

def _recording_names(rrd: Path) -> list[str]:
    return [v for row in static_components(rrd).get("/__properties", {}).get("RecordingInfo:name", [])
            for v in (row or [])]


def test_recordings_are_named(default_run: Path, crosscheck_run) -> None:
    assert _recording_names(default_run) == ["pendulum_mujoco (second_type, seed 1)"]
    assert _recording_names(crosscheck_run[0]) == ["pendulum_mujoco: cross-check MuJoCo vs ODE (seed 1)"]


def test_layout_follows_the_declared_diagnostics() -> None:
    """A controller declaring its own panels gets one view each; log ones hold log10."""
    from tspend.controllers.base import diagnostics

    diags = diagnostics(("s", 1, {"panel": "sliding", "unit": "", "chattering": True}),
                        ("gain", 2, {"panel": "sliding", "log": True}))
    specs = {s.entity: s for s in series_specs(2, ("cart_pos",), diags, "cartpole_ode")}
    assert specs["series/sliding"].minmax and specs["series/sliding"].names == ("s",)
    assert specs["series/sliding_log10"].names == ("log10 gain_1", "log10 gain_2")
    assert specs["series/tracking"].names == ("r", "theta") and "rad" in specs["series/tracking"].title
    assert "N" in specs["series/control"].title and specs["series/control"].minmax
    assert specs["series/plant/cart_pos"].title == "cart position x_c (m)"


def test_recorder_reachable_from_the_package() -> None:
    """The README's recipe: ``import tspend`` then ``tspend.recorder.open_recording``."""
    import importlib
    import sys

    sys.modules.pop("tspend.recorder", None)
    pkg = importlib.reload(tspend)
    assert callable(pkg.recorder.open_recording)


def test_tensor_columns_match_the_sdk_or_fail_clearly(monkeypatch) -> None:
    """The one hand-built Arrow column equals the SDK's own encoding; a changed encoding
    (simulated: the SDK's tensor turned into float64) stops with a message naming the version."""
    from tspend.recorder import arrow

    arrow.check_tensor_type.cache_clear()
    arrow.check_tensor_type()  # the installed SDK: no error

    class Float64Tensor(rr.Tensor):
        def __init__(self, array, dim_names=None):
            super().__init__(np.asarray(array, dtype=np.float64), dim_names=dim_names)

    monkeypatch.setattr(rr, "Tensor", Float64Tensor)
    arrow.check_tensor_type.cache_clear()
    with pytest.raises(arrow.RerunVersionError, match=r"rerun-sdk .*TensorData.*tspend/recorder/arrow.py needs updating"):
        arrow.check_tensor_type()
    monkeypatch.undo()
    arrow.check_tensor_type.cache_clear()
