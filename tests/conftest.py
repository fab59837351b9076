"""Test-session settings that must precede the first ``import mujoco``, and fixtures
shared by several test modules."""

import fcntl
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

# MuJoCo picks its OpenGL backend when it is imported; CI has no display, and EGL (Mesa's
# or a GPU's) is what renders headless here (the gym env's rgb_array, check_env's render)
os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture
def paths(monkeypatch):
    """The loop each run took, in order ("compiled" or "generic")."""
    import tspend.loop.runner as runner_module

    taken: list[str] = []
    real = runner_module.ClosedLoop._loop

    def spy(self, sinks):
        try:
            return real(self, sinks)
        finally:
            taken.append(self.path)

    monkeypatch.setattr(runner_module.ClosedLoop, "_loop", spy)
    return taken


#: the witness of the machine's punctuality beside a realtime test (tests/punctuality.py)
WITNESS = pytest.StashKey[subprocess.Popen]()
#: a realtime test that failed while, in some second, more than this share of the
#: witness's wake-ups came late, or one came later than STALL_MS, is skipped, saying so:
#: the machine missed the schedule, so the failure shows nothing about the code (quiet,
#: this VM's 1 kHz loops come late on under 0.1 % of wake-ups; in its slow spells on 4-5 %,
#: with stalls of 4-79 ms)
MACHINE_LATE_SHARE = 0.02
STALL_MS = 20.0


@pytest.fixture(autouse=True)
def machine_share(request, tmp_path_factory):
    """A ``realtime`` test runs with a witness of the machine's punctuality beside it;
    one marked ``realtime(alone=True)`` runs alone as well; every other test shares the
    machine.

    The suite runs on every core (pytest-xdist), and a rig test's loop, paced at 500 Hz,
    came late on a third of its cycles beside another worker's compiles on two cores: what
    it asserts (commands in force on time, frames fresh) measured the suite's load, not the
    code.  Alone is dear (the other workers wait: the cold suite took 43 min, not 28, with
    every rig test alone), so only the tests whose assertions are most sensitive to it are.
    Two locks in the session's shared temporary folder, one per machine: every test holds
    ``share`` shared; a test alone holds it alone.  ``turn`` is taken first by both, so a
    test waiting to be alone is not overtaken by the next test."""
    folder = _session_folder(tmp_path_factory)
    marker = request.node.get_closest_marker("realtime")
    alone = marker is not None and marker.kwargs.get("alone", False)
    with open(folder / "turn.lock", "a") as turn, open(folder / "share.lock", "a") as share:
        fcntl.flock(turn, fcntl.LOCK_EX)
        fcntl.flock(share, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        if not alone:
            fcntl.flock(turn, fcntl.LOCK_UN)
        if marker is not None:
            request.node.stash[WITNESS] = subprocess.Popen(
                [sys.executable, str(Path(__file__).with_name("punctuality.py"))],
                stdout=subprocess.PIPE, text=True)
        try:
            yield
        finally:
            _read_witness(request.node)  # still running when the test's setup failed
            fcntl.flock(share, fcntl.LOCK_UN)
            fcntl.flock(turn, fcntl.LOCK_UN)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    """A realtime test's failure while the witness saw the machine late becomes a skip
    that says so; any other failure of it carries the witness's figures."""
    report = yield
    if call.when != "call" or WITNESS not in item.stash or not report.failed:
        return report
    seen = _read_witness(item)
    late = (seen.get("worst_second_late_share", 0.0) > MACHINE_LATE_SHARE
            or seen.get("max_lateness_ms", 0.0) > STALL_MS)
    figures = (f"the machine's own 1 kHz timer (tests/punctuality.py) came over "
               f"{seen.get('late_us')} us late on {seen.get('worst_second_late_share', 0):.1%} "
               f"of its wake-ups in its worst second, at most {seen.get('max_lateness_ms', 0):.1f} ms late")
    if late:
        reason = report.longrepr.reprcrash.message if hasattr(report.longrepr, "reprcrash") else "failed"
        report.outcome = "skipped"
        report.longrepr = (str(item.path), item.location[1] or 0,
                           f"Skipped: the machine kept no schedule: {figures} ({reason.splitlines()[0][:200]})")
    else:
        report.sections.append(("the machine's punctuality", figures))
    return report


def _read_witness(node) -> dict:
    """Stop the witness (once) and return what it saw ({} if it said nothing)."""
    proc = node.stash.get(WITNESS, None)
    if proc is None:
        return {}
    if getattr(proc, "seen", None) is None:
        proc.send_signal(signal.SIGTERM)
        try:
            out, _ = proc.communicate(timeout=10)
            proc.seen = json.loads(out.strip().splitlines()[-1]) if out.strip() else {}
        except (subprocess.TimeoutExpired, ValueError):
            proc.kill()
            proc.communicate()
            proc.seen = {}
    return proc.seen


def _session_folder(tmp_path_factory) -> Path:
    """The folder every worker of this session shares (a worker's own base temporary folder
    is popen-gwN inside it; without xdist, the base folder itself)."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if base.name.startswith("popen-gw") else base
