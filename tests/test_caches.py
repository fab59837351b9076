"""Cache entries are checked before use and rebuilt when the check fails (issue 44).

The checks of :mod:`tspend.runtime.cache` against files damaged by hand (garbage, empty,
truncated, a directory, another key's entry, another machine's build); and, as a user
meets them, a derivation module and numba's code for it damaged between two processes,
and a process without a writable cache that leaves nothing in the temp folder.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tspend.runtime import cache

from cli_harness import ROOT


def _entry(tmp_path: Path, key: str = "k1") -> Path:
    path = tmp_path / "m.py"
    path.write_text(cache.stamped("X = 1\nY = 2\n", key))
    return path


@pytest.mark.parametrize("damage,phrase", [
    (lambda p: p.write_text("garbage"), "not a tspend cache entry"),
    (lambda p: p.write_text(""), "not a tspend cache entry"),
    (lambda p: p.write_bytes(p.read_bytes()[:8]), "not a tspend cache entry"),
    (lambda p: p.write_bytes(p.read_bytes()[:-20]), "checksum"),
    (lambda p: p.write_text(p.read_text().replace("Y = 2", "Y = 3")), "checksum"),
    (lambda p: (p.unlink(), p.mkdir()), "not a regular file"),
    (lambda p: p.write_text(cache.stamped("X = 1\nY = 2\n", "k2")), "another key"),
])
def test_a_damaged_text_entry_is_named(tmp_path, damage, phrase):
    path = _entry(tmp_path)
    assert cache.text_problem(path, "k1") is None
    damage(path)
    assert phrase in cache.text_problem(path, "k1")
    cache.discard(path)
    assert cache.text_problem(path, "k1") == "missing"


def test_a_binary_entry_is_checked_against_its_sidecar(tmp_path, monkeypatch):
    built = tmp_path / "built.so"
    built.write_bytes(b"\x7fELF" + bytes(range(256)) * 10)
    so = tmp_path / "f_abc.so"
    cache.write_binary(so, built, "abc")
    assert not built.exists() and cache.binary_problem(so, "abc") is None
    assert "another key" in cache.binary_problem(so, "abd")
    so.write_bytes(so.read_bytes()[:100])
    assert "checksum" in cache.binary_problem(so, "abc")
    side = so.with_name(so.name + cache.SIDECAR)
    meta = json.loads(side.read_text())
    so.write_bytes(b"\x7fELF" + bytes(range(256)) * 10)
    assert cache.binary_problem(so, "abc") is None
    side.write_text(json.dumps(dict(meta, machine="win32-arm64-py39")))
    assert "another machine" in cache.binary_problem(so, "abc")
    side.unlink()
    assert "no readable checksum" in cache.binary_problem(so, "abc")


def test_numba_files_that_changed_since_listed_are_removed(tmp_path, recwarn):
    pycache = tmp_path / "__pycache__"
    pycache.mkdir()
    import pickle

    a, b = pycache / "m.f-1.py311.nbi", pycache / "m.f-1.py311.1.nbc"
    # numba's layout: the index is two pickles, the code one
    a.write_bytes(pickle.dumps("0.60") + pickle.dumps((("stamp", 1), {"sig": "m.f-1.1.nbc"})))
    b.write_bytes(pickle.dumps({"code": b"\x00" * 4000}))
    cache._write_manifest(pycache)                 # what the process's end does
    assert cache.check_numba_files(pycache) == 0 and a.exists() and b.exists()
    # another process compiled a new signature: numba rewrote the index, whole
    a.write_bytes(pickle.dumps("0.60") + pickle.dumps((("stamp", 1), {"s1": 1, "s2": 2})))
    assert cache.check_numba_files(pycache) == 0 and a.exists()
    b.write_bytes(b.read_bytes()[:1000])           # truncated
    assert cache.check_numba_files(pycache) == 1
    assert a.exists() and not b.exists()
    assert any("not whole" in str(w.message) for w in recwarn)


def _articulated(env: dict, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tspend.cli", "run", "acrobot_mujoco",
                           "--duration", "0.01", "--no-record"], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)


def test_a_damaged_derivation_and_its_numba_code_are_rebuilt(tmp_path):
    # numba's code beside the derived module: not in a NUMBA_CACHE_DIR (.ci/run sets one)
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["TSPEND_CACHE_DIR"] = str(tmp_path / "cache")
    first = _articulated(env, ROOT)
    assert first.returncode == 0, first.stderr
    module, = (tmp_path / "cache" / "articulated").glob("*.py")
    good = module.read_text()
    # another machine's module under this key: the key in its last line says so
    module.write_text(good.replace("NV = 2", "NV = 3").rsplit("# tspend-cache", 1)[0]
                      + "# tspend-cache key=0123456789abcdef01234567 sha256=0\n")
    nbc = sorted((tmp_path / "cache" / "articulated" / "__pycache__").glob("*.nbc"))
    assert nbc
    nbc[0].write_bytes(nbc[0].read_bytes()[:100])
    second = _articulated(env, ROOT)
    assert second.returncode == 0, second.stderr
    said = [line for line in second.stderr.splitlines() if "rebuilt" in line]
    assert any("another key" in line for line in said), second.stderr
    assert all(line.startswith("tspend: warning: the cached ") for line in said)
    assert module.read_text() == good


def test_without_a_writable_cache_nothing_is_left_in_the_temp_folder(tmp_path):
    (tmp_path / "file").write_text("not a folder")
    temp = tmp_path / "temp"
    temp.mkdir()
    env = dict(os.environ, TSPEND_CACHE_DIR=str(tmp_path / "file" / "cache"), TMPDIR=str(temp))
    r = _articulated(env, tmp_path)
    assert r.returncode == 0, r.stderr
    assert list(temp.iterdir()) == [] and sorted(os.listdir(tmp_path)) == ["file", "temp"]
