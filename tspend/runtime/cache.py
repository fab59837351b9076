"""Cache entries that are checked before use, and rebuilt when the check fails.

A cache is a cache: an entry that is garbage, empty, truncated, a directory, written for
another key or on another kind of machine is not loaded (a generated module would run
another machine's equations on this one's arrays, a damaged shared object could crash the
process).  Each entry carries what it must be:

- a text entry (a generated module) ends in one line ``# tspend-cache key=K sha256=D``:
  the key it was made for and the SHA-256 of the text before that line
  (:func:`stamped`, :func:`text_problem`);
- a binary entry (a compiled ``.so``) has a sidecar ``NAME.tspend-sha256`` holding its
  key, the machine it was built on and its SHA-256 (:func:`write_binary`,
  :func:`binary_problem`);
- the files numba writes itself (``__pycache__/*.nbi``, ``*.nbc``) are listed, with their
  sizes, times and SHA-256, in a manifest written when the process ends
  (:func:`check_numba_files`): a file that changed since (or is not listed yet) is read
  as the pickles it must be, opcode by opcode; one that is not whole is removed before
  numba reads it, and numba compiles that function again.  (A checksum alone cannot
  tell damage from numba's own rewrite of an index by another process.)

A failed check is said in one warning line (``tspend: warning: the cached ... rebuilt``)
and the entry is rebuilt; it is never a crash.  Only the standard library is used.
"""

from __future__ import annotations

import atexit
import hashlib
import json
import os
import platform
import shutil
import sys
import tempfile
import warnings
from pathlib import Path

#: the last line of a stamped text entry
_TRAILER = "# tspend-cache key="
#: the sidecar of a binary entry, and numba's manifest in a __pycache__ folder
SIDECAR = ".tspend-sha256"
MANIFEST = "tspend-numba-manifest.json"


def machine_tag() -> str:
    """What a compiled entry is only good for: the OS, the CPU architecture, the Python."""
    return f"{sys.platform}-{platform.machine()}-py{sys.version_info[0]}{sys.version_info[1]}"


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def stamped(text: str, key: str) -> str:
    """``text`` with its trailer line: the key and the text's SHA-256."""
    body = text if text.endswith("\n") else text + "\n"
    return f"{body}{_TRAILER}{key} sha256={_sha256(body.encode())}\n"


def text_problem(path: Path, key: str) -> str | None:
    """None when ``path`` is a stamped entry for ``key`` whose text is whole; "missing"
    when there is nothing there; else what is wrong with it."""
    if not os.path.lexists(path):
        return "missing"
    if path.is_symlink() or not path.is_file():
        return "is not a regular file"
    try:
        data = path.read_bytes()
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc})"
    body, sep, last = data.rstrip(b"\n").rpartition(b"\n")
    if not sep or not last.startswith(_TRAILER.encode()):
        return "is not a tspend cache entry (empty, truncated or garbage)"
    fields = dict(part.split("=", 1) for part in last[len(b"# tspend-cache "):].decode(
        errors="replace").split() if "=" in part)
    if fields.get("key") != key:
        return f"was made for another key ({fields.get('key', '?')[:40]})"
    if fields.get("sha256") != _sha256(body + b"\n"):
        return "does not match its checksum (damaged or truncated)"
    return None


def discard(path: Path) -> None:
    """Remove whatever is at ``path`` (a file, a link, a directory); errors ignored."""
    try:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
    except OSError:
        pass


def write_atomically(path: Path, data: bytes) -> None:
    """``data`` to ``path`` through an exclusively created temporary file in the same
    folder, renamed onto it (a concurrent reader sees all of it or none)."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name[:100]}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def rebuilt(what: str, path: Path, problem: str, echo: bool = False) -> None:
    """The one line saying an entry failed its check and is rebuilt: a warning, which the
    CLI prints as ``tspend: warning: ...``; ``echo``: printed so at once (for checks made
    while the package is imported, before the CLI collects warnings)."""
    message = f"the cached {what} {path} {problem}; rebuilt"
    if echo:
        try:
            print(f"tspend: warning: {message}", file=sys.stderr, flush=True)
        except (OSError, ValueError):
            pass
    else:
        warnings.warn(message, stacklevel=2)


def write_binary(path: Path, data_path: Path, key: str) -> None:
    """Move the built file ``data_path`` onto ``path`` and write its sidecar."""
    digest = _sha256(data_path.read_bytes())
    # the sidecar first: a concurrent reader that sees the new file sees its checksum
    side = path.with_name(path.name + SIDECAR)
    write_atomically(side, json.dumps({"key": key, "machine": machine_tag(),
                                       "sha256": digest}).encode())
    os.replace(data_path, path)


def binary_problem(path: Path, key: str) -> str | None:
    """None when ``path`` and its sidecar agree (key, machine, checksum); "missing" when
    there is no entry; else what is wrong."""
    if not os.path.lexists(path):
        return "missing"
    if path.is_symlink() or not path.is_file():
        return "is not a regular file"
    side = path.with_name(path.name + SIDECAR)
    try:
        meta = json.loads(side.read_text())
        data = path.read_bytes()
    except (OSError, ValueError) as exc:
        return f"has no readable checksum beside it ({type(exc).__name__})"
    if not isinstance(meta, dict) or meta.get("key") != key:
        return "was made for another key"
    if meta.get("machine") != machine_tag():
        return f"was built on another machine ({str(meta.get('machine'))[:60]})"
    if meta.get("sha256") != _sha256(data):
        return "does not match its checksum (damaged or truncated)"
    return None


def discard_binary(path: Path) -> None:
    discard(path)
    discard(path.with_name(path.name + SIDECAR))


# -- numba's own files -------------------------------------------------------------------
_WATCHED: set[Path] = set()


def _numba_files(pycache: Path, prefix: str) -> list[Path]:
    try:
        return [p for p in pycache.iterdir()
                if p.name.startswith(prefix) and p.suffix in (".nbi", ".nbc")]
    except OSError:
        return []


def check_numba_files(pycache: Path, prefix: str = "", what: str = "compiled code",
                      echo: bool = False) -> int:
    """Remove the numba cache files in ``pycache`` (names starting with ``prefix``) that
    changed since this manifest listed them (truncated, damaged, a directory); returns
    how many.  The manifest is brought up to date when the process ends, so what numba
    writes during it is listed for the next one."""
    manifest = pycache / MANIFEST
    try:
        listed = json.loads(manifest.read_text())
        if not isinstance(listed, dict):
            listed = {}
    except (OSError, ValueError):
        listed = {}
    removed = 0
    names = {p.name for p in _numba_files(pycache, prefix)} | {
        n for n in listed if n.startswith(prefix) and os.path.lexists(pycache / n)}
    for name in sorted(names):
        entry = listed.get(name)
        if not (isinstance(entry, list) and len(entry) == 3):
            entry = None   # not listed yet (written by a process that ended abruptly)
        path = pycache / name
        problem = _file_problem(path, entry) or _replaced_alone(pycache, name, entry, listed)
        if problem:
            discard(path)
            removed += 1
            rebuilt(what, path, problem, echo)
    if pycache not in _WATCHED:
        _WATCHED.add(pycache)
        atexit.register(_write_manifest, pycache)
    return removed


def _file_problem(path: Path, entry: list | None) -> str | None:
    """None when ``path`` is as listed, or changed but whole (numba rewrites an index when
    another process compiles a new signature: that is no damage); else what is wrong."""
    if path.is_symlink() or not path.is_file():
        return "is not a regular file"
    st = path.stat()
    if entry is not None:
        size, mtime_ns, digest = entry
        if st.st_size == size and st.st_mtime_ns == mtime_ns:
            return None   # unchanged since listed: its checksum is not read again
    try:
        data = path.read_bytes()
    except OSError:
        return "cannot be read"
    if entry is not None and _sha256(data) == entry[2]:
        return None
    return None if _whole_pickles(data) else "is not whole (damaged or truncated)"


def _replaced_alone(pycache: Path, name: str, entry: list | None, listed: dict) -> str | None:
    """A listed code file (``.nbc``) whose bytes changed while its index (``.nbi``) did not:
    numba writes a function's code only with its index, so this is another file copied
    over it (whole pickles, another function's code: loading it crashes the process)."""
    if not name.endswith(".nbc") or entry is None:
        return None
    index_name = name.rsplit(".", 2)[0] + ".nbi"      # m.f-9.py311.1.nbc -> m.f-9.py311.nbi
    index_entry = listed.get(index_name)
    if not (isinstance(index_entry, list) and len(index_entry) == 3):
        return None
    try:
        st, index_st = (pycache / name).stat(), (pycache / index_name).stat()
    except OSError:
        return None
    if [index_st.st_size, index_st.st_mtime_ns] != index_entry[:2]:
        return None   # the index was rewritten too: numba's own save
    if [st.st_size, st.st_mtime_ns] == entry[:2]:
        return None
    try:
        if _sha256((pycache / name).read_bytes()) == entry[2]:
            return None   # touched, not changed
    except OSError:
        return "cannot be read"
    return "was replaced without its index (another function's code?)"


def _whole_pickles(data: bytes) -> bool:
    """Whether ``data`` is one or more complete pickles (numba's index is two, its code
    one), walked opcode by opcode without building any object (nothing is imported)."""
    import io
    import pickletools

    stream = io.BytesIO(data)
    if not data:
        return False
    try:
        while stream.tell() < len(data):
            last = None
            for opcode, _, _ in pickletools.genops(stream):
                last = opcode.name
            if last != "STOP":
                return False
    except Exception:  # noqa: BLE001 - any malformed opcode is damage
        return False
    return True


def _write_manifest(pycache: Path) -> None:
    """List every numba file in ``pycache`` as it is now (at the process's end)."""
    manifest = pycache / MANIFEST
    try:
        old = json.loads(manifest.read_text())
        old = old if isinstance(old, dict) else {}
    except (OSError, ValueError):
        old = {}
    entries = {}
    for path in _numba_files(pycache, ""):
        try:
            if path.is_symlink() or not path.is_file():
                continue
            st = path.stat()
            prev = old.get(path.name)
            if isinstance(prev, list) and len(prev) == 3 and prev[:2] == [st.st_size,
                                                                          st.st_mtime_ns]:
                entries[path.name] = prev
            else:
                entries[path.name] = [st.st_size, st.st_mtime_ns, _sha256(path.read_bytes())]
        except OSError:
            continue
    if entries == old:
        return
    try:
        write_atomically(manifest, json.dumps(entries).encode())
    except OSError:
        pass   # a read-only cache: nothing is listed, nothing is removed


def private_folder(prefix: str) -> Path:
    """A fresh folder in the system's temp folder for a process without a writable cache,
    removed when the process that made it ends (a forked worker leaves it to its parent)."""
    folder = Path(tempfile.mkdtemp(prefix=prefix))
    owner = os.getpid()

    def remove() -> None:
        if os.getpid() == owner:
            shutil.rmtree(folder, ignore_errors=True)

    atexit.register(remove)
    return folder
