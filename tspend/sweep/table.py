"""The sweep's table on disk: a Parquet file plus a journal of rows not yet in it.

Rows arrive one by one as runs finish.  Each is appended as one JSON line to
``PATH.journal`` (next to ``PATH``) and flushed, so a sweep killed at any moment keeps
every finished row; a line cut short by the kill is ignored when read.  Every
``compact_every`` seconds, and when the sweep ends, the journal is folded into ``PATH``:
the whole table is written to a temporary file that then replaces ``PATH`` atomically
(less often for a table so big that rewriting it would cost over 5% of the time),
and only after that is the journal removed.  So ``PATH`` is always a complete, readable
Parquet file, and :func:`read_table` (file + journal) always has every finished row,
once: a row is identified by its ``run_key``.

One sweep at a time writes a table: :class:`TableLock` (an advisory ``flock`` on
``PATH.lock``, which names the holder's pid) is held from before the table is read
until the journal is folded in, so a second sweep on the same table is refused (or
waits).  The journal is opened without following symbolic links, must be a regular file
with one name, and starts with a header naming its table, so a sweep never appends to a
file it does not own; a file at ``PATH`` that is not a tspend sweep table (even one of 0
rows) is never replaced.

JSON keeps floats exactly (Python writes the shortest text that reads back to the
same double), so rows are bit for bit the ones the workers produced.
"""

from __future__ import annotations

import errno
import json
import os
import stat
import time
from pathlib import Path
from typing import Any

try:
    import fcntl
except ImportError:  # Windows: no advisory locks
    fcntl = None  # type: ignore[assignment]

from tspend.runtime.errors import ScenarioError
from tspend.sweep.worker import METRIC_COLUMNS

NUMERIC_COLUMNS = METRIC_COLUMNS + ("job_s",)

#: the row identity that resuming and de-duplicating go by
KEY_COLUMN = "run_key"
#: the first line of a journal: which table it belongs to
HEADER_KEY = "tspend_journal"
#: a journal larger than this is not read (a sweep folds it in every few seconds)
MAX_JOURNAL_BYTES = 2_000_000_000


def journal_path(path: Path) -> Path:
    return path.with_name(path.name + ".journal")


def lock_path(path: Path) -> Path:
    return path.with_name(path.name + ".lock")


def _open_nofollow(path: Path, flags: int, what: str) -> int | None:
    """Open ``path`` without following a symbolic link; None if it does not exist.

    A symlink, a file with more than one name, or anything but a regular file is refused:
    a sweep writes only files it owns.
    """
    try:
        fd = os.open(path, flags | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0), 0o644)
    except FileNotFoundError:
        return None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise ScenarioError(f"{path}: the {what} is a symbolic link; a sweep writes only "
                                f"its table's own file (remove the link)") from None
        raise ScenarioError(f"{path}: cannot open the {what}: {exc.strerror or exc}") from None
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode) or st.st_nlink > 1:
        os.close(fd)
        why = "is not a regular file" if not stat.S_ISREG(st.st_mode) else \
            "has another name too (a hard link)"
        raise ScenarioError(f"{path}: the {what} {why}; a sweep writes only its table's own "
                            f"file")
    return fd


def _scalar(value: Any) -> bool:
    return value is None or isinstance(value, (str, int, float, bool))


def _read_journal(path: Path, table_name: str | None = None) -> list[dict[str, Any]]:
    """The rows of a journal; a line cut short by a kill is skipped, anything else that is
    not a row of a tspend journal is a ScenarioError (the file is left as it is)."""
    fd = _open_nofollow(path, os.O_RDONLY, "journal")
    if fd is None:
        return []
    with os.fdopen(fd, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        if size > MAX_JOURNAL_BYTES:
            raise ScenarioError(f"{path}: the journal is {size} bytes, more than "
                                f"{MAX_JOURNAL_BYTES}; not a sweep's journal")
        data = f.read()
    rows: list[dict[str, Any]] = []
    header = None
    for number, raw in enumerate(data.split(b"\n"), 1):
        if not raw.strip():
            continue
        try:
            row = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError, RecursionError, ValueError):
            continue  # the line being written when the sweep was killed
        if isinstance(row, dict) and HEADER_KEY in row and len(row) == 1:
            header = row[HEADER_KEY]
            if table_name is not None and header != table_name:
                raise ScenarioError(f"{path}: the journal of table {str(header)[:100]!r}, not "
                                    f"of {table_name!r}; move it aside or choose another --out")
            continue
        if not (isinstance(row, dict) and isinstance(row.get(KEY_COLUMN), str)
                and all(isinstance(k, str) and _scalar(v) for k, v in row.items())):
            raise ScenarioError(f"{path}: line {number} is not a row of a sweep journal; "
                                f"the journal is corrupt (move it aside to start afresh)")
        rows.append(row)
    if data.strip() and header is None and not rows:
        raise ScenarioError(f"{path}: not a tspend sweep journal; move it aside or choose "
                            f"another --out")
    return rows


def _check_schema(frame, path: Path) -> None:
    if KEY_COLUMN not in frame.columns:
        raise ScenarioError(f"{path}: not a tspend sweep table (no '{KEY_COLUMN}' column); "
                            f"it is left as it is: choose another --out")


def read_table(path: str | os.PathLike[str]):
    """Every finished row of the sweep table at ``path`` (its file and journal), once each,
    as a pandas DataFrame (empty if there is nothing yet).

    Raises
    ------
    ScenarioError
        ``path`` is not a tspend sweep table (another Parquet schema, even with 0 rows, or
        not Parquet), or its journal is a symlink, corrupt, or another table's.
    """
    import pandas as pd

    path = Path(path)
    frames = []
    if path.exists():
        if not path.is_file():
            raise ScenarioError(f"{path}: not a file; choose another --out")
        try:
            frames.append(pd.read_parquet(path))
        except Exception as exc:
            raise ScenarioError(f"{path}: not a readable Parquet table "
                                f"({' '.join(str(exc).split())[:200]})") from None
        _check_schema(frames[0], path)
    journal = _read_journal(journal_path(path), path.name)
    if journal:
        frames.append(pd.DataFrame.from_records(journal))
    frames = [f for f in frames if len(f)]
    if not frames:
        return pd.DataFrame()
    table = pd.concat(frames, ignore_index=True) if len(frames) > 1 else frames[0]
    return typed(table.drop_duplicates(KEY_COLUMN, keep="first").reset_index(drop=True))


def typed(table):
    """Metric columns as numbers: a column of failed runs alone would hold None objects."""
    import pandas as pd

    for column in NUMERIC_COLUMNS:
        if column in table.columns:
            table[column] = pd.to_numeric(table[column], errors="coerce")
    return table


class TableLock:
    """The advisory lock of a sweep table (``PATH.lock``, holding the holder's pid).

    :meth:`acquire` refuses with ScenarioError naming the holder, or waits for it
    (``wait``); :meth:`release` removes the lock file.  A lock file left by a killed sweep
    holds no lock (the kernel drops it with the process) and is taken over.
    """

    def __init__(self, table: Path) -> None:
        self.table = Path(table)
        self.path = lock_path(self.table)
        self._fd: int | None = None

    def holder(self) -> str:
        try:
            with open(self.path, encoding="utf-8", errors="replace") as f:
                text = f.read(40).strip()
        except OSError:
            text = ""
        return f"pid {text}" if text.isdigit() else "another process"

    def acquire(self, wait: bool = False, stop=None, poll_s: float = 0.2) -> "TableLock":
        while True:
            fd = _open_nofollow(self.path, os.O_RDWR | os.O_CREAT, "lock file")
            taken = True
            if fcntl is not None:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:
                    taken = False
                except OSError:
                    pass  # a file system without locks
            if taken:
                # the file may have been removed by its last holder between open and lock
                try:
                    same = os.stat(self.path, follow_symlinks=False).st_ino == os.fstat(fd).st_ino
                except FileNotFoundError:
                    same = False
                if same:
                    os.ftruncate(fd, 0)
                    os.write(fd, f"{os.getpid()}\n".encode())
                    self._fd = fd
                    return self
                os.close(fd)
                continue
            os.close(fd)
            if not wait:
                raise ScenarioError(f"--out {self.table}: another sweep ({self.holder()}) is "
                                    f"writing this table; wait for it to end, or pass --wait")
            if stop is not None and getattr(stop, "signal_name", None) is not None:
                from tspend.loop.runner import RunInterrupted

                raise RunInterrupted(stop.signal_name, stop.exit_status)
            time.sleep(poll_s)

    def release(self) -> None:
        fd, self._fd = self._fd, None
        if fd is None:
            return
        try:
            os.unlink(self.path)  # while still holding the lock: the next holder re-checks
        except OSError:
            pass
        os.close(fd)

    def __enter__(self) -> "TableLock":
        return self

    def __exit__(self, *exc) -> None:
        self.release()


class RowTable:
    """Appends rows to the journal of ``path`` and folds them into the Parquet file.

    Use under a held :class:`TableLock` of the same table.
    """

    def __init__(self, path: Path, compact_every: float = 10.0) -> None:
        self.path = Path(path)
        self.journal = journal_path(self.path)
        self.compact_every = compact_every
        self._last_compact = time.monotonic()
        self._interval = compact_every
        self._fd: int | None = None

    def check_writable(self) -> None:
        if not str(self.path).strip() or self.path.name in ("", ".", ".."):
            raise ScenarioError(f"--out {str(self.path)!r}: not a file name")
        parent = self.path.parent
        if self.path.is_dir():
            raise ScenarioError(f"--out {self.path}: is a directory")
        if self.path.exists() and not self.path.is_file():
            raise ScenarioError(f"--out {self.path}: not a regular file")
        if self.path.suffix.lower() != ".parquet":
            raise ScenarioError(f"--out {self.path}: a sweep table's name must end in .parquet "
                                f"(so that no other kind of file is ever replaced)")
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ScenarioError(f"--out {self.path}: cannot create directory {parent}: "
                                f"{exc.strerror or exc}") from None
        if not os.access(parent, os.W_OK):
            raise ScenarioError(f"--out {self.path}: directory {parent} is not writable")

    def append(self, row: dict[str, Any]) -> None:
        if self._fd is None:
            self._fd = _open_nofollow(self.journal, os.O_WRONLY | os.O_APPEND | os.O_CREAT,
                                      "journal")
            if os.fstat(self._fd).st_size == 0:
                self._write(json.dumps({HEADER_KEY: self.path.name}) + "\n")
            else:
                self._write("\n")  # a line cut short by a kill stays on its own line
        self._write(json.dumps(row) + "\n")
        if time.monotonic() - self._last_compact >= self._interval:
            self.compact()

    def _write(self, text: str) -> None:
        view = memoryview(text.encode())
        while view:
            view = view[os.write(self._fd, view):]

    def compact(self, order: dict[str, int] | None = None) -> None:
        """Fold the journal into the Parquet file (rows of ``order`` sorted by it)."""
        from tspend.runtime.outputs import write_atomic

        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
        started = self._last_compact = time.monotonic()
        if not os.path.lexists(self.journal):
            return
        import pandas as pd

        table = read_table(self.path)
        if order and len(table):
            rank = table[KEY_COLUMN].map(order)
            known = rank.notna()
            ranked = table[known].assign(_rank=rank[known]).sort_values("_rank")
            table = pd.concat([table[~known], ranked.drop(columns="_rank")], ignore_index=True)
        if len(table):
            write_atomic(self.path, lambda tmp: table.to_parquet(tmp, index=False),
                         what="sweep table")
        # only now is every journal row safely in the file
        self.journal.unlink(missing_ok=True)
        # a big table takes a while to rewrite: keep that under 5% of the sweep's time
        self._interval = max(self.compact_every, 20.0 * (time.monotonic() - started))

    def close(self, order: dict[str, int] | None = None) -> None:
        self.compact(order)
