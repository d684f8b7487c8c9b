"""The SITL autopilot's run directory: the vehicle's truth log, streamed and staged like
a run's (``config.toml``, ``robot.urdf``, ``robot.xml``, ``log.csv`` + ``meta.json``, then
``summary.json`` with the events: modes, failsafes, what it said; and the MAVLink
messages it read, by type, commands by id as ``COMMAND_LONG:400``). A SITL killed
outright leaves its staging directory (``DIR.partial-<pid>``) with the rows so far.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from aeromanip.experiment.closed_loop import run_meta
from aeromanip.experiment.logwriter import LogWriter
from aeromanip.experiment.rundir import RunDirectory
from aeromanip.experiment.runlog import LOG_FILE, RunLog, write_summary
from aeromanip.experiment.runner import write_static_files
from aeromanip.experiment.scenario import Scenario
from aeromanip.interrupts import RunInterrupted, deferred, interruptible
from aeromanip.interrupts import clear as clear_interrupts
from aeromanip.mavlink.sitl import STATE_HZ, SitlAutopilot


def run_sitl(
    sc: Scenario,
    link: str,
    out: Path,
    max_time_s: float | None = None,
    state_hz: float = STATE_HZ,
) -> tuple[dict[str, Any], RunInterrupted | None]:
    """Serve ``sc``'s vehicle on ``link`` until ``max_time_s`` [s] or a signal; return the
    truth summary and the signal (if one stopped it)."""
    sitl = SitlAutopilot(sc, link, state_hz)
    stopped: RunInterrupted | None = None
    with deferred(), RunDirectory(out) as rd:  # a signal after the run waits
        meta = run_meta(sc) | {"sim": "sitl", "link": link}
        try:
            with interruptible():
                write_static_files(sc, rd.staging)
                with LogWriter(rd.staging, sitl.columns(), meta) as writer:
                    sitl.run(writer.write, max_time_s)
        except RunInterrupted as e:
            stopped = e
            clear_interrupts()
        finally:
            sitl.close()
        summary: dict[str, Any] = {"scenario": sc.name, "sim": "sitl", "link": link}
        if (rd.staging / LOG_FILE).is_file() and len(log := RunLog.load(rd.staging)):
            summary |= log.summary()
        summary.update(
            interrupted=stopped is not None,
            sitl_time_s=sitl.t,
            overruns=sitl.overruns,
            received=dict(sorted(sitl.received.items())),
            events=[{"t": e.t, "text": e.text} for e in sitl.vehicle.events],
        )
        write_summary(rd.staging, summary)
        rd.commit()
    return summary, stopped
