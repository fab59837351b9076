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

JSON keeps floats exactly (Python writes the shortest text that reads back to the
same double), so rows are bit for bit the ones the workers produced.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

from tspend.errors import ScenarioError
from tspend.sweep.worker import METRIC_COLUMNS

NUMERIC_COLUMNS = METRIC_COLUMNS + ("job_s",)

#: the row identity that resuming and de-duplicating go by
KEY_COLUMN = "run_key"


def journal_path(path: Path) -> Path:
    return path.with_name(path.name + ".journal")


def _read_journal(path: Path) -> list[dict[str, Any]]:
    rows = []
    try:
        text = path.read_text()
    except FileNotFoundError:
        return rows
    for line in text.splitlines():
        try:
            row = json.loads(line)
        except json.JSONDecodeError:  # the line being written when the sweep was killed
            continue
        if isinstance(row, dict) and KEY_COLUMN in row:
            rows.append(row)
    return rows


def read_table(path: str | os.PathLike[str]):
    """Every finished row of the sweep table at ``path`` (its file and journal), once each,
    as a pandas DataFrame (empty if there is nothing yet)."""
    import pandas as pd

    path = Path(path)
    frames = []
    if path.exists():
        try:
            frames.append(pd.read_parquet(path))
        except Exception as exc:
            raise ScenarioError(f"{path}: not a readable Parquet table ({exc})") from None
        if len(frames[0]) and KEY_COLUMN not in frames[0].columns:
            raise ScenarioError(f"{path}: not a tspend sweep table (no '{KEY_COLUMN}' column); "
                                f"choose another --out")
    journal = _read_journal(journal_path(path))
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
            table[column] = pd.to_numeric(table[column])
    return table


class RowTable:
    """Appends rows to the journal of ``path`` and folds them into the Parquet file."""

    def __init__(self, path: Path, compact_every: float = 10.0) -> None:
        self.path = Path(path)
        self.journal = journal_path(self.path)
        self.compact_every = compact_every
        self._last_compact = time.monotonic()
        self._interval = compact_every
        self._file = None

    def check_writable(self) -> None:
        parent = self.path.parent
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ScenarioError(f"--out {self.path}: cannot create directory {parent}: "
                                f"{exc.strerror or exc}") from None
        if self.path.is_dir():
            raise ScenarioError(f"--out {self.path}: is a directory")
        if not os.access(parent, os.W_OK):
            raise ScenarioError(f"--out {self.path}: directory {parent} is not writable")

    def append(self, row: dict[str, Any]) -> None:
        if self._file is None:
            self._file = open(self.journal, "a", encoding="utf-8")
            if self._file.tell() > 0:
                self._file.write("\n")  # a line cut short by a kill stays on its own line
        self._file.write(json.dumps(row) + "\n")
        self._file.flush()
        if time.monotonic() - self._last_compact >= self._interval:
            self.compact()

    def compact(self, order: dict[str, int] | None = None) -> None:
        """Fold the journal into the Parquet file (rows of ``order`` sorted by it)."""
        if self._file is not None:
            self._file.close()
            self._file = None
        started = self._last_compact = time.monotonic()
        if not self.journal.exists():
            return
        import pandas as pd

        table = read_table(self.path)
        if order:
            rank = table[KEY_COLUMN].map(order)
            known = rank.notna()
            ranked = table[known].assign(_rank=rank[known]).sort_values("_rank")
            table = pd.concat([table[~known], ranked.drop(columns="_rank")], ignore_index=True)
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        table.to_parquet(tmp, index=False)
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, self.path)
        # only now is every journal row safely in the file
        self.journal.unlink(missing_ok=True)
        # a big table takes a while to rewrite: keep that under 5% of the sweep's time
        self._interval = max(self.compact_every, 20.0 * (time.monotonic() - started))

    def close(self, order: dict[str, int] | None = None) -> None:
        self.compact(order)
