"""Numba's on-disk cache, kept honest when a callee changes.

numba keys a cached function on its own source file only.  The controller step is
composed of functions from six modules (bspline, rules, ts_model, compensator,
control_law, controller) and inlines them, so after an edit of ``ts_model.py`` the
cached ``controller_step`` would silently run the old law.  Here every source file of
the package is hashed (a few hundred kB, well under a millisecond), and when the hash
differs from the one stamped beside the cache, every cached function of the package is
dropped and numba compiles afresh.  A user who never edits the package pays nothing; one
who does pays one compilation.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

#: numba options of every compiled function of the package: cached on disk, no GIL, numpy's
#: error model (a division by zero gives inf/nan, which the runner detects), no reference
#: counting runtime (nothing compiled allocates)
JIT = dict(cache=True, nogil=True, error_model="numpy", _nrt=False)

STAMP = "tspend-sources.sha256"


def sources_digest(package_dir: Path) -> str:
    """SHA-256 over the names and bytes of every ``.py`` file below ``package_dir``."""
    digest = hashlib.sha256()
    for path in sorted(package_dir.rglob("*.py")):
        digest.update(str(path.relative_to(package_dir)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def invalidate_stale_cache(package_dir: Path, cached: Path | None = None) -> bool:
    """Drop the numba cache files below ``cached`` (default: the package itself) if the
    package's sources changed since they were written.

    ``cached`` is another folder whose compiled functions call the package's (the
    benchmark scripts'): numba keys them on their own file only, and an index written
    before a package function moved names a module that no longer exists, so loading it
    fails instead of compiling afresh.  Returns True when files were dropped.  A read-only
    install (no writable ``__pycache__``) is left alone: nobody edits it.
    """
    cached = package_dir if cached is None else cached
    try:
        current = sources_digest(package_dir)
        stamp = cached / "__pycache__" / STAMP
        if stamp.is_file() and stamp.read_text().strip() == current:
            # the sources are the same: each cached function is checked against the
            # manifest of what numba wrote (a truncated file is removed and recompiled)
            from tspend.runtime.cache import check_numba_files

            for cache_dir in cached.rglob("__pycache__"):
                check_numba_files(cache_dir, "", "compiled code", echo=True)
            return False
        dropped = False
        for cache_dir in cached.rglob("__pycache__"):
            for pattern in ("*.nbi", "*.nbc"):
                for path in cache_dir.glob(pattern):
                    path.unlink(missing_ok=True)
                    dropped = True
        stamp.parent.mkdir(exist_ok=True)
        tmp = stamp.with_suffix(f".{id(current)}.tmp")
        tmp.write_text(current + "\n")
        tmp.replace(stamp)
        return dropped
    except OSError:
        return False


def drop_stale_kernels(folder: Path) -> bool:
    """For a script folder with ``cache=True`` kernels over tspend's compiled functions:
    drop its numba cache when tspend's sources changed (:func:`invalidate_stale_cache`).
    Call it before the first kernel compiles or loads."""
    return invalidate_stale_cache(Path(__file__).resolve().parents[1], cached=folder)


#: free space a cache folder must have to be used (bytes): an articulated machine's numba
#: code and an MPC's shared objects take a few MB each, and a write that fails half-way
#: through a run would end it; with less, the process builds in a private folder
MIN_CACHE_FREE_BYTES = 64 * 2**20


def writable_cache(folder: str) -> "Path | None":
    """``$TSPEND_CACHE_DIR/<folder>``, else ``$XDG_CACHE_HOME/tspend/<folder>`` (``~/.cache``),
    created; None when it cannot be written or its file system has less than
    :data:`MIN_CACHE_FREE_BYTES` free (then callers build anew in each process)."""
    import os
    import tempfile

    root = os.environ.get("TSPEND_CACHE_DIR")
    if not root:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        root = os.path.join(base, "tspend")
    path = Path(root) / folder
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = tempfile.NamedTemporaryFile(dir=path, delete=True)
        probe.close()
        free = os.statvfs(path)
    except OSError:
        return None
    if free.f_bavail * free.f_frsize < MIN_CACHE_FREE_BYTES:  # creating a file needs none
        return None
    return path
