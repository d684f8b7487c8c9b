"""Runs of scenarios into run directories that are streamed, complete, or kept as flown.

A run directory holds (DESIGN.md contract): ``config.toml`` (the resolved scenario),
``robot.urdf``, ``robot.xml`` (the MJCF model), ``log.csv`` (+ ``meta.json``) streamed
as the run goes, ``summary.json`` and ``figures/*.png``. A scenario with variants writes
``DIR/<variant>/`` each plus ``DIR/summary.json`` and comparison figures. Everything is
staged beside ``DIR`` and moved into place at the end (``experiment.rundir``). A run
stopped by a signal or by a write the operating system refused (disk full, permission,
read-only, I/O error) keeps the rows it flew, its summary says why (``"interrupted"``,
``"stopped_by"``), and the caller gets the cause in ``RunResult``.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomli_w

from aeromanip.errors import AeromanipError, describe_os_error
from aeromanip.experiment.closed_loop import fly, log_columns, make_simulator, run_meta
from aeromanip.experiment.logwriter import LogWriter
from aeromanip.experiment.plots import plot_comparison, plot_run
from aeromanip.experiment.rundir import RunDirectory
from aeromanip.experiment.runlog import (
    LOG_FILE,
    SUMMARY_FILE,
    RunLog,
    motion_share,
    read_summary,
    write_summary,
)
from aeromanip.experiment.scenario import MAX_BOUND_VIOLATION, Scenario
from aeromanip.interrupts import RunInterrupted, deferred, interruptible
from aeromanip.interrupts import clear as clear_interrupts
from aeromanip.robot.urdf_export import robot_to_urdf
from aeromanip.sim.mjcf import robot_to_mjcf


@dataclass
class RunResult:
    """What ``run_scenarios`` produced: each variant's summary and where it lies."""

    summaries: dict[str, dict[str, Any]] = field(default_factory=dict)
    out_dir: Path | None = None
    interrupted: RunInterrupted | None = None
    io_error: OSError | None = None  # a write refused: the run stopped there
    error: AeromanipError | None = None  # a fault it could not fly on: stopped there


def write_static_files(sc: Scenario, out_dir: Path) -> None:
    """``config.toml``, ``robot.urdf`` and ``robot.xml`` (the MJCF: what physics flies
    and replays render)."""
    (out_dir / "config.toml").write_text(tomli_w.dumps(_toml_safe(sc.resolved)))
    (out_dir / "robot.urdf").write_text(robot_to_urdf(sc.robot))
    # physics: the model flown, with its rotor count and rates
    xml = make_simulator(sc).to_xml() if sc.sim == "physics" else robot_to_mjcf(sc.robot)
    (out_dir / "robot.xml").write_text(xml)


def summarize(sc: Scenario, log: RunLog, interrupted: bool = False) -> dict[str, Any]:
    """The run's metrics (``RunLog.summary``) plus what identifies it."""
    summary = log.summary()
    if (phases := sc.reference.motion_phases()) is not None:  # who carries each phase (Fig. 3)
        summary["phases"] = [
            {"t0_s": t0, "t1_s": t1}
            | {
                f"{k}_share": v
                for k, v in motion_share(log, t0, t1, direction).items()
                if k in ("arm", "platform")
            }
            for t0, t1, direction in phases
        ]
    summary.update(
        scenario=sc.name,
        strategy=sc.strategy,
        backend=sc.backend,
        sim=sc.sim,
        duration_s=sc.duration,
        steps_planned=sc.steps,
        interrupted=interrupted,
    )
    summary.update(verdict(summary, sc.max_failure_ratio, sc.max_bound_violation))
    return summary


def verdict(
    summary: dict[str, Any],
    max_failure_ratio: float,
    max_bound_violation: float = MAX_BOUND_VIOLATION,
) -> dict[str, Any]:
    """Did the run fly? Not if any step stopped the robot, if more than
    ``max_failure_ratio`` of its steps failed (fell back on the last plan or stopped), or
    if its state left a bound by more than ``max_bound_violation`` [m, rad].
    Returns ``flight_ok`` and, when not, ``flight_problem`` (one line)."""
    counts = summary.get("steps_by_status", {})
    steps = max(int(summary.get("steps", 0)), 1)
    stopped = int(counts.get("stopped", 0))
    failed = stopped + int(counts.get("fallback", 0))
    problem = ""
    if stopped:
        problem = f"{stopped} of {steps} steps stopped the robot (no valid plan left)"
    elif failed / steps > max_failure_ratio:
        problem = (
            f"{failed} of {steps} steps failed ({failed / steps:.1%} > "
            f"max_failure_ratio {max_failure_ratio:g})"
        )
    elif float(summary.get("max_bound_violation", 0.0)) > max_bound_violation:
        problem = (
            f"{summary.get('max_bound_violation_column')} left its bound by "
            f"{summary['max_bound_violation']:.3g} (> max_bound_violation "
            f"{max_bound_violation:g})"
        )
    return {
        "flight_ok": not problem,
        "flight_problem": problem,
        "max_failure_ratio": max_failure_ratio,
    }


def _toml_safe(v: Any) -> Any:
    """Drop ``None`` values (TOML has no null); everything else tomli_w writes as is."""
    if isinstance(v, dict):
        return {k: _toml_safe(x) for k, x in v.items() if x is not None}
    if isinstance(v, list | tuple):
        return [_toml_safe(x) for x in v]
    return v


def run_one(
    sc: Scenario, out_dir: Path, progress: bool = True, figures: bool = True
) -> dict[str, Any]:
    """Fly ``sc`` into ``out_dir`` (streamed), then summarise and draw it; return the
    summary. On an interrupt, a refused write or a fault (an ``AeromanipError``) the
    summary (``"interrupted"``, ``"stopped_by"``) is written from the rows on disk, then
    the error is raised again."""
    out_dir.mkdir(parents=True, exist_ok=True)
    try:
        write_static_files(sc, out_dir)
        sim = make_simulator(sc)
        with LogWriter(out_dir, log_columns(sc, sim), run_meta(sc)) as writer:
            fly(sc, writer.write, progress=progress, sim=sim)
        with deferred():  # flown: its summary is written before a signal is acted on
            log = RunLog.load(out_dir)
            summary = summarize(sc, log)
            write_summary(out_dir, summary)
    except RunInterrupted as e:
        with deferred():
            _write_stopped_summary(sc, out_dir, str(e), interrupted=True)
        raise
    except OSError as e:
        with deferred():
            why = describe_os_error(e, root=str(out_dir))
            _write_stopped_summary(sc, out_dir, why, interrupted=False)
        raise
    except AeromanipError as e:  # a fault it cannot fly on (e.g. a state not finite)
        with deferred():
            _write_stopped_summary(sc, out_dir, str(e), interrupted=False)
        raise
    if figures:
        plot_run(log, out_dir / "figures")
    return summary


def _write_stopped_summary(sc: Scenario, out_dir: Path, why: str, interrupted: bool) -> None:
    """The summary of what a stopped run flew (nothing, if it stopped before), saying why;
    not written if the disk refuses it too (the rows on disk are what was flown)."""
    summary = {"scenario": sc.name, "steps": 0, "steps_planned": sc.steps}
    if (out_dir / LOG_FILE).is_file():
        with contextlib.suppress(AeromanipError, OSError):  # e.g. cut before its first row
            summary = summarize(sc, RunLog.load(out_dir), interrupted=interrupted)
    summary.update(interrupted=interrupted, stopped_by=why)
    try:
        write_summary(out_dir, summary)
    except OSError:  # the disk refuses it too: no half-written summary left
        with contextlib.suppress(OSError):
            (out_dir / SUMMARY_FILE).unlink(missing_ok=True)


def run_scenarios(
    scenarios: dict[str, Scenario], out_dir: Path, progress: bool = True, figures: bool = True
) -> RunResult:
    """Run every variant into ``out_dir`` (``out_dir/<variant>`` when there are several),
    staged beside it and moved into place at the end, even when interrupted or stopped
    by a refused write or a fault (then the cause is in ``RunResult.interrupted`` /
    ``io_error`` / ``error``, for the caller to act on; ``out_dir`` is where the run lies,
    the staging directory if it could not be moved into place)."""
    result = RunResult()
    try:
        with deferred(), RunDirectory(out_dir) as rd:  # a signal after the flight waits
            _fly_variants(result, scenarios, rd.staging, progress, figures)
            _commit(result, scenarios, rd)  # what was flown is written and moved whole
    except RunInterrupted as e:
        if result.out_dir is None:  # it came before the run directory was made
            raise
        result.interrupted = result.interrupted or e  # the run is in place all the same
        clear_interrupts()
    return result


def _fly_variants(
    result: RunResult, scenarios: dict[str, Scenario], staging: Path, progress: bool, figures: bool
) -> None:
    """Fly every variant into ``staging``; a signal, a refused write or a fault stops it
    there, recorded in ``result``."""
    try:
        with interruptible():
            for variant, sc in scenarios.items():
                summary = run_one(sc, _variant_dir(staging, variant), progress, figures)
                result.summaries[variant] = summary
            if figures and len(scenarios) > 1:
                logs = {v: RunLog.load(staging / v) for v in scenarios}
                plot_comparison(logs, staging / "figures")
    except RunInterrupted as e:
        result.interrupted = e
        clear_interrupts()  # handled here: the run is kept, the caller decides
    except OSError as e:
        result.io_error = e
    except AeromanipError as e:
        result.error = e


def _commit(result: RunResult, scenarios: dict[str, Scenario], rd: RunDirectory) -> None:
    """Summaries side by side (variants), then the staged run moved into place (or left
    where it is, said in ``result``, if the disk refuses)."""
    _read_stopped_summaries(result, scenarios, rd.staging)
    try:
        if len(scenarios) > 1:  # every variant's summary side by side
            top = {**result.summaries, "interrupted": result.interrupted is not None}
            write_summary(rd.staging, top)
        result.out_dir = rd.commit()
    except OSError as e:
        result.io_error = result.io_error or e
        result.out_dir = rd.left_behind


def _read_stopped_summaries(result: RunResult, scenarios: dict, staging: Path) -> None:
    """The summary of the variant a stop cut short (on disk, if it could be written)."""
    for variant in scenarios:
        d = _variant_dir(staging, variant)
        if variant in result.summaries:
            continue
        with contextlib.suppress(OSError, ValueError):
            if (d / SUMMARY_FILE).is_file():
                result.summaries[variant] = read_summary(d)
        with contextlib.suppress(OSError, ValueError):
            if variant not in result.summaries and (d / LOG_FILE).is_file():
                result.summaries[variant] = {"steps": len(RunLog.load(d))}  # no summary: rows


def _variant_dir(root: Path, variant: str) -> Path:
    return root / variant if variant else root
