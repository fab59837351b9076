"""The rig: the wire protocol, the simulated rig over UDP, the real-time runner, faults,
the watchdog, the stop frame, replay, and the C rig end over a pseudo-terminal.

Every process is bounded in time (timeouts on every wait); sockets on 127.0.0.1 only.
Timing figures are not asserted here (benchmarks/rig_timing.py measures them); what is
asserted is behaviour: what the controller saw against what the double sent, what the
double applied against what the host sent, bit-for-bit replay.  A test whose loop is paced
to the wall clock is marked ``realtime``: it runs beside a witness of the machine's
punctuality, and a failure while the machine itself kept no schedule is a skip that says
so; the four most sensitive to the suite's load run alone (tests/conftest.py).
"""

from __future__ import annotations

import json
import os
import shutil
import pty
import select
import signal
import socket
import subprocess
import sys
import time
import tty
import zlib
from pathlib import Path

import numpy as np
import pytest

from tests.cli_harness import ROOT, spawn, tspend
from tspend.rig import protocol
from tspend.rig.protocol import Command, FrameError, Hello, Sensor

SCENARIO = "pendulum_mujoco"
C_SOURCE = ROOT / "tspend" / "rig" / "rig_end.c"
#: the longest any one process of these tests may take (s)
PROCESS_TIMEOUT_S = 120


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_double(tmp_path: Path, *options: str,
                 scenario: str = SCENARIO) -> tuple[subprocess.Popen, str, Path]:
    """``tspend rig serve`` on a free port, once it listens; (process, url, its log)."""
    port, log = free_udp_port(), tmp_path / "double.npz"
    url = f"udp://127.0.0.1:{port}"
    proc = spawn("rig", "serve", scenario, "--listen", url, "--log", str(log),
                 "--wait-s", "60", "--max-session-s", "90", *options, cwd=tmp_path)
    line = proc.stdout.readline()  # printed once the socket is bound
    assert line.startswith("rig serve:"), line + proc.stderr.read()
    return proc, url, log


def finish(proc: subprocess.Popen) -> tuple[str, str]:
    try:
        out, err = proc.communicate(timeout=PROCESS_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"the process did not end: {out} {err}")
    return out, err


def off_sequence(rrd: Path) -> np.ndarray:
    """Per cycle of a rig run: it did not use the frame after the previous cycle's (no
    fresh frame: one late; or one skipped: the host late, it takes the newest).  From the
    first such cycle the run parts from a simulation's."""
    fresh = rig_series(rrd, "fresh").astype(bool)
    sensor_seq = rig_series(rrd, "sensor_seq").astype(int)
    return ~fresh | (np.diff(sensor_seq, prepend=sensor_seq[0] - 1) != 1)


def late_commands(rrd: Path, truth) -> np.ndarray:
    """Per cycle of a rig run: the double applied its command after the first physics
    step of the period the command was computed for (the double's own log: the command in
    force at each step; the frame each cycle used)."""
    frame_us = truth["sensor_rig_time_us"][1] - truth["sensor_rig_time_us"][0]
    steps_per_frame = round(frame_us * 1e-6 / (truth["t"][1] - truth["t"][0]))
    in_force = truth["command_seq"].astype(int)
    first_step = rig_series(rrd, "sensor_seq").astype(int) * steps_per_frame
    return np.array([step >= len(in_force) or in_force[step] < k
                     for k, step in enumerate(first_step)])


def first_of(flags: np.ndarray) -> int:
    """The first index set in ``flags``; their number if none is."""
    return int(np.argmax(flags)) if flags.any() else len(flags)


def rig_series(path: Path, name: str) -> np.ndarray:
    from tspend.recorder.readback import read_scalar_series

    return read_scalar_series(path, f"rig/{name}")[1]


# -- the protocol ---------------------------------------------------------------------
def test_crc_is_ieee_802_3_and_every_single_bit_error_is_rejected():
    assert zlib.crc32(b"123456789") == 0xCBF43926  # the standard's check value
    frame = protocol.sensor(Sensor(7, 123456, 6, 0, (1000, -2000)))
    kind, seq, fields = protocol.decode(frame)
    assert (kind, seq) == (protocol.SENSOR, 7)
    assert protocol.as_sensor(seq, fields).counts == (1000, -2000)
    for bit in range(len(frame) * 8):
        bad = bytearray(frame)
        bad[bit // 8] ^= 1 << (bit % 8)
        with pytest.raises(FrameError):
            protocol.decode(bytes(bad))


def test_frames_round_trip_with_their_documented_sizes():
    hello = Hello("cartpole:slider,hinge", (1e5, 3183.1), 0.002, 0.1, 0.02, 2000.0)
    back = protocol.as_hello(protocol.decode(protocol.hello(hello))[2])
    assert back == hello and not back.answers_query
    asks = Hello("cartpole:slider,hinge", (1e5, 3183.1), 0.002, 0.1, 0.02, 2000.0,
                 protocol.ANSWERS_QUERY)
    assert protocol.as_hello(protocol.decode(protocol.hello(asks))[2]).answers_query
    assert protocol.decode(protocol.query(5))[:2] == (protocol.QUERY, 5)
    u = 0.1 + 0.2  # not a short binary fraction: the command travels as binary64
    c = protocol.as_command(9, protocol.decode(protocol.command(Command(9, u, 8)))[2])
    assert c.u == u and c.sensor_seq == 8
    # docs/rig.md's table
    assert protocol.SIZES == {b"H": 16, b"h": 100, b"G": 20, b"S": 44, b"C": 28, b"X": 16,
                              b"Q": 16}


def test_a_byte_stream_resynchronises_after_garbage_and_a_corrupt_frame():
    good = [protocol.sensor(Sensor(i, i * 2000, i, 0, (i, -i))) for i in range(3)]
    corrupt = bytearray(good[1])
    corrupt[20] ^= 0x10
    stream = b"TS\x01junk" + good[0] + bytes(corrupt) + b"\x00TS" + good[2]
    parser = protocol.StreamParser()
    found = []
    for i in range(0, len(stream), 5):  # arriving in pieces, as from a serial port
        found += parser.feed(stream[i:i + 5])
    assert [seq for _, seq, _ in found] == [0, 2]
    assert parser.rejected == 1


def test_the_clock_tracker_measures_a_known_drift_and_ignores_one_outlier_window():
    """Arrivals of frames from a rig clock 200 ppm slow, each delayed by a random queueing
    of 0-300 us (one frame in a window at the floor): the minima's slope is the drift; the
    schedule follows in steps past the bound; a window whose frames all queue 1 ms (one
    outlier) moves nothing."""
    from tspend.rig.timing import ClockTracker

    period_ns, rng = 2_000_000, np.random.default_rng(0)
    tracker = ClockTracker(0, period_ns, 50_000)
    followed, host_ns = 0, 0
    for k in range(3000):  # 6 s
        rig_us = k * 2000
        host_ns = round(rig_us * 1000 * (1 + 200e-6))  # a slow clock: later on the host's
        queued = 0 if k % 10 == 0 else int(rng.integers(0, 300_000))
        outlier = 1_000_000 if 1000 <= k < 1050 else 0  # window 20: every frame 1 ms late
        tracker.arrived(host_ns + queued + outlier, rig_us)
        followed += tracker.end_of_cycle(k, host_ns)
    assert abs(tracker.gain_us_per_s() + 200) < 2  # loses 200 us per s
    # 6 s at 200 us/s: 1.2 ms, followed to within the bound and a window's drift
    assert abs(followed - 1_200_000) < 50_000 + 20_000 and tracker.realigned >= 10
    assert tracker.shift_ns == followed
    single = ClockTracker(0, period_ns, 50_000)
    for k in range(200):  # 4 windows, the second 1 ms late: no shift
        single.arrived(k * 2_000_000 + (1_000_000 if 50 <= k < 100 else 0), k * 2000)
        assert single.end_of_cycle(k, k * 2_000_000) == 0
    assert single.realigned == 0


def test_a_spell_of_queued_frames_moves_the_schedule_a_step_at_most_and_not_the_drift():
    """Two windows whose frames all queue 1 ms (a spell of the link or of the rig's
    sender) look like the offset moving: the schedule moves by at most two bounds (not the
    1 ms), and back within the bound once the frames come on time again.  While it is late
    the frames are already waiting when the host wakes to listen, stamped at the wake (their
    lag then follows the schedule): those windows stay out of the drift's fit, which finds
    no drift (before: 1 ms moved, and 143 ppm read from a clock that keeps the host's)."""
    from tspend.rig.runner import ALIGN_SHARE, LISTEN_SHARE
    from tspend.rig.timing import REALIGN_STEP_BOUNDS, ClockTracker

    period_ns, transit_ns = 2_000_000, 50_000
    bound_ns, listen_ns = 100_000, round(LISTEN_SHARE * period_ns)
    aligned_ns = round(ALIGN_SHARE * period_ns)  # the deadline's place after the frame
    tracker = ClockTracker(transit_ns, period_ns, bound_ns)
    late_ns, most_late_ns = 0, 0  # the schedule's error
    for k in range(1500):  # 3 s
        arrival = k * period_ns + transit_ns + (1_000_000 if 50 <= k < 150 else 0)
        wake = k * period_ns + transit_ns + aligned_ns + late_ns - listen_ns
        waiting = arrival <= wake
        stamp = wake if waiting else arrival
        tracker.arrived(stamp, k * period_ns // 1000, waiting)
        late_ns += tracker.end_of_cycle(k, stamp)
        most_late_ns = max(most_late_ns, late_ns)
    assert most_late_ns == REALIGN_STEP_BOUNDS * bound_ns
    assert abs(late_ns) <= bound_ns, (late_ns, tracker.block())
    assert abs(tracker.gain_us_per_s()) < 5


# -- the UDP double and the runner ------------------------------------------------------
@pytest.mark.realtime
def test_lqr_on_the_udp_double_completes_with_timing_and_replays_bit_for_bit(tmp_path):
    double, url, log = start_double(tmp_path)
    r = tspend("run", SCENARIO, "--controller", "lqr", "--rig", url, "--duration", "3",
               "--metrics", "m.json", "--out", "rig.rrd", cwd=tmp_path, timeout=PROCESS_TIMEOUT_S)
    out, _ = finish(double)
    assert r.status == 0, r.err
    assert "completed: 1500 steps" in r.out  # the double's 2 ms period, said in one line
    assert "running at 2 ms" in r.out
    assert "ended (stop frame)" in out
    m = json.loads((tmp_path / "m.json").read_text())
    timing = m["timing"]
    assert timing["cycles"] == 1500 and timing["period_s"] == 0.002
    for key in ("lateness_us", "compute_us"):
        q = timing[key]
        assert q["p50"] <= q["p99"] <= q["p99_9"] <= q["max"]
    assert set(timing["frames"]) >= {"lost", "late", "corrupt"}
    assert "velocity_estimator" in timing and "realtime" in timing
    # the double's clock is the host's: no drift to speak of (the minima of 11 windows)
    assert timing["clock"]["windows"] >= 10 and abs(timing["clock"]["rig_gain_us_per_s"]) < 50
    # the timing panels are in the recording, one value per cycle
    assert len(rig_series(tmp_path / "rig.rrd", "lateness_us")) == 1500
    # what the controller saw is what the double measured, frame by frame
    truth = np.load(log)
    seq = rig_series(tmp_path / "rig.rrd", "sensor_seq").astype(int)
    counts = rig_series(tmp_path / "rig.rrd", "counts").reshape(1500, -1)
    sent = dict(zip(truth["sensor_seq"], map(tuple, truth["sensor_counts"])))
    first = int(np.argmax(rig_series(tmp_path / "rig.rrd", "fresh")))  # cycle 0 may be stale
    assert first < 10
    assert all(tuple(counts[k].astype(int)) == sent[seq[k]] for k in range(first, 1500))

    again = tspend("replay", "rig.rrd", cwd=tmp_path, timeout=PROCESS_TIMEOUT_S)
    assert again.status == 0, again.err
    assert "1500 commands equal bit for bit, 0 differ" in again.out


@pytest.mark.realtime(alone=True)
def test_a_drifting_rig_clock_is_measured_followed_and_said(tmp_path):
    """A double whose clock runs 300 ppm slow: the timing block states the drift, the
    schedule re-aligns on the rig's clock and one line says so.  Without re-alignment each
    frame would reach the host after its deadline from 0.7 s on (the 0.2 ms lead at 2 ms
    periods, lost at 300 us per s): three quarters of the cycles stale."""
    stale = []
    for attempt in range(3):  # late frames in a slow spell of the machine: run again
        folder = tmp_path / f"try{attempt}"
        folder.mkdir()
        double, url, _ = start_double(folder, "--clock-ppm", "-300")
        r = tspend("run", SCENARIO, "--controller", "lqr", "--rig", url, "--duration", "3",
                   "--metrics", "m.json", "--no-record", cwd=folder, timeout=PROCESS_TIMEOUT_S)
        finish(double)
        assert r.status == 0, r.err
        timing = json.loads((folder / "m.json").read_text())["timing"]
        stale.append(timing["frames"]["stale_cycles"] / timing["cycles"])
        if stale[-1] < 0.10:
            break
    clock = timing["clock"]
    assert -345 < clock["rig_gain_us_per_s"] < -255, clock
    # 3 s at 300 ppm: 900 us, re-aligned in steps of at most a window's drift past the bound
    # (it trails the drift by up to two steps under load: 691 us seen at load 4), or ahead
    # by one capped step after a spell of queued frames near the end (REALIGN_STEP_BOUNDS
    # bounds: 200 us; before the cap, 1867 us in all was seen in a cold CI run)
    assert clock["realigned"] >= 4 and 600 < clock["schedule_shift_us"] < 1100, clock
    # three quarters stale without re-alignment; a few per cent with it (late frames under
    # load: 3.5 % seen with the suite's other rig tests beside it)
    assert timing["frames"]["stale_cycles"] < 0.10 * timing["cycles"], timing["frames"]
    assert "rig: the rig's clock loses " in r.out and "us per s on the host's" in r.out


def rig_run_with_twin(folder: Path, *double_options: str) -> dict:
    """A 2 s LQR run on the double with --twin (rig.rrd, m.json in ``folder``); its twin_gap."""
    folder.mkdir()
    double, url, _ = start_double(folder, *double_options)
    r = tspend("run", SCENARIO, "--controller", "lqr", "--rig", url, "--duration", "2", "--twin",
               "--metrics", "m.json", "--out", "rig.rrd", cwd=folder, timeout=PROCESS_TIMEOUT_S)
    finish(double)
    assert r.status == 0, r.err
    return json.loads((folder / "m.json").read_text())["twin_gap"]


@pytest.mark.realtime
def test_the_twin_is_drawn_in_the_rig_runs_recording_and_its_gap_is_in_the_metrics(tmp_path):
    """The twin beside the rig's trajectories in the rig run's own recording (read back),
    the gap in the metrics: at the encoders' resolution on an exact double, far above it on
    a double whose pole is 20 % heavier than the model's."""
    from tspend.recorder.readback import read_scalar_series

    count_rad = 2 * np.pi / 2e4  # the double's hinge encoder
    gaps, before_stale, all_fresh, folders = {}, {}, {}, {}
    for name, options in (("exact", ()), ("heavy", ("--set", "plant.m=1.2"))):
        first_stale = []
        # a frame late within the first cycles (the suite's other processes beside it)
        # leaves too few recorded samples to compare: run again, at most three times
        for attempt in range(3):
            folder = folders[name] = tmp_path / f"{name}{attempt}"
            gap = gaps[name] = rig_run_with_twin(folder, *options)
            assert gap["samples"] == 1000 and gap["twin_status"] == "completed"
            assert gap["states"]["hinge"]["unit"] == "rad" and gap["u"]["unit"] == "N"
            t_rig, rig = read_scalar_series(folder / "rig.rrd", "series/state/hinge")
            t_twin, twin = read_scalar_series(folder / "rig.rrd", "twin/series/state/hinge")
            assert len(t_rig) > 50 and np.array_equal(t_rig, t_twin)
            # the recorded samples are a subset of those the metrics' gap covers
            assert np.abs(twin - rig).max() <= gap["states"]["hinge"]["max_abs"] + 1e-12
            # up to the first cycle without a fresh frame (a frame late under load: the
            # estimator holds there, and the runs part)
            fresh = rig_series(folder / "rig.rrd", "fresh").astype(bool)
            first_stale.append(first_of(off_sequence(folder / "rig.rrd")))
            early = t_rig < first_stale[-1] * 0.002
            if early.sum() >= 2:
                break
        assert early.sum() >= 2, f"{name}: first stale cycles {first_stale} in 3 runs"
        before_stale[name] = np.abs(twin[early] - rig[early]).max()
        all_fresh[name] = first_stale[-1] == len(fresh)
    # export keeps the rig run's own column names (identify reads them) beside the twin's
    r = tspend("export", "rig.rrd", "--out", "e.csv", cwd=folders["exact"],
               timeout=PROCESS_TIMEOUT_S)
    assert r.status == 0, r.err
    header = (folders["exact"] / "e.csv").read_text().splitlines()[0].split(",")
    assert {"hinge_rad", "u_N", "twin_hinge_rad", "twin_u_N"} <= set(header), header
    exact, heavy = gaps["exact"]["states"], gaps["heavy"]["states"]
    assert gaps["exact"]["start"] == gaps["heavy"]["start"] == "x0"
    # the exact double: the twin follows the rig run to two counts until a frame came late
    # (a command the double applied a cycle late, under load, parts them by a count, and
    # the host cannot see it), and within a count (rms) when every frame came on time
    # (under load, late frames part the runs further: the estimator holds through them,
    # the twin does not)
    assert before_stale["exact"] <= 2 * count_rad + 1e-12
    if all_fresh["heavy"]:  # (a late frame early on leaves too few samples to part in)
        assert before_stale["heavy"] > 0.0
    if all_fresh["exact"]:
        assert exact["hinge"]["rms"] < count_rad and exact["hinge"]["max_abs"] < 3.5 * count_rad
    # a 20 % heavier pole: the cart moves otherwise (benchmarks/rig_twin.py, 20 s: 2.5 mm
    # rms against 0.4 mm on the exact double)
    # (against the exact double's gap only when all its frames came on time: a few late
    # frames raise that gap to the heavier pole's over 2 s, 0.70 against 0.73 mm seen)
    assert heavy["slider"]["rms"] > 2e-4, heavy
    if all_fresh["exact"]:
        assert heavy["slider"]["rms"] > 2 * exact["slider"]["rms"], (heavy, exact)


@pytest.mark.realtime
def test_a_simulation_with_the_rigs_estimator_gives_the_rig_runs_commands(tmp_path):
    """``run --estimator``: the simulated controller fed encoder counts and the rig runner's
    velocity estimate.  On an exact double (which rests at x0 until the first command and
    stamps its samples on its own clock) the rig run's commands equal the simulation's bit
    for bit up to the first cycle that did not use the next frame (one late, or one skipped
    by a late host: the estimator holds or jumps) or the first command the double applied
    late (its own log says): from there the two runs part."""
    from tspend.recorder.readback import read_scalar_series

    on_time = []
    # a frame or a command late within the first cycles (the suite's other processes beside
    # it) leaves little to compare: run again, at most three times
    for attempt in range(3):
        folder = tmp_path / f"rig{attempt}"
        folder.mkdir()
        double, url, log = start_double(folder)
        r = tspend("run", SCENARIO, "--controller", "lqr", "--rig", url, "--duration", "2",
                   "--out", "rig.rrd", cwd=folder, timeout=PROCESS_TIMEOUT_S)
        finish(double)
        assert r.status == 0, r.err
        rrd = folder / "rig.rrd"
        # a command applied late moves the rig's next sample: commands part from there
        on_time.append(min(first_of(off_sequence(rrd)),
                           first_of(late_commands(rrd, np.load(log))) + 1))
        if on_time[-1] >= 10:
            break
    assert on_time[-1] >= 10, f"cycles before a late frame or command: {on_time} in 3 runs"
    r = tspend("run", SCENARIO, "--controller", "lqr", "--estimator", "lowpass", "--set",
               "run.control_period=0.002", "--duration", "2", "--diagnostics-hz", "0",
               "--out", "sim.rrd", cwd=tmp_path, timeout=PROCESS_TIMEOUT_S)
    assert r.status == 0, r.err
    assert "sensors: encoders of 100000, 3183.1 counts per unit" in r.out
    rig_u = rig_series(folder / "rig.rrd", "u")
    sim_u = read_scalar_series(tmp_path / "sim.rrd", "series/control_command")[1]
    assert len(rig_u) == len(sim_u) == 1000
    assert np.array_equal(rig_u[:on_time[-1]], sim_u[:on_time[-1]])
    # without the estimator the controller sees the true velocities: other commands
    r = tspend("run", SCENARIO, "--controller", "lqr", "--set", "run.control_period=0.002",
               "--duration", "0.1", "--diagnostics-hz", "0", "--out", "true.rrd", cwd=tmp_path,
               timeout=PROCESS_TIMEOUT_S)
    true_u = read_scalar_series(tmp_path / "true.rrd", "series/control_command")[1]
    assert not np.array_equal(true_u[:10], sim_u[:10])


def test_estimator_options_are_checked(tmp_path):
    for argv, said in (
            (("--twin",), "--twin: only with --rig"),
            (("--counts-per-unit", "1000", "1000"), "--counts-per-unit: only with --estimator"),
            (("--estimator", "lowpass", "--counts-per-unit", "1000"),
             "--counts-per-unit: 1 given, the machine has 2 joints (slider, hinge)")):
        r = tspend("run", SCENARIO, "--no-record", "--duration", "0.01", *argv, cwd=tmp_path,
                   timeout=PROCESS_TIMEOUT_S)
        assert r.status == 2 and said in r.one_error_line(), (argv, r.err)


@pytest.mark.realtime
def test_replay_notices_a_different_estimator(tmp_path, monkeypatch):
    """Replay can fail: the same frames through another velocity filter give other commands."""
    double, url, _ = start_double(tmp_path)
    r = tspend("run", SCENARIO, "--controller", "lqr", "--rig", url, "--duration", "0.5",
               "--out", "rig.rrd", cwd=tmp_path, timeout=PROCESS_TIMEOUT_S)
    finish(double)
    assert r.status == 0, r.err
    from tspend.rig import replay as replay_module

    notes = replay_module.session_notes(tmp_path / "rig.rrd")
    assert replay_module.replay(tmp_path / "rig.rrd").equal == 250
    # the twin afterwards, from the recording: the same controller, encoders and estimator
    # on the model from x0 (the double's first frame reads as x0), within a count (rms) of
    # what the rig (the double) did
    gap = replay_module.twin(tmp_path / "rig.rrd", tmp_path / "twin.rrd")
    assert gap["samples"] == 250 and gap["start"] == "x0"
    from tspend.recorder.readback import read_scalar_series

    rig_hinge = read_scalar_series(tmp_path / "twin.rrd", "sim_vs_rig/hinge/rig")[1]
    twin_hinge = read_scalar_series(tmp_path / "twin.rrd", "sim_vs_rig/hinge/twin")[1]
    assert np.array_equal(rig_hinge,
                          rig_series(tmp_path / "rig.rrd", "state").reshape(250, -1)[:, 1])
    # the twin follows the rig run to two counts until a frame came late (under load the
    # estimator holds there and the runs part; a command the double applied a cycle late,
    # which the host cannot see, parts them by a count); every frame on time: a count (rms)
    fresh = rig_series(tmp_path / "rig.rrd", "fresh").astype(bool)
    first_stale = int(np.argmin(fresh)) if not fresh.all() else len(fresh)
    count_rad = 2 * np.pi / 2e4
    assert np.all(np.abs(twin_hinge[:first_stale] - rig_hinge[:first_stale])
                  <= 2 * count_rad + 1e-12)
    if fresh.all():
        assert gap["states"]["hinge"]["rms"] < 2 * np.pi / 2e4
    notes["timing_notes"]["velocity_tau_s"] *= 2
    monkeypatch.setattr(replay_module, "session_notes", lambda path: notes)
    assert replay_module.replay(tmp_path / "rig.rrd").equal < 250


@pytest.mark.realtime
def test_faults_are_counted_and_no_corrupt_frame_is_ever_applied(tmp_path):
    double, url, log = start_double(tmp_path, "--drop", "0.05", "--sensor-latency-ms", "3",
                                    "--corrupt", "0.01", "--fault-seed", "3")
    r = tspend("run", SCENARIO, "--controller", "lqr", "--rig", url, "--duration", "4",
               "--metrics", "m.json", "--out", "rig.rrd", cwd=tmp_path, timeout=PROCESS_TIMEOUT_S)
    finish(double)
    assert r.status in (0, 4), r.err  # completed, or the task ended it (its message says)
    m = json.loads((tmp_path / "m.json").read_text())
    frames, cycles = m["timing"]["frames"], m["timing"]["cycles"]
    truth = np.load(log)
    rrd = tmp_path / "rig.rrd"
    seq = rig_series(rrd, "sensor_seq").astype(int)
    counts = rig_series(rrd, "counts").reshape(cycles, -1).astype(int)
    fresh = rig_series(rrd, "fresh").astype(bool)
    # every frame up to the newest the host took has arrived or is accounted for
    seen = truth["sensor_seq"] <= seq.max()
    dropped, corrupted = truth["sensor_dropped"] & seen, truth["sensor_corrupted"] & seen
    assert frames["lost"] == int(dropped.sum()) > 0
    assert frames["corrupt"] == int((corrupted & ~dropped).sum()) > 0
    # the counts of every frame the controller got are what the double measured: none of
    # the corrupted ones reached it
    sent = {s: tuple(c) for s, c in zip(truth["sensor_seq"], truth["sensor_counts"])}
    bad = set(truth["sensor_seq"][truth["sensor_corrupted"]])
    assert not bad & set(seq[fresh])
    assert all(tuple(counts[k]) == sent[seq[k]] for k in np.nonzero(fresh)[0])
    # and every command the double applied is one the host sent, exactly
    u_sent = rig_series(rrd, "u_sent")
    applied = truth["command_applied"] & (truth["command_seq_received"] < len(u_sent))
    assert applied.sum() > 0.9 * cycles
    assert np.array_equal(truth["command_u_received"][applied],
                          u_sent[truth["command_seq_received"][applied]])
    assert (truth["event"] == "rejected_command").sum() > 0  # corrupted commands: dropped


@pytest.mark.realtime
def test_sigkill_the_runner_the_watchdog_zeroes_the_command(tmp_path):
    double, runner, log = running_pair(tmp_path, 1.5, "--watchdog-ms", "20")
    runner.send_signal(signal.SIGKILL)
    finish(runner)
    out, _ = finish(double)
    assert "ended (host lost)" in out
    truth = np.load(log)
    trips = truth["event_wall_s"][truth["event"] == "watchdog"]
    assert len(trips) == 1
    wall, applied, cseq = truth["wall_s"], truth["u_applied"], truth["command_seq"]
    tripped = np.nonzero(truth["watchdog"] > 0)[0]
    first = tripped[0]
    last_command = np.nonzero(np.diff(cseq[:first]) > 0)[0][-1] + 1
    waited_s = wall[first] - wall[last_command]
    # zero at the double's first step past the stated 20 ms, not one before (its steps are
    # 1 ms apart on a quiet machine, further under load: the bound is on the step, not 1 ms)
    assert wall[first - 1] - wall[last_command] <= 0.020 < waited_s, waited_s
    assert np.all(applied[first:] == 0.0) and np.any(applied[:first] != 0.0)


def _wait_for_line(proc: subprocess.Popen, text: str) -> None:
    until = time.monotonic() + PROCESS_TIMEOUT_S
    while time.monotonic() < until:
        line = proc.stdout.readline()
        if text in line:
            return
        if not line and proc.poll() is not None:
            break
    pytest.fail(f"no line with {text!r}")


def running_pair(tmp_path: Path, seconds: float, *double_options: str):
    """The double and a 60 s LQR run on it (metrics m.json, recording rig.rrd), ``seconds``
    into the session; (double, runner, the double's log)."""
    double, url, log = start_double(tmp_path, *double_options)
    runner = spawn("run", SCENARIO, "--controller", "lqr", "--rig", url, "--duration", "60",
                   "--metrics", "m.json", "--out", "rig.rrd", cwd=tmp_path)
    _wait_for_line(double, "session 1: period")
    time.sleep(seconds)
    return double, runner, log


@pytest.mark.realtime
def test_ctrl_c_sends_the_stop_frame_and_keeps_the_outputs(tmp_path):
    double, runner, log = running_pair(tmp_path, 1.5)
    runner.send_signal(signal.SIGINT)
    out, err = finish(runner)
    double_out, _ = finish(double)
    assert runner.returncode == 130, err
    assert "ended (stop frame)" in double_out
    truth = np.load(log)
    assert list(truth["event"]).count("stop_frame") == 1
    assert truth["watchdog"].max() == 0  # stopped by the host, not by the watchdog
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["status"] == "interrupted" and 0 < m["timing"]["cycles"] < 30_000
    assert (tmp_path / "rig.rrd").stat().st_size > 0


@pytest.mark.realtime
def test_a_rig_gone_silent_ends_the_run_with_its_outputs_kept(tmp_path):
    double, runner, _ = running_pair(tmp_path, 1.0)
    double.send_signal(signal.SIGKILL)
    finish(double)
    out, err = finish(runner)
    assert runner.returncode == 3, err
    assert "the rig is gone" in out + err
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["status"] == "diverged" and (tmp_path / "rig.rrd").exists()


@pytest.mark.realtime
def test_miss_policy_stop_ends_the_run_at_the_first_late_command(tmp_path):
    """A plug-in rig whose read stalls one cycle by three periods (a slow driver)."""
    plugin = tmp_path / "slow_rig.py"
    plugin.write_text(
        "import time\n"
        "from tspend.rig.inprocess import InProcessCartPole\n"
        "class Slow(InProcessCartPole):\n"
        "    def poll(self):\n"
        "        frames = super().poll()\n"
        "        if any(f.seq == 100 for f in frames):\n"
        "            time.sleep(0.006)\n"
        "        return frames\n")
    said = {}
    for policy, status in (("stop", 3), ("zero", 0)):
        r = said[policy] = tspend("run", SCENARIO, "--controller", "lqr", "--rig", f"{plugin}:Slow",
                   "--set", "run.control_period=0.002", "--duration", "1", "--miss-policy",
                   policy, "--metrics", f"{policy}.json", "--out", f"{policy}.rrd",
                   cwd=tmp_path, timeout=PROCESS_TIMEOUT_S)
        assert r.status == status, r.err
        timing = json.loads((tmp_path / f"{policy}.json").read_text())["timing"]
        assert timing["misses"] >= 1
    assert "deadline missed at cycle" in said["stop"].out + said["stop"].err
    sent = rig_series(tmp_path / "zero.rrd", "u_sent")
    missed = rig_series(tmp_path / "zero.rrd", "missed").astype(bool)
    assert np.all(sent[missed] == 0.0) and np.any(sent[~missed] != 0.0)


def test_an_unreachable_rig_and_a_wrong_machine_are_refused_in_one_line(tmp_path):
    r = tspend("run", SCENARIO, "--rig", f"udp://127.0.0.1:{free_udp_port()}", "--no-record",
               cwd=tmp_path, timeout=PROCESS_TIMEOUT_S)
    assert r.status == 2
    assert "unreachable" in r.one_error_line() or "no hello" in r.one_error_line()
    plugin = tmp_path / "my_rig.py"
    plugin.write_text(
        "from tspend.rig.links import RigLink\n"
        "from tspend.rig.protocol import Hello\n"
        "class Furuta(RigLink):\n"
        "    def hello(self):\n"
        "        return Hello('furuta:arm,pendulum', (1.0, 1.0), 0.001, 0.1, 0.02, 1.0)\n"
        "    def start(self, period_s): raise AssertionError('moved')\n"
        "    def poll(self): return []\n"
        "    def send(self, command): raise AssertionError('moved')\n"
        "    def stop(self, reason): self.stopped = True\n"
        "class NotARig:\n"
        "    pass\n")
    r = tspend("run", SCENARIO, "--rig", f"{plugin}:Furuta", "--no-record", cwd=tmp_path,
               timeout=PROCESS_TIMEOUT_S)
    assert r.status == 2
    assert "the rig is 'furuta:arm,pendulum', the scenario's machine is 'cartpole:slider,hinge'" \
        in r.one_error_line()
    r = tspend("run", SCENARIO, "--rig", f"{plugin}:NotARig", "--no-record", cwd=tmp_path,
               timeout=PROCESS_TIMEOUT_S)
    assert r.status == 2 and "not a subclass" in r.one_error_line()


@pytest.mark.realtime(alone=True)
def test_identify_recovers_the_mass_of_the_doubles_pole_through_the_rig(tmp_path):
    """The loop that makes the twin better: excite, run on the rig, export, identify."""
    r = tspend("excite", SCENARIO, "--out", "exp.toml", "--duration", "10", cwd=tmp_path,
               timeout=PROCESS_TIMEOUT_S)
    assert r.status == 0, r.err
    shares = []
    # a run whose frames or commands came late records what the double did not apply
    # (under load: 28 % stale cycles and 31 % late commands seen, and a fit of 1.71 kg):
    # run again, at most three times, until one carries the experiment
    for attempt in range(3):
        folder = tmp_path / f"try{attempt}"
        folder.mkdir()
        shutil.copy(tmp_path / "exp.toml", folder)
        double, url, log = start_double(folder, "--set", "plant.m=1.2", scenario="exp.toml")
        r = tspend("run", "exp.toml", "--rig", url, "--out", "e.rrd", cwd=folder,
                   timeout=PROCESS_TIMEOUT_S)
        finish(double)
        assert r.status == 0, r.err
        rrd = folder / "e.rrd"
        shares.append(float((off_sequence(rrd) | late_commands(rrd, np.load(log))).mean()))
        if shares[-1] <= 0.05:
            break
    assert shares[-1] <= 0.05, f"cycles with a late frame or command: {shares} in 3 runs"
    r = tspend("export", "e.rrd", "--out", "e.csv", cwd=folder, timeout=PROCESS_TIMEOUT_S)
    assert r.status == 0, r.err
    r = tspend("identify", "e.csv", "--model", str(ROOT / "models" / "cartpole.xml"),
               "--params", "m", "--out", "cal.xml", "--metrics", "fit.json", cwd=folder,
               timeout=PROCESS_TIMEOUT_S)
    assert r.status == 0, r.err
    fitted = json.loads((folder / "fit.json").read_text())["parameters"]["m"]["value"]
    # the double's pole is 20 % heavier than the model's 1 kg: the fit finds the double's,
    # not the model's (within 5 %: a few late commands bias the fit, 2.9 % off was seen in
    # the cold suite at load 5)
    assert abs(fitted / 1.2 - 1) < 0.05 and abs(fitted / 1.0 - 1) > 0.1, fitted


# -- the start checked before START ----------------------------------------------------------
#: a pendulum_finite_rail start no plan is certified from (docs/safety.md's refusal example)
FAR_START = ("--set", "plant.x0=[1.3, 2.0]")
MPSC = ("--set", "effects.rail=1.0", "--set", 'safety.filter="mpsc"')


def test_a_start_the_filter_refuses_is_refused_before_the_rig_starts(tmp_path):
    """mpsc with safety.refuse_unadmitted on the double: the runner queries the rig's state
    before START, the filter's admission refuses it, and START is never sent (the double
    saw a stop and no session; exit 4, the reason in the metrics); from a start it admits
    the same check lets the rig start, and the filter starts on the plan certified there."""
    double, url, log = start_double(tmp_path, *MPSC, *FAR_START, "--sessions", "2",
                                    scenario="pendulum_finite_rail")
    refused = tspend("run", "pendulum_finite_rail", "--controller", "pd", *MPSC,
                     "--set", "safety.refuse_unadmitted=true", "--rig", url, "--duration", "1",
                     "--metrics", "refused.json", "--no-record", cwd=tmp_path,
                     timeout=PROCESS_TIMEOUT_S)
    assert refused.status == 4, refused.err
    assert "rig: the start is refused before START: safety.refuse_unadmitted" in refused.out
    m = json.loads((tmp_path / "refused.json").read_text())
    check = m["timing"]["start_check"]
    assert check["before_start"] and check["refused"].startswith("safety.refuse_unadmitted")
    # the state read before the start: the double's x0, its hinge to the encoder's count
    assert abs(check["state"]["hinge"] - 1.3) < 2 * np.pi / 2e4
    assert m["timing"]["cycles"] == 0 and m["safety_filter"]["start_admitted"] is False
    # the double serves on; without the filter nothing checks the start, nothing is
    # queried, and the rig starts from it
    plain = tspend("run", "pendulum_finite_rail", "--controller", "pd", "--set",
                   "effects.rail=1.0", "--rig", url, "--duration", "0.1", "--no-record",
                   "--metrics", "plain.json", cwd=tmp_path, timeout=PROCESS_TIMEOUT_S)
    out, _ = finish(double)
    assert "session 1: the host stopped before START (reason 1: task); nothing moved" in out
    assert "session 2: period 2 ms" in out
    assert "start_check" not in json.loads((tmp_path / "plain.json").read_text())["timing"]
    assert plain.status == 0 and "completed: 50 steps" in plain.out, plain.err


def test_ctrl_c_during_the_check_before_start_sends_no_start(tmp_path):
    """Ctrl-C while the filter's admission runs (IPOPT, about a second from this start):
    the check is cut short, its cut answer is no verdict (no refusal claimed), START is
    never sent, and the stop frame says why (reason 2: signal); the outputs are kept."""
    double, url, log = start_double(tmp_path, *MPSC, *FAR_START, scenario="pendulum_finite_rail")
    host = spawn("run", "pendulum_finite_rail", "--controller", "pd", *MPSC,
                 "--set", "safety.refuse_unadmitted=true", "--rig", url, "--duration", "1",
                 "--metrics", "m.json", "--out", "rig.rrd", cwd=tmp_path)
    _wait_for_line(host, "rig: the start checked before START")
    host.send_signal(signal.SIGINT)
    out, err = finish(host)
    double_out, _ = finish(double)
    assert host.returncode == 130, out + err
    assert "rig: the check of the start cut short by SIGINT; START not sent" in out
    assert "the start is refused" not in out
    assert "session 1: the host stopped before START (reason 2: signal); nothing moved" in double_out
    assert not log.exists()  # the double logs a session only once START came
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["status"] == "interrupted" and m["timing"]["cycles"] == 0
    assert m["timing"]["start_check"]["interrupted"] == "SIGINT"
    assert "refused" not in m["timing"]["start_check"]
    assert m["safety_filter"]["start_admitted"] is None
    assert m["safety_filter"]["start_refusal"] is None
    assert (tmp_path / "rig.rrd").stat().st_size > 0


@pytest.mark.realtime
def test_an_admitted_start_is_checked_before_start_or_at_the_first_cycle(tmp_path):
    from tspend.rig.replay import session_notes

    """From the scenario's own start the check before START admits it and the run
    completes on it; a rig that answers no query (--no-query) is started, said in one
    line, and the filter admits at its first cycle as in a simulation."""
    for options, before in (((), True), (("--no-query",), False)):
        folder = tmp_path / ("query" if before else "no_query")
        folder.mkdir()
        double, url, _ = start_double(folder, *MPSC, *options, scenario="pendulum_finite_rail")
        r = tspend("run", "pendulum_finite_rail", "--controller", "pd", *MPSC, "--rig", url,
                   "--duration", "0.5", "--metrics", "m.json", "--out", "rig.rrd", cwd=folder,
                   timeout=PROCESS_TIMEOUT_S)
        out, _ = finish(double)
        assert r.status == 0, r.err
        assert ("rig: the rig reads no state before START" in r.out) is not before
        m = json.loads((folder / "m.json").read_text())
        assert m["timing"]["start_check"]["before_start"] is before
        assert m["safety_filter"]["start_admitted"] is True
        assert m["timing"]["cycles"] == 250 and "ended (stop frame)" in out
        # the recording's session document keeps the check, for replay to make it again
        notes = session_notes(folder / "rig.rrd")
        assert notes["timing_notes"]["start_check"] == m["timing"]["start_check"]
        if before:
            state = m["timing"]["start_check"]["state"]
            assert state["slider"] == 0.0 and state["slider_dot"] == 0.0
            assert abs(state["hinge"] - np.pi / 30) < 2 * np.pi / 2e4


# -- the C rig end over a serial line -------------------------------------------------------
@pytest.fixture(scope="module")
def rig_end(tmp_path_factory) -> Path:
    exe = tmp_path_factory.mktemp("c") / "rig_end"
    subprocess.run(["cc", "-std=c99", "-D_POSIX_C_SOURCE=200809L", "-Wall", "-Wextra", "-Werror",
                    "-O2", "-DRIG_END_HOST", "-o", str(exe), str(C_SOURCE), "-lm"], check=True,
                   timeout=PROCESS_TIMEOUT_S)
    return exe


def lqr_over_a_pseudo_terminal(tmp_path: Path, rig_end: Path):
    """A 2 s LQR run through the C rig end on a pseudo-terminal (m.json in ``tmp_path``);
    the run's result and what the rig end printed."""
    master, slave = pty.openpty()
    tty.setraw(slave)  # the line carries bytes, not text
    try:
        rig = subprocess.Popen([str(rig_end), str(master), "60"], pass_fds=[master],
                               stdout=subprocess.PIPE, text=True)
        r = tspend("run", SCENARIO, "--controller", "lqr", "--rig",
                   f"serial://{os.ttyname(slave)}?baud=1000000", "--duration", "2",
                   "--metrics", "m.json", "--no-record", cwd=tmp_path, timeout=PROCESS_TIMEOUT_S)
        out, _ = rig.communicate(timeout=PROCESS_TIMEOUT_S)
    finally:
        os.close(slave)
        os.close(master)
    return r, out


@pytest.mark.realtime(alone=True)
def test_lqr_over_a_serial_line_to_the_compiled_c_rig_end(tmp_path, rig_end):
    pytest.importorskip("serial")
    for attempt in range(3):
        r, out = lqr_over_a_pseudo_terminal(tmp_path, rig_end)
        # a pseudo-terminal's bytes reach the other end through a kernel worker at normal
        # priority: in a slow spell it may hold them past the 50 ms watchdog (CI: 52 ms
        # at 0.054 s); the run then ends as it must, and the line is tried again
        if not (r.status == 3 and "the rig is gone" in r.err):
            break
    assert r.status == 0, r.err
    assert "completed: 1000 steps" in r.out
    assert out.startswith("rig_end: stopped")  # by the host's stop frame
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["timing"]["frames"]["corrupt"] == 0 and m["joints"]["hinge"]["max_abs"] < 0.2


def test_the_c_rig_end_answers_a_query_before_start_and_ignores_it_after(tmp_path, rig_end):
    """The C rig end's hello says it answers a query; before START it answers with its
    state (the query's seq, no command applied, its x0's counts, nothing moved); a STOP
    before START ends it with the cart where it was."""
    master, slave = pty.openpty()
    tty.setraw(slave)
    parser = protocol.StreamParser()

    def exchange(frame: bytes, kind: bytes) -> tuple:
        os.write(slave, frame)
        until = time.monotonic() + 5.0
        while time.monotonic() < until:
            ready = select.select([slave], [], [], 0.05)[0]
            for found in parser.feed(os.read(slave, 4096)) if ready else ():
                if found[0] == kind:
                    return found
        pytest.fail(f"no {kind!r} frame from the rig end")

    try:
        rig = subprocess.Popen([str(rig_end), str(master), "20"], pass_fds=[master],
                               stdout=subprocess.PIPE, text=True)
        hello = protocol.as_hello(exchange(protocol.hello_request(1), protocol.HELLO)[2])
        assert hello.answers_query
        answers = [exchange(protocol.query(seq), protocol.SENSOR) for seq in (7, 8)]
        os.write(slave, protocol.stop(protocol.STOP_DONE))
        out, _ = rig.communicate(timeout=PROCESS_TIMEOUT_S)
    finally:
        os.close(slave)
        os.close(master)
    first, second = (protocol.as_sensor(seq, fields) for _, seq, fields in answers)
    assert (first.seq, second.seq) == (7, 8)
    assert first.command_seq == second.command_seq == protocol.NO_COMMAND
    # x0 = (0, pi/30) at the rig end's encoders, unchanged between the queries
    assert first.counts == second.counts == (0, round(np.pi / 30 * 2e4 / (2 * np.pi)))
    assert second.rig_time_us >= first.rig_time_us
    assert out.startswith("rig_end: stopped; slider 0.000000 m, hinge 0.104720 rad")


def test_a_period_the_baud_rate_cannot_carry_is_refused_before_any_frame(tmp_path):
    pytest.importorskip("serial")
    master, slave = pty.openpty()
    tty.setraw(slave)
    try:
        r = tspend("run", SCENARIO, "--controller", "lqr", "--rig",
                   f"serial://{os.ttyname(slave)}?baud=115200", "--no-record", cwd=tmp_path,
                   timeout=PROCESS_TIMEOUT_S)
        os.set_blocking(master, False)
        try:
            written = os.read(master, 4096)
        except BlockingIOError:
            written = b""
    finally:
        os.close(slave)
        os.close(master)
    assert r.status == 2
    # 44 + 28 bytes of 10 bits at 115200 baud: 6.25 ms, longer than the 1 ms period
    assert "6.25 ms of line time, longer than the period 1 ms" in r.one_error_line()
    assert written == b""


def _relay(master_a: int, master_b: int, done) -> None:
    """Bytes between two pseudo-terminals, both ways: a null-modem cable."""
    import select

    while not done.is_set():
        ready, _, _ = select.select([master_a, master_b], [], [], 0.05)
        for fd in ready:
            try:
                data = os.read(fd, 4096)
            except OSError:  # the other end closed
                return
            os.write(master_b if fd == master_a else master_a, data)


@pytest.mark.realtime(alone=True)
def test_the_double_serves_a_serial_line(tmp_path):
    """``rig serve --listen serial://`` end to end: the double on one pseudo-terminal, the
    runner on another, the test's relay between them as the cable."""
    pytest.importorskip("serial")
    import threading

    (rig_master, rig_slave), (host_master, host_slave) = pty.openpty(), pty.openpty()
    for fd in (rig_slave, host_slave):
        tty.setraw(fd)
    done = threading.Event()
    relay = threading.Thread(target=_relay, args=(rig_master, host_master, done), daemon=True)
    relay.start()
    log = tmp_path / "double.npz"
    baud = "?baud=1000000"
    try:
        double = spawn("rig", "serve", SCENARIO, "--listen",
                       f"serial://{os.ttyname(rig_slave)}{baud}", "--log", str(log),
                       "--wait-s", "60", "--max-session-s", "90", cwd=tmp_path)
        line = double.stdout.readline()
        assert line.startswith("rig serve:"), line + double.stderr.read()
        r = tspend("run", SCENARIO, "--controller", "lqr", "--rig",
                   f"serial://{os.ttyname(host_slave)}{baud}", "--duration", "1",
                   "--metrics", "m.json", "--out", "rig.rrd", cwd=tmp_path,
                   timeout=PROCESS_TIMEOUT_S)
        out, _ = finish(double)
    finally:
        done.set()
        relay.join(timeout=5)
        for fd in (rig_slave, host_slave, rig_master, host_master):
            os.close(fd)
    assert r.status == 0, r.err
    assert "completed: 500 steps" in r.out and "ended (stop frame)" in out
    # what the controller saw is what the double measured, frame by frame, over the line
    truth = np.load(log)
    seq = rig_series(tmp_path / "rig.rrd", "sensor_seq").astype(int)
    counts = rig_series(tmp_path / "rig.rrd", "counts").reshape(500, -1).astype(int)
    sent = dict(zip(truth["sensor_seq"], map(tuple, truth["sensor_counts"])))
    first = int(np.argmax(rig_series(tmp_path / "rig.rrd", "fresh")))  # cycle 0 may be stale
    # the first frame crosses the test's relay (a Python thread, the cable): in a cold
    # suite beside other work it came fresh at cycle 11; 50 cycles (0.1 s) bound the
    # line's coming up, and every cycle after it is checked
    assert first < 50 and all(tuple(counts[k]) == sent[seq[k]] for k in range(first, 500))
    assert json.loads((tmp_path / "m.json").read_text())["timing"]["frames"]["corrupt"] == 0
