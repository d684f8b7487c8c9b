"""One run of a campaign, as a Ray task runs it: a scenario flown into ``DIR/runs/<id>/``.

The run is built exactly as ``aeromanip run SCENARIO --set ...`` builds it
(``expand_variants`` then ``build_scenario``, from the scenario table the driver read, so
a worker needs no scenario file) and flown by ``run_scenarios`` into its directory, which
thus holds the whole run-output contract. A run that raises is reported as failed with
its error in one line, not raised: Ray retries only tasks whose worker died. A retried
run first removes what its dead predecessor left staged.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from aeromanip.errors import ConfigError
from aeromanip.experiment.runlog import SUMMARY_FILE
from aeromanip.experiment.runner import run_scenarios
from aeromanip.experiment.scenario import Scenario, build_scenario
from aeromanip.experiment.sources import expand_variants

TASK_FILE = "task.json"  # in a run directory: how and where the campaign ran it
DONE, FAILED = "done", "failed"  # a run's status in results.csv


@dataclass(frozen=True)
class RunTask:
    """What a worker needs to fly one run (small, picklable)."""

    run_id: str
    data: dict[str, Any]  # the scenario's table (extends resolved), before any override
    base_dir: str  # where its relative file names are anchored
    overrides: tuple[str, ...]  # --set texts
    variant: str | None
    run_dir: str  # DIR/runs/<id>
    figures: bool = True


def build_run(
    data: dict[str, Any], base_dir: Path, overrides: tuple[str, ...], variant: str | None
) -> Scenario:
    """The run's scenario, built by the path ``aeromanip run --set`` takes (no flying)."""
    tables = expand_variants(data, list(overrides), variant)
    (name, table), *rest = tables.items()
    if rest:  # the campaign always picks a variant of a scenario that has some
        raise ConfigError(f"{len(tables)} variants: a run flies one (got variant {variant!r})")
    return build_scenario(table, Path(base_dir), name)


def one_line(e: BaseException) -> str:
    """An exception as one line: its type and message."""
    text = f"{type(e).__name__}: {e}".replace("\r", " ").replace("\n", " | ")
    return text.rstrip(": ")


_BUILDS = {"hooked": 0, "count": 0}  # compilers of shared libraries this process started


def _count_builds(event: str, args: tuple[Any, ...]) -> None:
    """Audit hook: count each compiler started to build a shared library (``-shared``)."""
    if event == "subprocess.Popen" and isinstance(args[1], list | tuple) and "-shared" in args[1]:
        _BUILDS["count"] += 1


def libraries_built() -> int:
    """How many C libraries this process has compiled so far, counted from the compilers
    it started (an audit hook, installed on the first call): exact, whatever other
    processes add to the same cache meanwhile."""
    if not _BUILDS["hooked"]:
        sys.addaudithook(_count_builds)
        _BUILDS["hooked"] = 1
    return _BUILDS["count"]


def complete(run_dir: Path) -> bool:
    """Whether ``run_dir`` holds a finished run: a readable summary, neither interrupted
    nor stopped (by a refused write or a fault)."""
    try:
        summary = json.loads((run_dir / SUMMARY_FILE).read_text())
    except (OSError, ValueError):
        return False
    if not isinstance(summary, dict) or "steps" not in summary:
        return False
    return not summary.get("interrupted") and "stopped_by" not in summary


def clear_leftovers(run_dir: Path) -> None:
    """Remove what a dead attempt of this run left staged (``<id>.partial-<pid>``), unless
    a live process holds the run's lock."""
    lock = run_dir.with_name(f"{run_dir.name}.lock")
    if lock.exists():
        with lock.open("a") as fh:
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return  # being written now: not ours to clean
            fcntl.flock(fh, fcntl.LOCK_UN)
    for stale in run_dir.parent.glob(f"{run_dir.name}.partial-*"):
        shutil.rmtree(stale, ignore_errors=True)


def execute(task: RunTask) -> dict[str, Any]:
    """Fly one run into ``task.run_dir``; return its status, error and timing (never
    raises for a failing run: the error is the result)."""
    t0 = time.perf_counter()
    before = libraries_built()
    out: dict[str, Any] = {"run_id": task.run_id, "pid": os.getpid(), "host": socket.gethostname()}
    run_dir = Path(task.run_dir)
    try:
        sc = build_run(task.data, Path(task.base_dir), task.overrides, task.variant)
        run_dir.parent.mkdir(parents=True, exist_ok=True)
        clear_leftovers(run_dir)
        result = run_scenarios({"": sc}, run_dir, progress=False, figures=task.figures)
        if result.interrupted is not None:
            out.update(status=FAILED, error=f"interrupted ({result.interrupted})")
        elif (stop := result.io_error or result.error) is not None:  # kept, not complete
            out.update(status=FAILED, error=one_line(stop))
        else:
            out.update(status=DONE, error="")
    except Exception as e:  # a failing run is a result: recorded, the campaign goes on
        out.update(status=FAILED, error=one_line(e))
    out.update(
        elapsed_s=round(time.perf_counter() - t0, 3),
        cache_built=libraries_built() - before,
    )
    if out["status"] == DONE:
        (run_dir / TASK_FILE).write_text(json.dumps(out, indent=2) + "\n")
    return out
