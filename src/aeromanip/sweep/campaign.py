"""A campaign, start to end: the plan (``sweep.plan``: every run checked before Ray
starts), each distinct problem compiled once, the missing runs fanned out, everything
recorded as it comes.

``DIR`` holds ``sweep.json`` (the campaign: scenario, swept keys, figure settings; a
re-run into ``DIR`` must be of the same scenario), ``runs/<id>/`` (each run's output
contract, plus ``task.json``), ``results.csv``, ``failed.json`` and ``figures/``. A run
is done when its directory holds a complete ``summary.json``: re-running the command
runs only the others (failed ones included). A lock keeps two campaigns out of one DIR.

Compile once: before the fan-out the driver builds one controller per distinct problem
of the plan, which compiles its C code into the cache; the workers get the cache
directory (``AEROMANIP_CACHE``) and load the libraries from it.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from aeromanip.errors import ConfigError
from aeromanip.experiment.closed_loop import make_controller
from aeromanip.interrupts import RunInterrupted, deferred, interruptible
from aeromanip.interrupts import clear as clear_interrupts
from aeromanip.sweep.axes import Run
from aeromanip.sweep.campaign_plots import plot_sweep
from aeromanip.sweep.fanout import MAX_RETRIES, ProgressLine, fan_out, ray_session
from aeromanip.sweep.plan import Plan, scenario_hash
from aeromanip.sweep.results import (
    FAILED_FILE,
    RESULTS_FILE,
    RUNS_DIR,
    cell,
    read_results,
    run_row,
    write_failed,
    write_results,
)
from aeromanip.sweep.tasks import (
    DONE,
    FAILED,
    RunTask,
    build_run,
    complete,
    libraries_built,
    one_line,
)

CAMPAIGN_FILE = "sweep.json"
LOCK_FILE = "sweep.lock"
FIGURES_DIR = "figures"
SAVE_EVERY_S = 5.0  # [s] results.csv is rewritten at most this often during the fan-out
DEFAULT_PARETO = ("ee_rmse_m", "cog_xy_mean_m")
CACHE_ENV = "AEROMANIP_CACHE"  # where the codegen cache is (nmpc.backends.codegen)


@dataclass
class Settings:
    """How a campaign runs (``aeromanip sweep`` options)."""

    workers: int | None = None  # local Ray CPUs (default: all); with a cluster, a cap
    address: str | None = None  # join this Ray cluster
    max_retries: int = MAX_RETRIES
    figures: bool = True  # each run's figures (the campaign's are always drawn)
    cache_dir: Path | None = None  # the compile cache, passed to the workers
    quiet: bool = False
    pareto: tuple[str, str] | None = DEFAULT_PARETO
    metrics: tuple[str, ...] | None = None  # plotted metrics (default: those that vary)


@dataclass
class Outcome:
    """What a campaign did."""

    runs: int
    skipped: int  # complete before this invocation
    ran: int  # sent to Ray now
    done: int  # complete now
    errors: dict[str, str]  # failed run id -> error
    compiled: dict[str, Any]  # driver: problems, seconds, libraries built
    worker_built: int  # libraries the workers built (0: compiled once, before)
    wall_s: float
    results: Path | None = None
    figures: list[Path] = field(default_factory=list)
    interrupted: RunInterrupted | None = None
    figure_error: str = ""  # why the campaign's figures could not be drawn (e.g. --pareto)
    fanout_s: float = 0.0  # [s] from the first task submitted to the last result (Ray up)


def record(plan: Plan, settings: Settings) -> dict[str, Any]:
    """The content of ``sweep.json``."""
    spec = plan.spec
    return {
        "scenario": plan.scenario,
        "scenario_sha256": scenario_hash(plan.data),
        "keys": spec.keys,
        "set": list(spec.base),
        "replicate_key": spec.seed_key if spec.seeds else None,
        "pareto": list(settings.pareto) if settings.pareto else None,
        "metrics": list(settings.metrics) if settings.metrics else None,
        "runs": len(plan.runs),
    }


def read_record(out: Path) -> dict[str, Any] | None:
    """``DIR/sweep.json`` (``None`` if there is none)."""
    try:
        data = json.loads((out / CAMPAIGN_FILE).read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as e:
        raise ConfigError(f"{out / CAMPAIGN_FILE}: unreadable: {e}") from None
    return data if isinstance(data, dict) else None


def check_out(out: Path, plan: Plan) -> None:
    """``--out`` is new, empty, or a campaign of this very scenario."""
    old = read_record(out)
    if old is None:
        if out.is_dir() and any(out.iterdir()):
            raise ConfigError(f"--out: {out} is not empty and holds no sweep ({CAMPAIGN_FILE})")
        return
    if old.get("scenario_sha256") != scenario_hash(plan.data):
        raise ConfigError(
            f"--out: {out} holds a sweep of another scenario ({old.get('scenario')!r}, or "
            f"it changed since); use another --out"
        )


@contextlib.contextmanager
def campaign_lock(out: Path) -> Iterator[None]:
    """Hold ``DIR/sweep.lock`` (``ConfigError`` if another campaign holds it)."""
    out.mkdir(parents=True, exist_ok=True)
    fd = os.open(out / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise ConfigError(f"--out: {out} is being written by another sweep") from None
        yield
    finally:
        os.close(fd)


@contextlib.contextmanager
def _cache_env(cache_dir: Path | None) -> Iterator[None]:
    """``AEROMANIP_CACHE`` set to ``cache_dir`` (if given) for the block, then restored."""
    saved = os.environ.get(CACHE_ENV)
    if cache_dir is not None:
        os.environ[CACHE_ENV] = str(cache_dir)
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop(CACHE_ENV, None)
        else:
            os.environ[CACHE_ENV] = saved


def precompile(plan: Plan, todo: list[Run], cache_dir: Path | None) -> dict[str, Any]:
    """Build one controller per distinct problem of ``todo`` in the driver: the first
    build of a problem compiles its C code into ``cache_dir`` (the workers' cache;
    nothing is built if it is there)."""
    keys = list(dict.fromkeys(plan.problem_of[r.run_id] for r in todo))
    before, t0 = libraries_built(), time.perf_counter()
    failed = []
    for key in keys:
        try:
            run = plan.example[key]
            with _cache_env(cache_dir):
                make_controller(build_run(plan.data, plan.base_dir, run.overrides, run.variant))
        except Exception as e:  # its runs will fail in the workers, with their message
            failed.append(one_line(e))
    built = libraries_built() - before
    return {
        "problems": len(keys),
        "seconds": round(time.perf_counter() - t0, 2),
        "libraries_built": built,
        "failed": failed,
    }


def worker_env(cache_dir: Path | None) -> dict[str, str]:
    """Environment variables of the workers: the compile cache, the codegen switch and
    its optimisation level (the driver's builds are the workers' only with its flags)."""
    env = {CACHE_ENV: str(cache_dir)} if cache_dir else {}
    for name in ("AEROMANIP_CODEGEN", "AEROMANIP_CODEGEN_OPT"):
        if name in os.environ:
            env[name] = os.environ[name]
    return env


def run_campaign(plan: Plan, out: Path, settings: Settings) -> Outcome:
    """Run what is missing of ``plan`` into ``out``; write the tables and figures. A
    signal stops the fan-out: what finished is recorded, ``Outcome.interrupted`` says so."""
    t0, out = time.perf_counter(), Path(out)
    check_out(out, plan)
    with campaign_lock(out):
        (out / CAMPAIGN_FILE).write_text(json.dumps(record(plan, settings), indent=2) + "\n")
        runs_dir = out / RUNS_DIR
        rows = {r.run_id: row for r in plan.runs if (row := run_row(r, runs_dir, None))}
        todo = [r for r in plan.runs if r.run_id not in rows and r.run_id not in plan.invalid]
        outcome = Outcome(len(plan.runs), len(rows), len(todo), 0, dict(plan.invalid), {}, 0, 0.0)
        with deferred():  # a signal after the fan-out waits for the tables
            try:
                with interruptible():
                    if todo:
                        outcome.compiled = precompile(plan, todo, settings.cache_dir)
                        _fly(plan, todo, out, settings, rows, outcome)
            except RunInterrupted as e:
                outcome.interrupted = e
                clear_interrupts()  # handled: what finished is written below
            outcome.results = write_tables(plan, out, rows, outcome.errors)
        outcome.done = sum(1 for r in plan.runs if complete(runs_dir / r.run_id))
        try:
            outcome.figures = draw(out)
        except ConfigError as e:  # the results stand; the figures' settings were wrong
            outcome.figure_error = str(e)
    outcome.wall_s = round(time.perf_counter() - t0, 2)
    return outcome


def _fly(
    plan: Plan,
    todo: list[Run],
    out: Path,
    settings: Settings,
    rows: dict[str, dict[str, Any]],
    outcome: Outcome,
) -> None:
    """Fan ``todo`` out on Ray; record each result as it comes (tables saved now and then)."""
    runs_dir, cache = out / RUNS_DIR, settings.cache_dir
    by_id = {r.run_id: r for r in todo}
    tasks = [
        RunTask(
            run_id=r.run_id,
            data=plan.data,
            base_dir=str(plan.base_dir),
            overrides=r.overrides,
            variant=r.variant,
            run_dir=str(runs_dir / r.run_id),
            figures=settings.figures,
        )
        for r in todo
    ]
    progress = ProgressLine(len(tasks), settings.quiet)
    saved = [time.perf_counter()]

    def on_result(task: RunTask, result: dict[str, Any]) -> None:
        run = by_id[task.run_id]
        error = result.get("error") if result["status"] != DONE else None
        row = run_row(run, runs_dir, error)
        if row is None:  # reported done, but no complete summary on disk
            error = "the run reported done but left no complete summary.json"
            row = run_row(run, runs_dir, error)
        if error:
            outcome.errors[run.run_id] = error
        else:
            outcome.errors.pop(run.run_id, None)
        rows[run.run_id] = row
        outcome.worker_built += int(result.get("cache_built") or 0)
        progress.update(result | {"status": FAILED if error else DONE}, label(run))
        if time.perf_counter() - saved[0] > SAVE_EVERY_S:
            write_tables(plan, out, rows, outcome.errors)
            saved[0] = time.perf_counter()

    with ray_session(settings.address, settings.workers) as session:
        start = time.perf_counter()
        try:
            fan_out(
                tasks,
                on_result,
                session=session,
                env=worker_env(cache),
                max_retries=settings.max_retries,
            )
        finally:
            outcome.fanout_s = round(time.perf_counter() - start, 2)


def label(run: Run) -> str:
    """A run's swept values, ``key=value`` each."""
    return ", ".join(f"{k}={cell(v)}" for k, v in run.values.items())


def write_tables(
    plan: Plan, out: Path, rows: dict[str, dict[str, Any]], errors: dict[str, str]
) -> Path:
    """``results.csv`` (runs in the campaign's order) and ``failed.json``."""
    runs_dir = out / RUNS_DIR
    ordered = []
    for r in plan.runs:
        row = rows.get(r.run_id) or run_row(r, runs_dir, errors.get(r.run_id))
        if row is not None:
            ordered.append(row)
    write_failed(out / FAILED_FILE, plan.runs, errors)
    return write_results(out / RESULTS_FILE, ordered, plan.spec.keys)


def draw(out: Path) -> list[Path]:
    """The campaign's figures from ``DIR/results.csv`` and ``DIR/sweep.json``."""
    rec = read_record(out)
    if rec is None:
        raise ConfigError(f"{out}: no {CAMPAIGN_FILE}: not a sweep directory")
    pareto = rec.get("pareto")
    return plot_sweep(
        read_results(out / RESULTS_FILE),
        list(rec.get("keys") or []),
        out / FIGURES_DIR,
        metrics=rec.get("metrics"),
        pareto=tuple(pareto) if pareto else None,
        replicate_key=rec.get("replicate_key"),
    )
