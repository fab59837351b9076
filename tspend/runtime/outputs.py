"""Output files that never cost the user a file: checked, claimed, written aside, renamed.

The life of an output (a recording, a metrics or report JSON):

1. :func:`plan_outputs` checks every path before anything is written: the suffix
   (``.rrd`` for a recording, ``.json`` for a document, so a typo cannot aim a run at a
   scenario or source file), that an existing target is a regular, writable file, that
   the file name fits the file system, and that no two outputs and no output and input
   are the same file, by resolved path and by identity (hard links, symlinks).
2. :func:`claim` creates beside each target, by exclusive creation, the partial file the
   data goes to (``.NAME.partial.rrd``, hidden) and holds a lock on it while the command runs, so
   a second run aimed at the same file is refused.  A default name carries the seed and
   the time and is made unique by the same exclusive creation: parallel runs never
   share one.
3. :meth:`Output.commit` syncs the partial file to disk and renames it onto the target,
   so an existing file is only ever replaced by a complete one; :meth:`Output.discard`
   removes it instead.

A run killed outright (SIGKILL, or ``os._exit`` in a plug-in) leaves the hidden
``.NAME.partial.rrd`` behind: the name says the file is incomplete, a listing does not
show it among the outputs, and the target it was meant to replace is untouched.

Only the standard library is used, so checks run before any heavy import.
"""

from __future__ import annotations

import errno
import os
import re
import stat
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Iterator, Sequence

try:
    import fcntl
except ImportError:  # Windows: no advisory locks; exclusive creation still protects
    fcntl = None  # type: ignore[assignment]

from tspend.runtime.errors import OutputError, ScenarioError

PARTIAL_TAG = ".partial"
#: how many numbered alternatives a default name or a partial file may try
MAX_CANDIDATES = 1000
#: the longest default stem taken from a scenario name
MAX_SLUG = 80


@dataclass(frozen=True)
class OutputRequest:
    """One output a command wants: ``path`` as the user gave it, or None for a default name."""

    option: str              # how the user names it, e.g. "--out"
    what: str                # "recording", "metrics", ...
    suffix: str              # ".rrd", ".json"
    path: str | None = None
    default_dir: str = "runs"
    default_stem: str = "run"


@dataclass(frozen=True)
class PlannedOutput:
    request: OutputRequest
    #: the resolved target (a default name's directory and stem, its final name is chosen
    #: by :func:`claim`)
    target: Path
    default: bool


def slug(text: str, limit: int = MAX_SLUG) -> str:
    """``text`` made safe as part of a file name: no separators, dots in front or controls."""
    s = re.sub(r"[^A-Za-z0-9_+-]+", "_", text).strip("_-")[:limit]
    return s or "run"


def _name_max(directory: Path) -> int:
    try:
        return int(os.pathconf(directory, "PC_NAME_MAX"))
    except (OSError, ValueError, AttributeError):
        return 255


def _existing_ancestor(path: Path) -> Path:
    p = path
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _identity(path: Path) -> tuple[int, int] | None:
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino


def _bad(req: OutputRequest, path: object, problem: str) -> ScenarioError:
    return ScenarioError(f"{req.option} {path}: {problem}")


def _check_explicit(req: OutputRequest) -> Path:
    raw = req.path or ""
    if not raw.strip():
        raise _bad(req, repr(raw), "empty path")
    if "\x00" in raw:
        raise _bad(req, repr(raw), "the path contains a NUL byte")
    given = Path(raw)
    if given.suffix.lower() != req.suffix:
        raise _bad(req, raw, f"a {req.what} file name must end in {req.suffix} (so that no "
                             f"other kind of file is ever replaced)")
    target = Path(os.path.realpath(given))  # a symlink's own target is what gets replaced
    if target.suffix.lower() != req.suffix:
        raise _bad(req, raw, f"is a link to {display(target)}, not to a {req.suffix} file")
    if len(os.fsencode(str(target))) >= 4096:
        raise _bad(req, raw, "the path is longer than the file system allows (4096 bytes)")
    ancestor = _existing_ancestor(target.parent)
    limit = _name_max(ancestor)
    if len(os.fsencode(target.name)) > limit:
        raise _bad(req, raw, f"the file name is {len(os.fsencode(target.name))} bytes long; "
                             f"the file system allows {limit}")
    try:
        st = os.stat(target)
    except (FileNotFoundError, NotADirectoryError):
        st = None  # the directory check says what is wrong with the path
    except OSError as exc:
        raise _bad(req, raw, f"cannot be inspected: {exc.strerror}") from None
    if st is not None:
        if stat.S_ISDIR(st.st_mode):
            raise _bad(req, raw, "is a directory")
        if not stat.S_ISREG(st.st_mode):
            raise _bad(req, raw, "is not a regular file (a device, pipe or socket); give the "
                                 "path of an ordinary file")
        if not st.st_mode & 0o222 or not os.access(target, os.W_OK):
            raise _bad(req, raw, "exists and is read-only; refusing to replace it")
    _check_directory(req, raw, target.parent)
    return target


def _check_directory(req: OutputRequest, raw: object, directory: Path) -> None:
    ancestor = _existing_ancestor(directory)
    if not ancestor.is_dir():
        raise _bad(req, raw, f"{ancestor} is not a directory")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise _bad(req, raw, f"directory {ancestor} is not writable")
    try:
        if os.statvfs(ancestor).f_flag & os.ST_RDONLY:
            raise _bad(req, raw, f"directory {ancestor} is on a read-only file system")
    except (OSError, AttributeError):
        pass


def plan_outputs(requests: Sequence[OutputRequest],
                 inputs: Iterable[str | os.PathLike[str]] = ()) -> list[PlannedOutput]:
    """Check every requested output; nothing is written.  Raises ScenarioError (exit 2)."""
    plans: list[PlannedOutput] = []
    for req in requests:
        if req.path is None:
            directory = Path(os.path.realpath(req.default_dir))
            _check_directory(req, f"(default {req.default_dir}/)", directory)
            plans.append(PlannedOutput(req, directory / slug(req.default_stem), True))
        else:
            try:
                plans.append(PlannedOutput(req, _check_explicit(req), False))
            except OSError as exc:  # e.g. a directory name longer than the system allows
                raise _bad(req, req.path, f"cannot be used: {exc.strerror or exc}") from None
    explicit = [p for p in plans if not p.default]
    for i, a in enumerate(explicit):
        for b in explicit[i + 1:]:
            same = a.target == b.target or (_identity(a.target) is not None
                                             and _identity(a.target) == _identity(b.target))
            if same:
                raise ScenarioError(f"{a.request.option} and {b.request.option} name the same "
                                    f"file {b.request.path}; give each output its own file")
    for raw in inputs:
        if raw is None:
            continue
        src = Path(os.path.realpath(raw))
        ident = _identity(src)
        for p in explicit:
            if p.target == src or (ident is not None and _identity(p.target) == ident):
                raise ScenarioError(f"{p.request.option} {p.request.path}: is an input of this "
                                    f"run ({raw}); refusing to overwrite it")
    return plans


class Output:
    """A claimed output: its data goes to :attr:`partial` until :meth:`commit`."""

    def __init__(self, plan: PlannedOutput, target: Path, partial: Path, fd: int,
                 created_dirs: list[Path]) -> None:
        self.plan, self.target, self.partial = plan, target, partial
        self._fd: int | None = fd
        self._created_dirs = created_dirs
        self.committed = False

    @property
    def what(self) -> str:
        return self.plan.request.what

    def write(self, data: bytes) -> None:
        """Write all of ``data`` to the partial file (for documents tspend writes itself)."""
        view = memoryview(data)
        try:
            while view:
                view = view[os.write(self._require_fd(), view):]
        except OSError as exc:
            raise self._failure(exc) from None

    def _require_fd(self) -> int:
        if self._fd is None:
            raise ValueError(f"{self.partial}: already closed")
        return self._fd

    def _failure(self, exc: OSError | str) -> OutputError:
        why = exc if isinstance(exc, str) else (exc.strerror or str(exc))
        return OutputError(f"{self.what} {display(self.target)}: could not be completed ({why}); "
                           f"nothing was replaced")

    def commit(self) -> Path:
        """Sync the partial file and rename it onto the target; returns the final path.

        Raises OutputError (the partial file is removed) if the data cannot be made durable.
        """
        try:
            os.fsync(self._require_fd())
            final = self._rename()
        except OSError as exc:
            self.discard()
            raise self._failure(exc) from None
        self.committed = True
        self.target = final
        _sync_directory(final.parent)
        self._close()
        return final

    def _rename(self) -> Path:
        if not self.plan.default:
            os.replace(self.partial, self.target)
            return self.target
        # a default name never replaces anything: link() fails if the name was taken
        for candidate in _numbered(self.target):
            try:
                os.link(self.partial, candidate)
            except FileExistsError:
                continue
            except OSError as exc:
                if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EXDEV):
                    raise
                if candidate.exists():  # no hard links here: check, then rename
                    continue
                os.rename(self.partial, candidate)
                return candidate
            os.unlink(self.partial)
            return candidate
        raise OSError(errno.EEXIST, f"no free name after {MAX_CANDIDATES} tries")

    def discard(self) -> None:
        """Remove the partial file (and the directories the claim created, if empty)."""
        if not self.committed:
            try:
                os.unlink(self.partial)
            except OSError:
                pass
        self._close()
        for d in reversed(self._created_dirs):
            try:
                d.rmdir()
            except OSError:
                break
        self._created_dirs = []

    def _close(self) -> None:
        if self._fd is not None:
            try:
                os.close(self._fd)  # also releases the lock
            except OSError:
                pass
            self._fd = None


def _numbered(first: Path) -> Iterable[Path]:
    yield first
    for k in range(2, MAX_CANDIDATES + 1):
        yield first.with_name(f"{first.stem}-{k}{first.suffix}")


def _sync_directory(directory: Path) -> None:
    """Make a rename durable (best effort: not every system can sync a directory)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _partial_names(target: Path) -> Iterable[Path]:
    """``.NAME.partial.rrd``, then ``.NAME.partial-2.rrd``, ... within the name limit.

    Hidden (a leading dot): a process that ends without its cleanup (``os._exit`` in a
    plug-in, SIGKILL) leaves nothing that a listing shows beside the user's outputs."""
    limit = _name_max(target.parent)
    for k in range(1, MAX_CANDIDATES + 1):
        tag = PARTIAL_TAG if k == 1 else f"{PARTIAL_TAG}-{k}"
        room = limit - len(os.fsencode("." + tag + target.suffix))
        stem = os.fsencode(target.stem)[:room].decode("utf-8", "ignore")
        yield target.with_name(f".{stem}{tag}{target.suffix}")


def _lock(fd: int) -> bool:
    """Take the lock on an open partial file; False if another process holds it."""
    if fcntl is None:
        return True
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    except OSError:  # file systems without locks: exclusive creation still protects
        return True
    return True


def _in_use(path: Path) -> bool:
    """Whether a live process holds the lock of an existing partial file."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return False
    try:
        return not _lock(fd)
    finally:
        os.close(fd)


def _create_exclusive(path: Path) -> int | None:
    try:
        return os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0),
                       0o644)
    except FileExistsError:
        return None


def _make_dirs(directory: Path) -> list[Path]:
    missing = []
    p = directory
    while not p.exists():
        missing.append(p)
        p = p.parent
    for d in reversed(missing):
        try:
            d.mkdir()
        except FileExistsError:
            pass
    return list(reversed(missing))  # in creation order, outermost first


def _claim_one(plan: PlannedOutput, stamp: str) -> Output:
    req = plan.request
    created = _make_dirs(plan.target.parent)
    try:
        if plan.default:
            base = plan.target.with_name(f"{plan.target.name}-{stamp}{req.suffix}")
            for target in _numbered(base):
                if target.exists():
                    continue
                partial = next(iter(_partial_names(target)))
                fd = _create_exclusive(partial)
                if fd is None:
                    continue
                _lock(fd)
                return Output(plan, target, partial, fd, created)
            raise _bad(req, base, f"no free file name after {MAX_CANDIDATES} tries")
        for partial in _partial_names(plan.target):
            fd = _create_exclusive(partial)
            if fd is None:
                if _in_use(partial):
                    raise _bad(req, req.path, f"another tspend run is writing this file (its "
                                              f"partial file {display(partial)} is in use)")
                continue  # left by a killed run: keep it, take the next name
            if not _lock(fd):  # raced with another run between create and lock
                os.close(fd)
                continue
            return Output(plan, plan.target, partial, fd, created)
        raise _bad(req, req.path, f"too many partial files beside it ({MAX_CANDIDATES})")
    except BaseException as exc:
        for d in reversed(created):
            try:
                d.rmdir()
            except OSError:
                break
        if not isinstance(exc, OSError):
            raise
        raise _bad(req, req.path or plan.target.parent,
                   f"cannot create a file in {display(plan.target.parent)}: "
                   f"{exc.strerror or exc}") from None


def claim(plans: Sequence[PlannedOutput], seed: int | None = None) -> list[Output]:
    """Create the partial file of every planned output, or none of them (ScenarioError)."""
    stamp = time.strftime("%Y%m%d-%H%M%S") + (f"-s{seed}" if seed is not None else "")
    claimed: list[Output] = []
    try:
        for plan in plans:
            claimed.append(_claim_one(plan, stamp))
    except BaseException:
        for out in reversed(claimed):
            out.discard()
        raise
    return claimed


@contextmanager
def atomic_path(target: str | os.PathLike[str], *, replace: bool = True,
                what: str = "output") -> Iterator[Path]:
    """A fresh temporary path beside ``target``: whatever the block writes there is synced
    and renamed onto ``target`` when the block ends normally, and removed on every other
    exit (an exception, a signal's exception, a full disk).

    The one helper every output that is not a :class:`Claimed` partial file goes through
    (sweep tables, exports).  ``replace=False``: an existing ``target`` is never replaced
    (the final name is taken with a hard link, which fails if it exists; ScenarioError).

    Raises
    ------
    OutputError
        the data could not be made durable (disk full, I/O error); ``target`` is untouched.
    ScenarioError
        ``replace=False`` and ``target`` exists.
    """
    target = Path(target)
    try:
        fd, name = tempfile.mkstemp(prefix=f".{target.name[:120]}.", suffix=".tmp",
                                    dir=target.parent)
    except OSError as exc:
        raise OutputError(f"{what} {display(target)}: cannot create a file in "
                          f"{display(target.parent)} ({exc.strerror or exc})") from None
    try:  # the mode a new file would have (mkstemp's is 0600), or the replaced file's
        os.fchmod(fd, stat.S_IMODE(os.stat(target).st_mode) if target.exists()
                  else 0o666 & ~_umask())
    except OSError:
        pass
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        try:
            fd = os.open(tmp, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            if replace:
                os.replace(tmp, target)
            else:
                try:
                    os.link(tmp, target)
                except FileExistsError:
                    raise ScenarioError(f"{what} {display(target)}: exists; choose another "
                                        f"path (nothing is overwritten)") from None
                except OSError as exc:
                    if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP):
                        raise
                    if target.exists():
                        raise ScenarioError(f"{what} {display(target)}: exists; choose "
                                            f"another path (nothing is overwritten)") from None
                    os.rename(tmp, target)
        except OSError as exc:
            raise OutputError(f"{what} {display(target)}: could not be completed "
                              f"({exc.strerror or exc}); nothing was replaced") from None
        _sync_directory(target.parent)
    finally:
        try:
            os.unlink(tmp)
        except OSError:
            pass


def _umask() -> int:
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    return 0o022


def write_atomic(target: str | os.PathLike[str], write: Callable[[Path], object], *,
                 replace: bool = True, what: str = "output") -> Path:
    """``write(tmp)`` writes the data to a temporary path, then :func:`atomic_path` puts it
    in place; an ``OSError`` of ``write`` (disk full) is an :class:`OutputError`."""
    target = Path(target)
    with atomic_path(target, replace=replace, what=what) as tmp:
        try:
            write(tmp)
        except OSError as exc:
            raise OutputError(f"{what} {display(target)}: could not be completed "
                              f"({exc.strerror or exc}); nothing was replaced") from None
    return target


def display(path: Path | str) -> str:
    """A path as the user would type it: relative to the working directory when below it."""
    p = Path(path)
    try:
        return str(p.relative_to(Path.cwd()))
    except ValueError:
        return str(p)
