"""Runs of scenarios into run directories that are streamed, complete, or kept as flown.

A run directory holds (DESIGN.md contract): ``config.toml`` (the resolved scenario),
``robot.urdf``, ``robot.xml`` (the MJCF model), ``log.csv`` (+ ``meta.json``) streamed
as the run goes, ``summary.json`` and ``figures/*.png``. A scenario with variants writes
``DIR/<variant>/`` each plus ``DIR/summary.json`` and comparison figures. Everything is
staged beside ``DIR`` and moved into place at the end (``experiment.rundir``). A run
stopped by a signal keeps the rows it flew, its summary says ``"interrupted": true``,
and the interrupt is raised again for the caller.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomli_w

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
from aeromanip.interrupts import RunInterrupted, deferred
from aeromanip.interrupts import clear as clear_interrupts
from aeromanip.robot.urdf_export import robot_to_urdf
from aeromanip.sim.mjcf import robot_to_mjcf


@dataclass
class RunResult:
    """What ``run_scenarios`` produced: each variant's summary and where it lies."""

    summaries: dict[str, dict[str, Any]] = field(default_factory=dict)
    out_dir: Path | None = None
    interrupted: RunInterrupted | None = None


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
    summary. On an interrupt the summary (``"interrupted": true``) is written from the
    rows on disk, then the interrupt is raised again."""
    out_dir.mkdir(parents=True, exist_ok=True)
    try:
        write_static_files(sc, out_dir)
        sim = make_simulator(sc)
        with LogWriter(out_dir, log_columns(sc, sim), run_meta(sc)) as writer:
            fly(sc, writer.write, progress=progress, sim=sim)
    except RunInterrupted:
        with deferred():
            write_summary(out_dir, _interrupted_summary(sc, out_dir))
        raise
    log = RunLog.load(out_dir)
    summary = summarize(sc, log)
    write_summary(out_dir, summary)
    if figures:
        plot_run(log, out_dir / "figures")
    return summary


def _interrupted_summary(sc: Scenario, out_dir: Path) -> dict[str, Any]:
    """The summary of what an interrupted run flew (nothing, if it stopped before)."""
    if (out_dir / LOG_FILE).is_file():
        return summarize(sc, RunLog.load(out_dir), interrupted=True)
    return {"scenario": sc.name, "steps": 0, "steps_planned": sc.steps, "interrupted": True}


def run_scenarios(
    scenarios: dict[str, Scenario], out_dir: Path, progress: bool = True, figures: bool = True
) -> RunResult:
    """Run every variant into ``out_dir`` (``out_dir/<variant>`` when there are several),
    staged beside it and moved into place at the end, even when interrupted (then the
    interrupt is in ``RunResult.interrupted``, for the caller to act on)."""
    result = RunResult()
    with RunDirectory(out_dir) as rd:
        try:
            for variant, sc in scenarios.items():
                summary = run_one(sc, _variant_dir(rd.staging, variant), progress, figures)
                result.summaries[variant] = summary
            if figures and len(scenarios) > 1:
                logs = {v: RunLog.load(rd.staging / v) for v in scenarios}
                plot_comparison(logs, rd.staging / "figures")
        except RunInterrupted as e:
            result.interrupted = e
            clear_interrupts()  # handled here: the run is kept, the caller decides
            for variant in scenarios:  # the one it stopped (its summary is on disk)
                d = _variant_dir(rd.staging, variant)
                if variant not in result.summaries and (d / SUMMARY_FILE).is_file():
                    result.summaries[variant] = read_summary(d)
        with deferred():  # what was flown is written and moved into place whole
            if len(scenarios) > 1:  # every variant's summary side by side
                top = {**result.summaries, "interrupted": result.interrupted is not None}
                write_summary(rd.staging, top)
            result.out_dir = rd.commit()
    return result


def _variant_dir(root: Path, variant: str) -> Path:
    return root / variant if variant else root
