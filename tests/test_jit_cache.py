"""A cached compiled function is dropped when any source of the package changes."""

from __future__ import annotations

import pickle
from pathlib import Path

from tspend.runtime.jit import STAMP, invalidate_stale_cache, sources_digest


def _package(tmp_path: Path) -> Path:
    pkg = tmp_path / "pkg"
    (pkg / "sub" / "__pycache__").mkdir(parents=True)
    (pkg / "__pycache__").mkdir()
    (pkg / "a.py").write_text("x = 1\n")
    (pkg / "sub" / "b.py").write_text("y = 2\n")
    return pkg


def _cache_files(pkg: Path) -> list[Path]:
    return sorted(pkg.rglob("*.nb[ic]"))


def test_unchanged_sources_keep_the_cache(tmp_path: Path) -> None:
    pkg = _package(tmp_path)
    invalidate_stale_cache(pkg)            # first sight: stamps the sources
    # whole pickles, as numba writes them (a damaged file is removed: tests/test_caches.py)
    (pkg / "__pycache__" / "a.f-1.py311.nbi").write_bytes(pickle.dumps("index") * 2)
    (pkg / "sub" / "__pycache__" / "b.g-2.py311.1.nbc").write_bytes(pickle.dumps("code"))
    assert invalidate_stale_cache(pkg) is False
    assert len(_cache_files(pkg)) == 2
    assert (pkg / "__pycache__" / STAMP).read_text().strip() == sources_digest(pkg)


def test_a_changed_callee_drops_every_cached_function(tmp_path: Path) -> None:
    pkg = _package(tmp_path)
    invalidate_stale_cache(pkg)
    # whole pickles, as numba writes them (a damaged file is removed: tests/test_caches.py)
    (pkg / "__pycache__" / "a.f-1.py311.nbi").write_bytes(pickle.dumps("index") * 2)
    (pkg / "sub" / "__pycache__" / "b.g-2.py311.1.nbc").write_bytes(pickle.dumps("code"))
    (pkg / "sub" / "b.py").write_text("y = 3\n")    # only the callee's file changes
    assert invalidate_stale_cache(pkg) is True
    assert _cache_files(pkg) == []
    assert (pkg / "__pycache__" / STAMP).read_text().strip() == sources_digest(pkg)


def test_the_installed_package_is_stamped() -> None:
    import tspend

    pkg = Path(tspend.__file__).resolve().parent
    stamp = pkg / "__pycache__" / STAMP
    assert stamp.is_file() and stamp.read_text().strip() == sources_digest(pkg)


def test_a_script_folders_kernels_are_dropped_when_the_package_changes(tmp_path: Path) -> None:
    # a benchmark's cached kernel whose index names a module the package has since moved:
    # numba keys it on the script alone, so only the package's digest can drop it
    pkg, scripts = _package(tmp_path), tmp_path / "scripts"
    (scripts / "__pycache__").mkdir(parents=True)
    invalidate_stale_cache(pkg, cached=scripts)
    kernel = scripts / "__pycache__" / "bench.loop-9.py311.nbi"
    kernel.write_bytes(pickle.dumps("index") * 2)
    assert invalidate_stale_cache(pkg, cached=scripts) is False and kernel.is_file()
    (pkg / "a.py").write_text("x = 4\n")
    assert invalidate_stale_cache(pkg, cached=scripts) is True and not kernel.exists()
    assert (scripts / "__pycache__" / STAMP).read_text().strip() == sources_digest(pkg)
    assert not (pkg / "__pycache__" / STAMP).exists()     # the package's own stamp untouched
