"""A campaign's tables: ``results.csv`` (one row per run) and ``failed.json``.

``results.csv`` columns: ``run_id, status, error`` (``done`` or ``failed`` and the error in
one line), the swept keys (their values as ``--set`` writes them), ``elapsed_s`` (the
run's wall time in its worker) and ``cache_built`` (C libraries the run's worker compiled:
0 when the driver compiled the problem first), then every entry of the run's
``summary.json``, nested ones flattened with dots (``levels.0.cost_mean``). A run of the
campaign that has neither finished nor failed (an interrupted campaign) has no row yet.
``failed.json`` maps each failed run's id to its swept values, overrides and error.
Both files are replaced whole (written aside, then moved), never left half-written.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from aeromanip.errors import ConfigError
from aeromanip.experiment.runlog import SUMMARY_FILE
from aeromanip.sweep.axes import Run, toml_value
from aeromanip.sweep.tasks import DONE, FAILED, TASK_FILE, complete

RESULTS_FILE = "results.csv"
FAILED_FILE = "failed.json"
RUNS_DIR = "runs"
FIXED_COLUMNS = ("run_id", "status", "error")
TASK_COLUMNS = ("elapsed_s", "cache_built")


def flatten(value: Any, prefix: str = "") -> dict[str, Any]:
    """Nested tables and lists as one level: ``{"a": {"b": 1}, "c": [2]}`` ->
    ``{"a.b": 1, "c.0": 2}``."""
    if isinstance(value, Mapping):
        items: Iterable[tuple[Any, Any]] = value.items()
    elif isinstance(value, list | tuple):
        items = enumerate(value)
    else:
        return {prefix: value}
    out: dict[str, Any] = {}
    for k, v in items:
        out.update(flatten(v, f"{prefix}.{k}" if prefix else str(k)))
    return out


def cell(value: Any) -> str:
    """A value as a CSV cell: strings as they are, numbers and the rest as TOML writes
    them, ``None`` and NaN empty."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    if isinstance(value, str):
        return value
    if isinstance(value, float):
        return repr(value)
    return toml_value(value)


def run_row(run: Run, runs_dir: Path, error: str | None) -> dict[str, Any] | None:
    """The row of one run: from its directory if complete, else its error (``None``:
    neither finished nor failed yet)."""
    run_dir = runs_dir / run.run_id
    row: dict[str, Any] = {"run_id": run.run_id}
    if complete(run_dir):
        summary = json.loads((run_dir / SUMMARY_FILE).read_text())
        task = _task_record(run_dir)
        row.update(status=DONE, error="", **run.values)
        row.update({k: task.get(k) for k in TASK_COLUMNS})
        row.update(flatten(summary))
        return row
    if error is None:
        return None
    return row | {"status": FAILED, "error": error, **run.values}


def _task_record(run_dir: Path) -> dict[str, Any]:
    try:
        data = json.loads((run_dir / TASK_FILE).read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def columns_of(rows: list[dict[str, Any]], keys: list[str]) -> list[str]:
    """The table's columns: fixed, swept keys, task columns, then metrics as they come."""
    cols = [*FIXED_COLUMNS, *keys, *TASK_COLUMNS]
    seen = set(cols)
    for row in rows:
        for k in row:
            if k not in seen:
                seen.add(k)
                cols.append(k)
    return cols


def _replace(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}")
    tmp.write_text(text)
    os.replace(tmp, path)


def write_results(path: Path, rows: list[dict[str, Any]], keys: list[str]) -> Path:
    """Write ``results.csv`` (replaced whole)."""
    cols = columns_of(rows, keys)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for row in rows:
        w.writerow([cell(row.get(c)) for c in cols])
    _replace(path, buf.getvalue())
    return path


def read_results(path: Path) -> list[dict[str, str]]:
    """The rows of a ``results.csv`` (cells as text)."""
    try:
        with path.open(newline="") as fh:
            return list(csv.DictReader(fh))
    except OSError as e:
        raise ConfigError(f"{path}: cannot read: {e.strerror}") from None
    except csv.Error as e:
        raise ConfigError(f"{path}: malformed CSV: {e}") from None


def number(text: str | None) -> float:
    """A cell as a float (NaN if empty or not a number; ``true`` / ``false`` as 1 / 0)."""
    if text in ("true", "false"):
        return float(text == "true")
    try:
        return float(text) if text else math.nan
    except ValueError:
        return math.nan


def write_failed(path: Path, runs: list[Run], errors: Mapping[str, str]) -> Path | None:
    """Write ``failed.json`` for the failed runs of ``runs`` (removed if there are none)."""
    failed = {
        r.run_id: {
            "values": r.values,
            "overrides": list(r.overrides),
            "variant": r.variant,
            "error": errors[r.run_id],
        }
        for r in runs
        if r.run_id in errors
    }
    if not failed:
        path.unlink(missing_ok=True)
        return None
    _replace(path, json.dumps(failed, indent=2, default=str) + "\n")
    return path
