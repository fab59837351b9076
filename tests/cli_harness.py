"""Running ``tspend`` as a user would (a separate process) and checking a user's files."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@dataclass
class Result:
    status: int | None
    out: str
    err: str

    @property
    def err_lines(self) -> list[str]:
        """stderr's lines less the progress of a slow step (numba's first compile, on a cold
        cache or a busy machine): those say how long to wait, never what went wrong."""
        from tspend.runtime.progress import PROGRESS_PREFIX

        return [line for line in self.err.splitlines()
                if line.strip() and not line.startswith(PROGRESS_PREFIX)]

    def one_error_line(self) -> str:
        """The single stderr line, asserting there is exactly one and no traceback."""
        assert "Traceback" not in self.err + self.out, self.err
        assert len(self.err_lines) == 1, self.err
        return self.err_lines[0]


def tspend(*args: str, cwd: Path, timeout: float = 120, **popen) -> Result:
    proc = subprocess.run([sys.executable, "-m", "tspend.cli", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=timeout, **popen)
    return Result(proc.returncode, proc.stdout, proc.stderr)


def spawn(*args: str, cwd: Path, **popen) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "tspend.cli", *args], cwd=cwd,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **popen)


def user_files(d: Path) -> dict[str, str]:
    """A user's directory: a past recording and metrics, a scenario, a model, notes.

    Returns the snapshot :func:`assert_intact` compares against.
    """
    (d / "K.rrd").write_bytes(b"RRF2" + os.urandom(200_000))
    (d / "K.json").write_text('{"rmse": 0.01}\n')
    (d / "notes.txt").write_text("my notes\n")
    shutil.copy(ROOT / "scenarios" / "ex2_duffing.toml", d / "S.toml")
    text = (ROOT / "scenarios" / "pendulum_mujoco.toml").read_text()
    (d / "P.toml").write_text(text.replace('model = "models/cartpole.xml"', 'model = "M.xml"'))
    shutil.copy(ROOT / "models" / "cartpole.xml", d / "M.xml")
    return snapshot(d)


def snapshot(d: Path) -> dict[str, str]:
    return {str(p.relative_to(d)): _digest(p)
            for p in sorted(d.rglob("*")) if p.is_file() and not p.is_symlink()}


def _digest(p: Path) -> str:
    st = p.stat()
    if st.st_size > 50_000_000:  # sparse test files of gigabytes: size and time stand in
        return f"{st.st_size}:{st.st_mtime_ns}"
    return hashlib.sha256(p.read_bytes()).hexdigest()


def assert_intact(d: Path, before: dict[str, str], allow_new: tuple[str, ...] = ()) -> None:
    """Every file that was there is unchanged, and nothing new appeared (but ``allow_new``)."""
    after = snapshot(d)
    changed = [p for p, h in before.items() if after.get(p) != h]
    assert not changed, f"changed or lost: {changed}"
    new = [p for p in after if p not in before and not p.startswith(allow_new)]
    assert not new, f"new files: {new}"
