"""Outputs: checked before anything is written, claimed exclusively, replaced only by a
complete file, unique default names, and write failures reported as failures.

Each CLI test asserts the exit status, the single stderr line and that every file the
user had is byte-for-byte intact (``cli_harness.assert_intact``).
"""

from __future__ import annotations

import errno
import json
import os
import resource
import signal
import sys
import time
from pathlib import Path

import pytest
from rerun.chunk import RrdReader

from cli_harness import assert_intact, snapshot, spawn, tspend, user_files
from tspend.runtime import outputs
from tspend.runtime.errors import OutputError, ScenarioError
from tspend.runtime.outputs import OutputRequest, claim, plan_outputs
from tspend.recorder import read_scalar_series
from tspend.recorder.series import SAMPLES_ENTITY

SHORT = ("--duration", "0.05")


def _samples(rrd: Path) -> int:
    """Samples of the state in a (compact) recording, read back through a complete footer."""
    RrdReader(str(rrd)).store()  # raises on a file without its footer
    return len(read_scalar_series(rrd, SAMPLES_ENTITY)[0])


# -- the module on its own -------------------------------------------------------------
def test_default_names_are_unique_for_the_same_second_and_seed(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(outputs.time, "strftime", lambda fmt: "20260101-000000")
    req = OutputRequest("--out", "recording", ".rrd", None, default_stem="scn")
    plans = plan_outputs([req])
    first, second = claim(plans, seed=1)[0], claim(plans, seed=1)[0]
    assert first.target != second.target and first.partial != second.partial
    assert first.target.name == "scn-20260101-000000-s1.rrd"
    for out in (first, second):
        out.write(b"data")
    finals = {second.commit(), first.commit()}
    assert {p.name for p in finals} == {"scn-20260101-000000-s1.rrd",
                                        "scn-20260101-000000-s1-2.rrd"}
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == sorted(p.name for p in finals)


def test_commit_of_a_default_name_never_replaces_a_file(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    req = OutputRequest("--out", "recording", ".rrd", None, default_stem="scn")
    out = claim(plan_outputs([req]), seed=3)[0]
    out.target.write_bytes(b"someone else's")  # the name was taken during the run
    out.write(b"mine")
    final = out.commit()
    assert final.read_bytes() == b"mine"
    taken = final.with_name(final.name.replace("-2.rrd", ".rrd"))
    assert taken.read_bytes() == b"someone else's"


def test_an_explicit_target_is_replaced_only_at_commit(tmp_path):
    target = tmp_path / "K.json"
    target.write_text("old")
    out = claim(plan_outputs([OutputRequest("--metrics", "metrics", ".json", str(target))]))[0]
    out.write(b"new")
    assert target.read_text() == "old" and out.partial.name == ".K.partial.json"
    out.commit()
    assert target.read_text() == "new" and not out.partial.exists()


def test_discard_leaves_the_target_and_removes_created_directories(tmp_path):
    target = tmp_path / "a" / "b" / "K.json"
    out = claim(plan_outputs([OutputRequest("--metrics", "metrics", ".json", str(target))]))[0]
    assert out.partial.exists()
    out.discard()
    assert not (tmp_path / "a").exists()


def test_a_fault_injected_writer_fails_the_output_and_replaces_nothing(tmp_path, monkeypatch):
    target = tmp_path / "K.json"
    target.write_text("old")
    out = claim(plan_outputs([OutputRequest("--metrics", "metrics", ".json", str(target))]))[0]

    def full(fd, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(outputs.os, "write", full)
    with pytest.raises(OutputError, match="K.json: could not be completed .No space left"):
        out.write(b"new")
    out.discard()
    assert target.read_text() == "old" and not out.partial.exists()


@pytest.mark.parametrize("make,option,path,message", [
    (None, "--out", "x.toml", "must end in .rrd"),
    (None, "--metrics", "m.txt", "must end in .json"),
    ("dir", "--out", "d.rrd", "is a directory"),
    ("ro", "--metrics", "ro.json", "read-only"),
    (None, "--out", "x" * 300 + ".rrd", "the file system allows"),
    (None, "--out", "", "empty path"),
    (None, "--out", "/dev/full", "must end in .rrd"),
    ("fifo", "--out", "f.rrd", "not a regular file"),
])
def test_plan_rejects_paths_that_are_not_ordinary_new_or_writable_files(tmp_path, make, option,
                                                                        path, message):
    p = tmp_path / path if path else Path("")
    if make == "dir":
        p.mkdir()
    elif make == "ro":
        p.write_text("{}")
        p.chmod(0o444)
    elif make == "fifo":
        os.mkfifo(p)
    before = snapshot(tmp_path)
    what = "recording" if option == "--out" else "metrics"
    suffix = ".rrd" if option == "--out" else ".json"
    with pytest.raises(ScenarioError, match=message):
        plan_outputs([OutputRequest(option, what, suffix, str(p) if path else "")])
    assert_intact(tmp_path, before)


# -- the command -----------------------------------------------------------------------
def test_a_rejected_run_leaves_an_existing_recording_whole(tmp_path):
    """The issue's case: a good recording, then the same --out with a dt MuJoCo rejects."""
    good = tspend("run", "P.toml", "--duration", "0.2", "--out", "K.rrd", cwd=tmp_path
                  ) if user_files(tmp_path) else None
    assert good.status == 0, good.err
    before = snapshot(tmp_path)
    r = tspend("run", "P.toml", "--duration", "0.2", "--out", "K.rrd", "--metrics", "K.json",
               "--set", "run.dt=0.0015", cwd=tmp_path)
    assert r.status == 2
    assert "not a whole multiple of the model timestep" in r.one_error_line()
    assert r.out == ""  # rejected before the banner
    assert_intact(tmp_path, before)
    assert _samples(tmp_path / "K.rrd") == 200


@pytest.mark.parametrize("argv,message", [
    (("--out", "K.rrd", "--metrics", "K.rrd"), "must end in .json"),
    (("--out", "X.rrd", "--metrics", "X.rrd.json", "--set", "name='x'"), None),
    (("--metrics", "S.toml"), "must end in .json"),
    (("--out", "S.toml"), "must end in .rrd"),
    (("--out", "link.rrd"), "is a link to S.toml"),
    (("--metrics", "hard.json"), "is an input of this run"),
    (("--out", "same.rrd", "--metrics", "same.json"), None),
    (("--out", "mlink.rrd"), "is a link to M.xml"),
    (("--metrics", "slink.json"), "is an input of this run"),
])
def test_outputs_never_overwrite_inputs_or_each_other(tmp_path, argv, message):
    before = user_files(tmp_path)
    os.symlink("S.toml", tmp_path / "link.rrd")
    os.symlink("M.xml", tmp_path / "mlink.rrd")
    os.link(tmp_path / "S.toml", tmp_path / "hard.json")
    (tmp_path / "S.json").write_text((tmp_path / "S.toml").read_text())
    os.symlink("S.json", tmp_path / "slink.json")
    before = snapshot(tmp_path)
    scenario = "P.toml" if "mlink.rrd" in argv else "S.json" if "slink.json" in argv else "S.toml"
    r = tspend("run", scenario, *SHORT, *argv, cwd=tmp_path)
    if message is None:  # distinct files: the run goes ahead
        assert r.status == 0, r.err
        assert_intact(tmp_path, before, allow_new=("X.", "same."))
        return
    assert r.status == 2 and message in r.one_error_line()
    assert_intact(tmp_path, before)


def test_two_outputs_naming_one_file_are_refused(tmp_path):
    """Through a symlinked directory: the same file by identity, not by spelling."""
    (tmp_path / "K.json").write_text("{}")
    os.symlink(".", tmp_path / "here")
    before = snapshot(tmp_path)
    with pytest.raises(ScenarioError, match="--a and --b name the same file"):
        plan_outputs([OutputRequest("--a", "report", ".json", str(tmp_path / "K.json")),
                      OutputRequest("--b", "report", ".json", str(tmp_path / "here" / "K.json"))])
    assert_intact(tmp_path, before)


def test_an_output_linked_to_another_kind_of_file_is_refused(tmp_path):
    before = user_files(tmp_path)
    os.symlink("notes.txt", tmp_path / "notes.rrd")
    before = snapshot(tmp_path)
    r = tspend("run", "S.toml", *SHORT, "--out", "notes.rrd", cwd=tmp_path)
    assert r.status == 2 and "is a link to notes.txt" in r.one_error_line()
    assert_intact(tmp_path, before)


def test_parallel_runs_never_share_a_default_name(tmp_path):
    """Five runs started together, two of them with the same seed: five whole recordings."""
    seeds = ("1", "2", "3", "1", "1")
    procs = [spawn("run", "ex2_duffing", *SHORT, "--seed", s, cwd=tmp_path) for s in seeds]
    results = [(p.wait(timeout=300), p.communicate()) for p in procs]
    assert all(status == 0 for status, _ in results), [e for _, (o, e) in results]
    files = sorted((tmp_path / "runs").iterdir())
    assert len(files) == 5 and not [f for f in files if "partial" in f.name]
    assert sum("-s1" in f.name for f in files) == 3
    for f in files:
        assert _samples(f) == 50


def test_a_second_run_aimed_at_the_same_file_is_refused(tmp_path):
    before = user_files(tmp_path)
    first = spawn("run", "pendulum_mujoco", "--duration", "600", "--out", "K.rrd", cwd=tmp_path)
    partial = tmp_path / ".K.partial.rrd"
    deadline = time.time() + 120
    while time.time() < deadline and (not partial.exists() or partial.stat().st_size == 0):
        time.sleep(0.05)
    r = tspend("run", "S.toml", *SHORT, "--out", "K.rrd", cwd=tmp_path)
    first.send_signal(signal.SIGTERM)
    out, err = first.communicate(timeout=120)
    assert r.status == 2 and "another tspend run is writing" in r.one_error_line()
    assert first.returncode == 143, err
    assert _samples(tmp_path / "K.rrd") > 0  # the first run's recording, whole, up to the stop
    assert_intact(tmp_path, {k: v for k, v in before.items() if k != "K.rrd"},
                  allow_new=("K.rrd",))


def _limit_file_size(limit: int):
    def pre() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes past the limit fail with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return pre


@pytest.mark.skipif(sys.platform != "linux", reason="RLIMIT_FSIZE fault injection is Linux's")
def test_a_recording_that_cannot_be_completed_is_a_failure_not_a_success(tmp_path):
    """Writes fail past 60 kB (the kernel's file size limit): exit 4, one line naming the
    file, the metrics on stdout, the old recording untouched, no partial file left."""
    before = user_files(tmp_path)
    r = tspend("run", "ex2_duffing", "--duration", "2", "--out", "K.rrd", "--metrics", "new.json",
               cwd=tmp_path, preexec_fn=_limit_file_size(60_000))
    line = r.one_error_line()
    assert r.status == 5 and "recording K.rrd: could not be completed" in line, r.err
    assert "completed:" in r.out
    doc = json.loads(r.out[r.out.index("{"):])
    assert doc["status"] == "completed" and doc["steps"] == 2000
    assert_intact(tmp_path, before, allow_new=("new.json",))
    assert json.loads((tmp_path / "new.json").read_text())["steps"] == 2000


@pytest.mark.skipif(sys.platform != "linux", reason="RLIMIT_FSIZE fault injection is Linux's")
def test_metrics_that_cannot_be_written_go_to_stdout(tmp_path):
    before = user_files(tmp_path)
    (tmp_path / "big.json").write_bytes(b" " * 5000)
    before = snapshot(tmp_path)
    r = tspend("run", "ex2_duffing", *SHORT, "--no-record", "--metrics", "big.json",
               cwd=tmp_path, preexec_fn=_limit_file_size(1000))
    assert r.status == 5 and "metrics big.json: could not be completed" in r.one_error_line()
    doc = json.loads(r.out[r.out.index("{"):])
    assert doc["steps"] == 50 and doc["scenario"] == "ex2_duffing"
    assert_intact(tmp_path, before)


@pytest.mark.skipif(os.geteuid() != 0 or sys.platform != "linux", reason="mounts a tmpfs")
def test_a_full_tmpfs_fails_the_run_and_keeps_the_old_files(tmp_path):
    import subprocess

    disk = tmp_path / "disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(disk)]).returncode:
        pytest.skip("cannot mount a tmpfs here")
    try:
        before = user_files(disk)  # 200 kB of it is K.rrd: little room is left
        r = tspend("run", str(disk / "S.toml"), "--duration", "2", "--out", "out.rrd",
                   "--metrics", "m.json", cwd=disk)
        assert r.status == 5 and "out.rrd: could not be completed" in r.one_error_line()
        assert "the metrics are on stdout" in r.err and '"steps": 2000' in r.out
        assert_intact(disk, before, allow_new=("m.json",))
    finally:
        subprocess.run(["umount", str(disk)])


def test_a_cold_cache_first_run_says_it_compiles_and_adds_no_error_line(tmp_path):
    """From empty caches (a new machine, CI) the first run compiles for tens of seconds:
    progress lines say so, with an estimate and then how long it took, and they are not
    error lines, so a failure's one line stays one line (issue 51, items 1 and 4: the
    compile notice broke the full-tmpfs check on a new machine)."""
    from tspend.runtime.progress import PROGRESS_PREFIX

    cold = tmp_path / "cold"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cold / "numba"),
               TSPEND_CACHE_DIR=str(cold / "tspend"))
    r = tspend("run", "pendulum_mujoco", *SHORT, "--no-record", cwd=tmp_path, env=env,
               timeout=900)
    assert r.status == 0, r.err
    progress = [line for line in r.err.splitlines()
                if line.startswith(PROGRESS_PREFIX + "compiling")]  # (a busy machine: "preparing" too)
    assert len(progress) == 2 and "about 25 s" in progress[0]
    assert "done in" in progress[1]
    assert r.err_lines == []
    assert any((cold / "numba").rglob("*.nbi"))  # it was cold: numba wrote its cache there


def test_sigkill_leaves_a_readable_partial_recording_under_a_name_that_says_so(tmp_path):
    before = user_files(tmp_path)
    proc = spawn("run", "pendulum_mujoco", "--duration", "600", "--out", "K.rrd", cwd=tmp_path)
    partial = tmp_path / ".K.partial.rrd"
    deadline = time.time() + 120
    # 1 MB: some 30 chunks (the first ones, with the model's geometry, are the largest)
    while time.time() < deadline and (not partial.exists() or partial.stat().st_size < 1_000_000):
        time.sleep(0.1)
    proc.kill()
    proc.communicate(timeout=60)
    assert_intact(tmp_path, before, allow_new=(".K.partial.rrd",))
    with pytest.warns(Warning, match="no footer"):  # killed: the footer never came
        chunks = sum(1 for _ in RrdReader(str(partial)).stream())
    assert chunks > 10
    # the next run with the same --out leaves the killed run's partial file alone
    kept = partial.read_bytes()
    r = tspend("run", "S.toml", *SHORT, "--out", "K.rrd", cwd=tmp_path)
    assert r.status == 0 and partial.read_bytes() == kept
    assert _samples(tmp_path / "K.rrd") == 50
