"""A real-time flight into a run directory (the output contract), streamed and staged
like ``aeromanip run``'s (``experiment.rundir``): ``config.toml``, ``robot.urdf``,
``robot.xml``, ``log.csv`` + ``meta.json`` as it flies, then ``summary.json`` (with the
runtime's keys: deadline misses, setpoint rate, state age, link loss) and, when the
mission completed, ``figures/``. Whatever ends the flight (done, link lost, a signal),
what it flew is summarised and moved into place.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from aeromanip.errors import AeromanipError, describe_os_error
from aeromanip.experiment.closed_loop import log_columns, run_meta
from aeromanip.experiment.logwriter import LogWriter
from aeromanip.experiment.plots import plot_run
from aeromanip.experiment.rundir import RunDirectory
from aeromanip.experiment.runlog import LOG_FILE, RunLog, write_summary
from aeromanip.experiment.runner import summarize, write_static_files
from aeromanip.interrupts import RunInterrupted, deferred, interruptible
from aeromanip.interrupts import clear as clear_interrupts
from aeromanip.runtime.loop import RUNTIME_COLUMNS, RealtimeFlight
from aeromanip.runtime.transport import LinkError


class _NoSimulator:
    """The run log's columns need a simulator's extras: a vehicle reports none."""

    def extras(self) -> dict[str, float]:
        return {}


@dataclass
class SessionResult:
    """How a flight ended: its summary, where it lies, and what stopped it (if anything)."""

    summary: dict[str, Any]
    out_dir: Path
    error: LinkError | None = None
    interrupted: RunInterrupted | None = None
    io_error: OSError | None = None  # a write refused: the flight stopped there
    fault: AeromanipError | None = None  # a fault it could not fly on: stopped there


def fly_session(
    flight: RealtimeFlight, out: Path, link: str, figures: bool = True
) -> SessionResult:
    """Fly ``flight`` into run directory ``out``; ``link`` is recorded in the summary."""
    sc = flight.sc
    error, interrupted, io_error, fault = None, None, None, None
    with deferred(), RunDirectory(out) as rd:  # a signal after the flight waits
        columns = [*log_columns(sc, _NoSimulator()), *RUNTIME_COLUMNS]  # type: ignore[arg-type]
        meta = run_meta(sc) | {"sim": "vehicle", "link": link}
        try:
            with interruptible():
                write_static_files(sc, rd.staging)
                with LogWriter(rd.staging, columns, meta) as writer:
                    flight.fly(writer.write)
        except LinkError as e:
            error = e
        except RunInterrupted as e:
            interrupted = e
            clear_interrupts()
        except OSError as e:
            io_error = e
        except AeromanipError as e:  # e.g. a state not finite: the vehicle holding
            fault = e
        summary = _summary(flight, rd.staging, link, interrupted is not None)
        if error is not None:
            summary["error"] = str(error)
        if fault is not None:
            summary["stopped_by"] = str(fault)
        if io_error is not None:
            summary["stopped_by"] = describe_os_error(io_error, root=str(rd.staging))
            return SessionResult(summary, _keep(rd, summary), None, None, io_error)
        write_summary(rd.staging, summary)
        stopped = error is not None or interrupted is not None or fault is not None
        if figures and not stopped and summary["steps"]:
            plot_run(RunLog.load(rd.staging), rd.staging / "figures")
        out_dir = rd.commit()
    return SessionResult(summary, out_dir, error, interrupted, fault=fault)


def _keep(rd: RunDirectory, summary: dict[str, Any]) -> Path:
    """After a refused write: the summary if the disk takes it, the run moved into place
    if it can be; where the run lies."""
    with contextlib.suppress(OSError):
        write_summary(rd.staging, summary)
    try:
        return rd.commit()
    except OSError:
        return rd.staging


def _summary(flight: RealtimeFlight, d: Path, link: str, interrupted: bool) -> dict[str, Any]:
    sc = flight.sc
    if (d / LOG_FILE).is_file() and len(log := RunLog.load(d)):
        summary = summarize(sc, log, interrupted=interrupted)
    else:
        summary = {"scenario": sc.name, "steps": 0, "steps_planned": sc.steps}
        summary["interrupted"] = interrupted
    summary.update(flight.stats.summary(), sim="vehicle", link=link)
    return summary
