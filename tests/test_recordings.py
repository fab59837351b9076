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

from tspend.recorder.timeseries import recording_table

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
                 "--metrics", str(js), "--out", str(rrd)]) == 0
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
    assert specs["series/tracking"].names == ("r (rad)", "theta (rad)") and "rad" in specs["series/tracking"].title
    assert "N" in specs["series/control"].title and specs["series/control"].minmax
    assert specs["series/plant/cart_pos"].title == "cart position x_c (m)"
    assert specs["series/plant/cart_pos"].names == ("x_c (m)",)


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


def _entities(rrd: Path) -> set[str]:
    return {chunk.entity_path for chunk in RrdReader(rrd).stream().to_chunks()}


def test_initial_membership_functions_beside_the_adapted_ones(default_run: Path) -> None:
    """Issue 24: every input's first curves under /fuzzy/.../initial, equal to the first
    curves the run sent (read back), so adaptation shows as a distance between two sets."""
    initial = sorted(e for e in _entities(default_run) if e.startswith("/fuzzy/") and "initial" in e)
    assert "/fuzzy/model/in0/initial" in initial and "/fuzzy/compensator/in0/initial" in initial
    first = None
    for chunk in RrdReader(default_run).stream().to_chunks():
        if chunk.entity_path == "/fuzzy/model/in0" and "sim_time" in chunk.timeline_names:
            batch = chunk.to_record_batch()
            names = batch.schema.names
            if "LineStrips2D:strips" in names:
                first = batch.column(names.index("LineStrips2D:strips")).to_pylist()[0]
                break
    stored = static_components(default_run)["/fuzzy/model/in0/initial"]["LineStrips2D:strips"][0]
    assert first is not None and len(stored) == len(first)
    np.testing.assert_array_equal(np.asarray(stored, dtype=float), np.asarray(first, dtype=float))


def test_crosscheck_differences_on_a_log10_scale(crosscheck_run) -> None:
    """Issue 24: under /crosscheck/ a log10 |MuJoCo - ODE| per state, floored at 1e-16,
    equal to log10 of the signed difference read back."""
    from tspend.recorder.crosscheck import DIFF_FLOOR, log10_diff_entity

    rrd, _ = crosscheck_run
    logs = {e for e in _entities(rrd) if e.startswith("/crosscheck/") and "log10" in e}
    assert {"/" + log10_diff_entity(k) for k in ("x1", "x2", "cart_pos")} <= logs
    for key in ("x1", "x2", "cart_pos"):
        t_log, log_d = read_scalar_series(rrd, log10_diff_entity(key))
        t, d = read_scalar_series(rrd, diff_entity(key))
        np.testing.assert_array_equal(t_log, t)
        np.testing.assert_allclose(log_d, np.log10(np.maximum(np.abs(d), DIFF_FLOOR)), rtol=0, atol=1e-12)
        assert log_d.min() >= np.log10(DIFF_FLOOR)


def test_steady_state_and_compensator_share_series(default_run: Path) -> None:
    """The steady-state view holds e_1 from T/2 on only; the compensator's share of u is
    -u_s / b_hat of the recorded series (u's unit), not u_s itself."""
    diags = paper_diagnostics(2)
    specs = {s.entity: s for s in series_specs(2, ("cart_pos", "cart_vel"), diags, "cartpole_mujoco")}
    t_ss, e_ss = read_scalar_series(default_run, "series/error_steady")
    t, e1 = read_scalar_series(default_run, "series/error", 0)
    assert t_ss[0] >= 0.5 * 1.0 - 1e-9 and t_ss.size < t.size
    np.testing.assert_array_equal(e_ss, e1[-t_ss.size:])
    _, share = read_scalar_series(default_run, "series/compensator_share")
    _, u_s = read_scalar_series(default_run, "series/compensator")
    _, b_hat = read_scalar_series(default_run, "series/params", 2)
    np.testing.assert_allclose(share, -u_s / b_hat, rtol=1e-12)
    assert "(N)" in specs["series/compensator_share"].title and "N" not in specs["series/compensator"].title


def test_full_state_recorded_with_the_domains_names(default_run: Path) -> None:
    """Issue 24: every entry of the plant's full state is a series of its own, named by
    the domain with its unit; the pole's is the tracked x1 sample for sample."""
    styles = static_components(default_run)
    names = {e: styles[e]["SeriesLines:names"][0][0] for e in styles
             if e.startswith("/series/state/") and "SeriesLines:names" in styles[e]}
    assert names == {"/series/state/slider": "x_c (m)", "/series/state/hinge": "theta (rad)",
                     "/series/state/slider_dot": "x_c' (m/s)",
                     "/series/state/hinge_dot": "theta' (rad/s)"}
    _, hinge = read_scalar_series(default_run, "series/state/hinge")
    _, x1 = read_scalar_series(default_run, "series/tracking", 1)
    np.testing.assert_array_equal(hinge, x1)
    _, cart = read_scalar_series(default_run, "series/state/slider")
    # the plant's extra that repeats a state (the cart's position is the slide joint's) is
    # in no view, and a compact recording leaves it out
    with pytest.raises(KeyError):
        read_scalar_series(default_run, "series/plant/cart_pos")


def test_rail_ends_drawn_and_a_terminated_run_marked_where_it_ended(tmp_path: Path) -> None:
    """Issue 24: the task's bounds in the world view (the rail's ends at +/- effects.rail,
    the fall angle as rays from the pivot); a run the rail ended carries its reason on
    the timeline (events), as a cross on the tracking view at its last sample and as a
    label in the 3D view, from the time it ended."""
    rrd = tmp_path / "rail.rrd"
    status = main(["run", "--duration", "1", "--set", "effects.rail=0.05", "--out", str(rrd)])
    assert status == 4
    styles = static_components(rrd)
    posts = styles["/world/rail/ends"]["LineStrips3D:strips"][0]
    np.testing.assert_allclose(sorted({strip[0][0] for strip in posts}), [-0.05, 0.05], rtol=1e-6)  # float32
    assert any("rail_end +0.05 m" in str(v) for v in styles["/world/rail/ends/labels"]["Points3D:labels"][0])
    rays = styles["/world/cart/bounds"]["LineStrips3D:strips"][0]
    assert len(rays) == 2  # the fall angle, pi/2 either side
    table, _ = recording_table(rrd)  # every sample (the views are thinned)
    t_x, x1 = table["t_s"].to_numpy(), table["hinge_rad"].to_numpy()
    t_end, marked = read_scalar_series(rrd, "series/end")
    assert t_end.tolist() == [t_x[-1]] and marked.tolist() == [x1[-1]]
    events = [row for chunk in RrdReader(rrd).stream().filter(content="/events").to_chunks()
              for row in chunk.to_record_batch().column("TextLog:text").to_pylist()]
    assert len(events) == 1 and f"rail_end at t = {t_x[-1]:.4f} s" in str(events[0])
    label = [chunk for chunk in RrdReader(rrd).stream().filter(content="/world/cart/end",
                                                                is_static=False).to_chunks()]
    assert label and "rail_end at t =" in str(label[0].to_record_batch().column("Points3D:labels").to_pylist())
