"""``log.csv`` written as the run goes: a row per control step, each handed to the operating
system as it is logged (line-buffered), so a crash loses at most the row being written.

The columns are fixed before the first row (a CSV has one header): a row may leave some
out (written as empty text or ``nan``), never add one. The format is ``RunLog.save``'s,
so ``RunLog.load`` reads a streamed log, even one cut short by a crash, exactly.
``meta.json`` is written when the log opens. A write the operating system refuses (disk
full, permission, read-only, I/O error) closes the log and raises ``OutputError``: the rows
before it stay readable (a last row cut short is dropped by ``RunLog.load``).
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, TextIO

from aeromanip.errors import ConfigError, OutputError
from aeromanip.experiment.runlog import LOG_FILE, META_FILE, TEXT_COLUMNS, jsonable


class LogWriter:
    """Streams rows to ``out_dir/log.csv``; use as a context manager (closes the file).

    Args:
        out_dir: the run directory (created if needed).
        columns: every column, in order.
        meta: the run's metadata (``meta.json``).
    """

    def __init__(
        self,
        out_dir: Path,
        columns: Sequence[str],
        meta: Mapping[str, Any] | None = None,
    ) -> None:
        if len(set(columns)) != len(columns):
            raise ConfigError(f"log: duplicate columns in {list(columns)}")
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / META_FILE).write_text(json.dumps(jsonable(dict(meta or {})), indent=2) + "\n")
        self.path = out_dir / LOG_FILE
        self.columns = list(columns)
        self._known = set(self.columns)
        self._file = open_stream(self.path)
        self._csv = csv.writer(self._file, lineterminator="\n")
        self.rows = 0
        self._guarded(self.columns)

    def write(self, row: Mapping[str, Any]) -> None:
        """Append one row (missing columns empty or ``nan``)."""
        extra = set(row) - self._known
        if extra:
            raise ConfigError(f"log: row has columns not in the header: {sorted(extra)}")
        self._guarded([_cell(c, row.get(c)) for c in self.columns])
        self.rows += 1

    def _guarded(self, cells: list[str]) -> None:
        """Write one line; a refused write closes the log and raises ``OutputError``."""
        try:
            self._csv.writerow(cells)
        except OSError as e:
            self._abandon()
            raise OutputError(e.errno, e.strerror, str(self.path)) from None

    def _abandon(self) -> None:
        """Close after a failed write (what the buffer still holds is lost: one row)."""
        with contextlib.suppress(OSError):
            self._file.close()

    def close(self) -> None:
        """Flush and close (idempotent)."""
        if not self._file.closed:
            try:
                self._file.flush()
            except OSError as e:
                self._abandon()
                raise OutputError(e.errno, e.strerror, str(self.path)) from None
            self._file.close()

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def open_stream(path: Path) -> TextIO:
    """``path`` opened for the log: text, line-buffered (each row handed to the OS)."""
    return path.open("w", newline="", buffering=1)


def _cell(column: str, value: Any) -> str:
    """A value as ``RunLog.save`` writes it: text as is, numbers by ``repr`` of a float."""
    if column in TEXT_COLUMNS:
        return "" if value is None else str(value)
    if value is None:
        return repr(math.nan)
    if isinstance(value, str):
        return value
    return repr(float(value))
