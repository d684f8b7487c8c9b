"""``log.csv`` written as the run goes: a row per control step, each handed to the operating
system as it is logged (line-buffered), so a crash loses at most the row being written.

The columns are fixed before the first row (a CSV has one header): a row may leave some
out (written as empty text or ``nan``), never add one. The format is ``RunLog.save``'s,
so ``RunLog.load`` reads a streamed log, even one cut short by a crash, exactly.
``meta.json`` is written when the log opens.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

from aeromanip.errors import ConfigError
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
        self._file = self.path.open("w", newline="", buffering=1)  # line-buffered
        self._csv = csv.writer(self._file, lineterminator="\n")
        self._csv.writerow(self.columns)
        self.rows = 0

    def write(self, row: Mapping[str, Any]) -> None:
        """Append one row (missing columns empty or ``nan``)."""
        extra = set(row) - self._known
        if extra:
            raise ConfigError(f"log: row has columns not in the header: {sorted(extra)}")
        self._csv.writerow([_cell(c, row.get(c)) for c in self.columns])
        self.rows += 1

    def close(self) -> None:
        """Flush and close (idempotent)."""
        if not self._file.closed:
            self._file.flush()
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


def _cell(column: str, value: Any) -> str:
    """A value as ``RunLog.save`` writes it: text as is, numbers by ``repr`` of a float."""
    if column in TEXT_COLUMNS:
        return "" if value is None else str(value)
    if value is None:
        return repr(math.nan)
    if isinstance(value, str):
        return value
    return repr(float(value))
