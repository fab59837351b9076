"""The Rerun recorder, driven with synthetic runs and read back with ``RrdReader``."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

import pytest
import rerun as rr
from rerun.chunk import RrdReader

from tspend.recorder import (
    RerunSink,
    build_blueprint,
    close_recording,
    open_recording,
    read_scalar_series,
    series_location,
)
from tspend.controllers.paper.controller import paper_diagnostics
from tspend.loop.sinks import Block, FuzzyInputInfo, InnerSnapshot, RunEnd, RunInfo

SCENARIO = '[plant]\nkind = "cartpole_ode"\nM = 10.0\n\n[run]\nduration = 3.0\n'
TERMS = ("NB", "NS", "Z", "PS", "PB")
DT = 0.001


def cartpole_drawing():
    """The drawing of models/cartpole.xml (pendulum_mujoco's)."""
    from tspend import load_scenario
    from tspend.loop.simulation import build_plant
    from tspend.plants.registry import drawing

    scn = load_scenario("pendulum_mujoco")
    return drawing(build_plant(scn), scn)


def make_info(order: int = 2, plant_kind: str = "cartpole_ode", steps: int = 3000) -> RunInfo:
    extras = ("cart_pos", "cart_vel") if "cartpole" in plant_kind else ()
    model = tuple(FuzzyInputInfo(f"x_o{i + 1}", -1.0, 1.0, TERMS) for i in range(order)) + (
        FuzzyInputInfo("u_o", -5.0, 5.0, TERMS),)
    comp = (FuzzyInputInfo("e_delta", -2.0, 2.0, ("N", "Z", "P")), FuzzyInputInfo("|x|", 0.0, 3.0, ("S", "B")))
    return RunInfo(scenario_name="synthetic", scenario_text=SCENARIO, scenario_path="scenarios/synthetic.toml",
                   seed=1234, version="0.1.0", plant_kind=plant_kind, order=order, dt=DT, duration=steps * DT,
                   steps=steps, model_inputs=model, compensator_inputs=comp, extras=extras,
                   controller_kind="second_type", diagnostics=paper_diagnostics(order),
                   drawing=cartpole_drawing() if extras else None)


def make_run(order: int, steps: int, seed: int = 0) -> dict[str, np.ndarray]:
    """Synthetic per-step arrays with the shapes of the block table in ``tspend.loop.sinks``."""
    rng = np.random.default_rng(seed)
    t = np.arange(steps) * DT
    n = order
    x = np.column_stack([np.sin(2.0 * t + i) * 0.3 for i in range(n)]) + 1e-3 * rng.standard_normal((steps, n))
    ref = np.column_stack([0.1 * np.sin(t + i) for i in range(n + 1)])
    e = x - ref[:, :n]
    data = {
        "t": t, "x": x, "ref": ref, "e": e, "e_delta": e.sum(axis=1), "u": np.cos(3 * t), "u_s": 0.1 * np.sin(5 * t),
        "d_hat": 0.2 * np.sin(t), "d": 0.25 * np.sin(t), "p": rng.standard_normal((steps, n + 1)),
        "V": 0.5 * (e**2).sum(axis=1), "norm_P": 1.0 + t, "norm_q": 0.5 + t, "min_b": np.full(steps, 0.1),
        "extra/cart_pos": 0.5 * np.sin(0.5 * t), "extra/cart_vel": 0.25 * np.cos(0.5 * t),
    }
    return data


def blocks(data: dict[str, np.ndarray], size: int = 1000):
    steps = data["t"].shape[0]
    for start in range(0, steps, size):
        yield Block(start=start, data={k: v[start:start + size] for k, v in data.items()})


def make_snapshot(info: RunInfo, t: float, step: int) -> InnerSnapshot:
    def sets(inputs: tuple[FuzzyInputInfo, ...], z: float):
        out = []
        for inp in inputs:
            grid = np.linspace(inp.lo, inp.hi, 41)
            centres = np.linspace(inp.lo, inp.hi, len(inp.terms))
            width = (inp.hi - inp.lo) / max(1, len(inp.terms) - 1)
            curves = np.exp(-(((grid[None, :] - centres[:, None]) / width) ** 2))
            zc = float(np.clip(z, inp.lo, inp.hi))
            out.append((grid, curves, zc, np.exp(-(((zc - centres) / width) ** 2))))
        return tuple(out)

    h = len(TERMS) ** (info.order + 1)
    rng = np.random.default_rng(step)
    firing = rng.random(h)
    return InnerSnapshot(t=t, step=step, model_sets=sets(info.model_inputs, math.sin(t)),
                         compensator_sets=sets(info.compensator_inputs, math.cos(t)),
                         firing=firing / firing.sum(), compensator_firing=rng.random(6),
                         consequents=rng.standard_normal((h, info.order + 1)), q=rng.standard_normal(6))


def drive(sink: RerunSink, info: RunInfo, data: dict[str, np.ndarray], end: RunEnd,
          upto: int | None = None, inner_every: int = 20) -> None:
    """What the runner does: start, snapshots during each block, the block, finish."""
    sink.start(info)
    for blk in blocks(data):
        if upto is not None and blk.start >= upto:
            break
        for step in range(blk.start, blk.start + blk.data["t"].shape[0], inner_every):
            sink.inner(make_snapshot(info, float(data["t"][step]), step))
        sink.block(blk)
    sink.finish(end)


def completed(steps: int) -> RunEnd:
    return RunEnd(status="completed", message="ok", steps_done=steps, metrics={"iae": 0.125, "max_u": 3.5})


def entity_paths(path: Path) -> set[str]:
    return {c.entity_path for c in RrdReader(path).stream().to_chunks()}


def chunks_of(path: Path, entity: str, component: str):
    """Temporal chunks of ``entity`` holding ``component``, as record batches."""
    chunks = RrdReader(path).stream().filter(content=entity, is_static=False, components=component).to_chunks()
    return [c.to_record_batch() for c in chunks]


def static_text(path: Path, entity: str) -> str:
    chunks = RrdReader(path).stream().filter(content=entity, is_static=True).to_chunks()
    texts = [t for c in chunks for row in c.to_record_batch().to_pydict().get("TextDocument:text", []) for t in row]
    assert texts, f"no text document at {entity}"
    return texts[-1]


@pytest.fixture()
def recorded(tmp_path: Path) -> tuple[Path, RunInfo, dict[str, np.ndarray]]:
    info = make_info()
    data = make_run(info.order, info.steps)
    path = tmp_path / "run.rrd"
    rec = open_recording("tspend_test", "save", path)
    assert rec is not None
    sink = RerunSink(rec)
    drive(sink, info, data, completed(info.steps))
    sink.close()
    return path, info, data


def test_entities_timeline_and_blueprint(recorded) -> None:
    path, info, _ = recorded
    reader = RrdReader(path)
    assert len(reader.recordings()) == 1
    # the layout at the start (views fit the data as it comes) and again at the end, each
    # series view's y range set so that it keeps its tick labels (the last one is shown)
    assert len(reader.blueprints()) == 2, "the default blueprint is stored as a blueprint store"
    summaries = [reader.store(store=b).summary() for b in reader.blueprints()]
    for blueprint in summaries:
        assert "/viewport" in blueprint and "ViewBlueprint:class_identifier" in blueprint
    assert sum("ScalarAxis:range" in b for b in summaries) == 1
    paths = entity_paths(path)
    expected = {"/info/scenario", "/info/run", "/info/status", "/info/metrics", "/series/tracking",
                "/series/error", "/series/control", "/series/compensator", "/series/disturbance",
                "/series/params",
                "/series/lyapunov", "/series/norms", "/series/norms_log10", "/series/plant/cart_pos",
                    "/series/plant/cart_vel", "/world/rail", "/world/cart/readout", "/world", "/world/cart", "/world/pole",
                "/fuzzy/model/in0", "/fuzzy/model/in2", "/fuzzy/compensator/in1", "/fuzzy/firing",
                "/fuzzy/compensator_firing", "/fuzzy/consequents", "/fuzzy/q"}
    assert expected <= paths, expected - paths
    schema = reader.store().schema()
    assert "sim_time" in {c.name for c in schema.index_columns()}


def test_x1_is_exact(recorded) -> None:
    path, info, data = recorded
    entity, instance = series_location("x1", info.order, info.extras)
    t, x1 = read_scalar_series(path, entity, instance)
    assert np.array_equal(x1, data["x"][:, 0])
    assert np.allclose(t, data["t"], atol=1e-12)
    _, params = read_scalar_series(path, "series/params")
    assert np.array_equal(params, data["p"])
    _, v = read_scalar_series(path, "series/lyapunov")
    # V is declared log: recorded as log10 V (Rerun's plots have no log axis)
    assert v.shape == (info.steps,) and np.array_equal(v, np.log10(np.maximum(data["V"], 1e-12)))


def test_static_documents(recorded) -> None:
    path, info, _ = recorded
    assert SCENARIO.strip() in static_text(path, "/info/scenario")
    run = static_text(path, "/info/run")
    assert str(info.seed) in run and info.version in run and info.plant_kind in run
    assert "completed" in static_text(path, "/info/status")
    assert "0.125" in static_text(path, "/info/metrics")


def test_cartpole_frames_at_50hz(recorded) -> None:
    path, info, _ = recorded
    chunks = RrdReader(path).stream().filter(content="/world/pole", is_static=False).to_chunks()
    rows = sum(c.num_rows for c in chunks)
    assert rows == 1 + info.steps // 20  # the initial pose plus one frame every 20 ms


def test_firing_tensors_match_the_sdk_encoding(recorded) -> None:
    path, info, data = recorded
    batches = chunks_of(path, "/fuzzy/firing", "BarChart:values")
    rows = [row for b in batches for row in b.column("BarChart:values").to_pylist()]
    assert len(rows) == info.steps // 20
    expected = make_snapshot(info, float(data["t"][40]), 40).firing.astype(np.float32)
    sdk = rr.components.TensorDataBatch(expected).as_arrow_array().to_pylist()[0]
    assert rows[2] == [sdk]


def test_runner_may_reuse_its_buffers(tmp_path: Path) -> None:
    """Blocks are views of buffers the runner overwrites, snapshots hold live arrays."""
    info = make_info(steps=2000)
    data = make_run(2, 2000)
    path = tmp_path / "reuse.rrd"
    rec = open_recording("tspend_test", "save", path)
    assert rec is not None
    sink = RerunSink(rec)
    sink.start(info)
    scratch = {k: np.empty((1000,) + v.shape[1:]) for k, v in data.items()}
    live = np.zeros((len(TERMS) ** 3, 3))
    for start in (0, 1000):
        for step in range(start, start + 1000, 20):
            snap = make_snapshot(info, float(data["t"][step]), step)
            live[:] = step
            sink.inner(InnerSnapshot(snap.t, snap.step, snap.model_sets, snap.compensator_sets, snap.firing,
                                     snap.compensator_firing, live, snap.q))
        for k, v in data.items():
            scratch[k][:] = v[start:start + 1000]
        sink.block(Block(start=start, data={k: v[:] for k, v in scratch.items()}))
        for v in scratch.values():
            v.fill(np.nan)
        live.fill(np.nan)
    sink.finish(completed(2000))
    close_recording(rec)
    _, x1 = read_scalar_series(path, *series_location("x1", info.order, info.extras))
    assert np.array_equal(x1, data["x"][:, 0])
    cons = [row[0] for b in chunks_of(path, "/fuzzy/consequents", "Tensor:data")
            for row in b.column("Tensor:data").to_pylist()]
    # drawn as (k, rule): three wide rows of a heat map
    assert [row["shape"] for row in cons[:1]] == [[3, len(TERMS) ** 3]] and cons[0]["names"] == ["k", "rule"]
    assert [row["buffer"][0] for row in cons] == [float(s) for s in range(0, 2000, 20)]


def test_membership_curves_sent_only_when_changed(tmp_path: Path) -> None:
    info = make_info(steps=2000)
    data = make_run(2, 2000)
    path = tmp_path / "curves.rrd"
    rec = open_recording("tspend_test", "save", path)
    assert rec is not None
    sink = RerunSink(rec)
    sink.start(info)
    for blk in blocks(data):
        for step in range(blk.start, blk.start + 1000, 20):
            snap = make_snapshot(info, float(data["t"][step]), step)
            if step >= 1500:  # the first model input's sets move once, at t = 1.5 s
                grid, curves, z, mu = snap.model_sets[0]
                snap = InnerSnapshot(snap.t, snap.step, ((grid, 0.5 * curves, z, mu),) + snap.model_sets[1:],
                                     snap.compensator_sets, snap.firing, snap.compensator_firing,
                                     snap.consequents, snap.q)
            sink.inner(snap)
        sink.block(blk)
    sink.finish(completed(2000))
    close_recording(rec)
    strips = chunks_of(path, "/fuzzy/model/in0", "LineStrips2D:strips")
    times = sorted(t for b in strips for t in b.column("sim_time").cast("int64").to_pylist())
    assert times == [0, 1_500_000_000]
    assert sum(b.num_rows for b in chunks_of(path, "/fuzzy/model/in1", "LineStrips2D:strips")) == 1
    points = chunks_of(path, "/fuzzy/model/in0", "Points2D:positions")
    assert sum(b.num_rows for b in points) == 100


@pytest.mark.filterwarnings("ignore:.*no footer.*")
def test_diverged_run_is_readable_without_close(tmp_path: Path) -> None:
    info = make_info()
    data = make_run(info.order, info.steps)
    path = tmp_path / "diverged.rrd"
    rec = open_recording("tspend_test", "save", path)
    assert rec is not None
    sink = RerunSink(rec)
    end = RunEnd(status="diverged", message="|theta| > pi/2 at t=1.9", steps_done=2000, metrics={"iae": float("nan")})
    drive(sink, info, data, end, upto=2000)
    # no close(): finish() alone must leave everything sent on disk
    t, x1 = read_scalar_series(path, *series_location("x1", info.order, info.extras))
    assert np.array_equal(x1, data["x"][:2000, 0])
    assert "diverged" in static_text(path, "/info/status")
    close_recording(rec)
    assert "/events" in entity_paths(path)


def test_generic_plant_has_no_3d_and_side_by_side_prefixes(tmp_path: Path) -> None:
    """Two runs in one recording, wired like the CLI's cross-check."""
    info = make_info(order=3, plant_kind="third_order", steps=2000)
    data = make_run(3, 2000)
    path = tmp_path / "two.rrd"
    prefixes = ("mujoco/", "ode/")
    rec = open_recording("tspend_test", path=path)
    assert rec is not None
    sinks = [RerunSink(rec, prefix=p, blueprint_prefixes=prefixes if i == 0 else None)
             for i, p in enumerate(prefixes)]
    assert [s.variant for s in sinks] == [0, 1]
    for sink in sinks:
        drive(sink, info, data, completed(2000))
    close_recording(rec)
    paths = entity_paths(path)
    assert {"/mujoco/series/tracking", "/ode/series/tracking", "/ode/fuzzy/firing"} <= paths
    assert not any("/world" in p for p in paths)
    _, e = read_scalar_series(path, "ode/series/error")
    assert e.shape == (2000, 4) and np.array_equal(e[:, :3], data["e"])
    reader = RrdReader(path)
    assert len(reader.blueprints()) == 1
    queries = [q for c in reader.stream(store=reader.blueprints()[0]).to_chunks()
               if "ViewContents:query" in c.to_record_batch().schema.names
               for q in c.to_record_batch().column("ViewContents:query").to_pylist()[0]]
    assert ["/mujoco/series/error", "/ode/series/error"] in [queries[i:i + 2] for i in range(len(queries))]
    assert build_blueprint(info, prefixes) is not None


def test_curves_every_decimates(tmp_path: Path) -> None:
    info = make_info(steps=2000)
    data = make_run(2, 2000)
    path = tmp_path / "dec.rrd"
    rec = open_recording("tspend_test", "save", path)
    assert rec is not None
    drive(RerunSink(rec, curves_every=7), info, data, completed(2000))
    close_recording(rec)
    t, x1 = read_scalar_series(path, "series/tracking", 1)
    assert np.array_equal(x1, data["x"][::7, 0])


def test_a_cart_machine_is_drawn_on_its_rail_in_the_models_colours(tmp_path: Path) -> None:
    """The model's own geoms, a material's colour as MuJoCo renders it; the cart (a slide
    along x on a body of the world) found whatever comes first in the file, its box giving
    the rail's width and height; a machine without one has no rail."""
    from tspend.plants.drawing.model import ModelDrawing
    from tspend.plants.articulated.machine import load_machine

    mjcf = tmp_path / "cp.xml"
    mjcf.write_text(  # a rail box and a pivot cylinder come first: they must not be taken for cart and pole
        '<mujoco><asset><material name="pole" rgba="0 1 0 1"/></asset><worldbody><geom type="plane" size="5 5 .1"/>'
        '<geom name="rail" type="box" size="30 .04 .04"/>'
        '<body name="cart" pos="0 0 1"><joint name="x" type="slide" axis="1 0 0"/><geom type="box" size=".4 .25 .15" rgba="1 0 0 1" mass="1"/>'
        '<body name="pole"><joint name="th" type="hinge" axis="0 1 0"/><geom type="cylinder" size=".09 .2" mass="0.1"/>'
        '<geom type="capsule" fromto="0 0 0 0 0 1" size=".03" material="pole" mass="1"/></body></body></worldbody>'
        '<actuator><motor joint="x"/></actuator></mujoco>')
    machine = load_machine(mjcf)
    d = ModelDrawing(machine, ("th", "th_dot"), "cp")
    assert d.cart == machine.model.body("cart").id and d.rail_joint == 0
    assert d.half_width == pytest.approx(0.25) and d.rail_z == pytest.approx(0.85)
    assert d.end_entity == "cart/end"
    path = tmp_path / "d.rrd"
    rec = rr.RecordingStream("tspend_test")
    rec.save(str(path))
    d.log_static(rec, "world", lambda c: c)
    rec.flush()
    del rec
    styles = {chunk.entity_path: chunk.to_record_batch().to_pydict()
              for chunk in RrdReader(path).stream().filter(is_static=True).to_chunks()}
    capsule = next(e for e in styles if e.startswith("/world/pole/") and "Capsules3D:colors" in styles[e])
    rgba = int(styles[capsule]["Capsules3D:colors"][0][0])
    assert (rgba >> 24, (rgba >> 16) & 255, (rgba >> 8) & 255) == (0, 255, 0)
    assert "/world/rail" in styles and "/world/cart/readout" in styles
    acrobot = load_machine(Path(__file__).resolve().parents[1] / "models" / "acrobot.xml")
    assert ModelDrawing(acrobot, ("shoulder", "shoulder_dot"), "acrobot").cart == -1


def test_open_recording_fallbacks(tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch) -> None:
    assert open_recording("tspend_test", "none") is None
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    rec = open_recording("tspend_test", "connect", tmp_path / "fb.rrd", url="rerun+http://127.0.0.1:9/proxy")
    assert rec is not None
    rec.log("x", rr.Scalars(1.0), static=True)
    close_recording(rec)
    assert (tmp_path / "fb.rrd").exists()
    assert open_recording("tspend_test", "connect", None, url="rerun+http://127.0.0.1:9/proxy") is None
    assert open_recording("tspend_test", "spawn", None) is None  # no display here
    err = capsys.readouterr().err
    assert err.count("warning") == 3 and len(err.strip().splitlines()) == 3
    # the CLI's form: a file plus a viewer that is not there -> the file alone, one warning
    tee = open_recording("tspend_test", path=tmp_path / "tee.rrd", spawn=True,
                         connect="rerun+http://127.0.0.1:9/proxy")
    assert tee is not None
    close_recording(tee)
    assert (tmp_path / "tee.rrd").exists()
    assert capsys.readouterr().err.count("warning") == 2
    assert open_recording("tspend_test", path=None) is None


def test_sink_without_recording_records_nothing(tmp_path: Path, monkeypatch) -> None:
    """A sink handed no recording logs nowhere: not to a global recording that happens to
    be active (Rerun's fallback for a call without ``recording=``), not to a file."""
    monkeypatch.chdir(tmp_path)
    fallback = rr.RecordingStream("tspend_fallback")
    fallback.save(tmp_path / "global.rrd")
    rr.set_global_data_recording(fallback)
    try:
        info = make_info(steps=1000)
        drive(RerunSink(None), info, make_run(2, 1000), completed(1000))
    finally:
        rr.set_global_data_recording(None)
        close_recording(fallback)
    logged = {p for p in entity_paths(tmp_path / "global.rrd") if not p.startswith("/__")}
    assert logged == set(), logged
    assert sorted(p.name for p in tmp_path.iterdir()) == ["global.rrd"]
    # the check can fail: the same drive with the global recording does log there
    control = rr.RecordingStream("tspend_control")
    control.save(tmp_path / "control.rrd")
    drive(RerunSink(control), info, make_run(2, 1000), completed(1000))
    close_recording(control)
    assert {p for p in entity_paths(tmp_path / "control.rrd") if not p.startswith("/__")}


def test_labelled_range_keeps_two_decade_ticks_labelled() -> None:
    """Rerun's plots tick at powers of ten and label a step only when its ticks are far
    enough apart: the range given to a view holds two labelled ticks of one step, that
    step's ticks at least Y_LABEL_SPACING_PX apart, and the data."""
    from tspend.recorder.blueprint import PLOT_HEIGHT_PX, Y_LABEL_SPACING_PX, labelled_range

    rng = np.random.default_rng(3)
    for _ in range(500):
        centre, span = rng.normal() * 10.0 ** rng.integers(-4, 4), 10.0 ** rng.uniform(-5, 4)
        lo, hi = centre - span * rng.uniform(0, 1), centre + span * rng.uniform(0, 1)
        a, b = labelled_range(lo, hi)
        assert a <= lo and hi <= b and b - a <= 20 * (hi - lo)
        steps = [10.0 ** k for k in range(-8, 8) if PLOT_HEIGHT_PX * 10.0 ** k / (b - a) >= Y_LABEL_SPACING_PX]
        labelled = [s for s in steps if math.floor(b / s + 1e-9) - math.ceil(a / s - 1e-9) + 1 >= 2]
        assert labelled, (lo, hi, a, b)
    a, b = labelled_range(-65.0, 70.0)
    assert a < -100.0 < 100.0 < b < 120.0  # -100, 0, 100 labelled, inside the plot
    assert labelled_range(1.0, 1.0) is None
