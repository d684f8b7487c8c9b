"""SIGINT and SIGTERM at random moments of ``aeromanip run``, from the first line of
``main`` to the last file written (real processes: a signal needs one).

Moments (seeded): up to 0.5 s after ``main`` installed its handlers (start-up, scenario
loading, the solver's build), up to 0.3 s after the first row is on disk, and up to
1.5 s after the run's summary is staged (figures, the move into place, ``run.mcap``).
Each case checks: an exit within ``EXIT_WITHIN_S``, exit 128 + the signal with one line
on stderr (or 0 with the run complete, when the signal came after the last file), no
traceback, and every row on disk counted in the summary and in the line (no row lost,
no staging directory left).
"""

from __future__ import annotations

import json
import os
import random
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from aeromanip.experiment.runlog import RunLog

EXIT_WITHIN_S = 5.0  # [s] from the signal to the end of the process (a loaded machine)
START_TIMEOUT_S = 120.0  # [s] until the moment to signal comes
VARIANT = "hierarchical"


def handlers_installed(pid: int) -> bool:
    """``main`` has run its first line: the process catches SIGTERM (``/proc`` status)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    m = re.search(r"^SigCgt:\s*([0-9a-f]+)$", status, re.MULTILINE)
    return bool(m) and bool(int(m[1], 16) >> (signal.SIGTERM - 1) & 1)


def summary_staged(out: Path) -> bool:
    """The run flew and its summary is written; the rest of its outputs follow."""
    return bool(list(out.parent.glob(f"{out.name}.partial-*/{VARIANT}/summary.json")))


def wait_for(p: subprocess.Popen, ready, what: str) -> bool:
    """Wait until ``ready()``; False if the process ended first."""
    deadline = time.monotonic() + START_TIMEOUT_S
    while not ready():
        if p.poll() is not None:
            return False
        assert time.monotonic() < deadline, f"no {what} after {START_TIMEOUT_S:g} s"
        time.sleep(0.002)
    return True


def check_outcome(rc: int, err: str, out_text: str, out: Path, sig: signal.Signals) -> str:
    """The contract after the signal; returns which way the run ended."""
    assert "Traceback" not in err + out_text, err
    assert not list(out.parent.glob(f"{out.name}.partial-*")), "staging directory left"
    lines = err.strip().splitlines()
    if rc == 0:  # the signal came after the last file was written
        assert not lines, err
        log = RunLog.load(out / VARIANT)
        assert json.loads((out / VARIANT / "summary.json").read_text())["steps"] == len(log)
        return "completed"
    assert rc == 128 + sig, f"exit {rc} after {sig.name}: {err!r}"
    assert len(lines) == 1 and lines[0].startswith(f"aeromanip: interrupted ({sig.name})"), err
    m = re.search(r"(\d+) of (\d+) steps flown, kept in (.+)$", lines[0])
    if m is None:  # stopped before the run directory, or while writing its exports
        if "the run is complete in" in lines[0]:
            return "exports"
        assert not out.exists(), f"{out} exists, the line does not say so: {lines[0]}"
        return "before"
    run = Path(m[3]) / VARIANT
    rows = len(RunLog.load(run)) if (run / "log.csv").is_file() else 0
    summary = json.loads((run / "summary.json").read_text())
    assert rows == int(m[1]) == summary["steps"], (rows, lines[0], summary.get("steps"))
    if rows == summary["steps_planned"]:  # stopped after the flight, while drawing
        return "after-flight"
    assert summary["interrupted"] is True
    return "flying"


MOMENTS = {"start": 0.5, "flying": 0.3, "end": 1.5}  # [s] longest wait after the moment
CASES = [
    (backend, sig, moment, k)
    for backend in ("ipopt", "sqp", "sqp-rti")
    for moment in MOMENTS
    for k, sig in enumerate((signal.SIGINT, signal.SIGTERM))
]


def moment_came(moment: str, p: subprocess.Popen, out: Path) -> bool:
    """``start``: main's handlers are in; ``flying``: a row is on disk; ``end``: the
    summary is staged."""
    if moment == "start":
        return handlers_installed(p.pid)
    if moment == "flying":
        logs = out.parent.glob(f"{out.name}.partial-*/{VARIANT}/log.csv")
        return any(log.read_bytes().count(b"\n") >= 2 for log in logs)
    return summary_staged(out)


@pytest.mark.parametrize(("backend", "sig", "moment", "k"), CASES)
def test_a_signal_at_a_random_moment_is_one_line_and_loses_nothing(
    backend, sig, moment, k, tmp_path
):
    rng = random.Random(f"{backend}-{sig.name}-{moment}-{k}")
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "aeromanip.cli", "run", "waypoints", "--variant", VARIANT]
    cmd += ["--set", f"controller.backend={backend}", "--set", "duration=2"]
    cmd += ["--quiet", "--out", str(out)]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    with (tmp_path / "stdout").open("w") as so, (tmp_path / "stderr").open("w") as se:
        p = subprocess.Popen(cmd, cwd=tmp_path, stdout=so, stderr=se, env=env)
        try:
            if wait_for(p, lambda: moment_came(moment, p, out), moment):
                time.sleep(rng.uniform(0.0, MOMENTS[moment]))
                t0 = time.monotonic()
                p.send_signal(sig)
                p.wait(timeout=60)
                assert time.monotonic() - t0 < EXIT_WITHIN_S, "slow to stop"
            else:
                p.wait(timeout=60)
        finally:
            if p.poll() is None:
                p.kill()
                p.wait()
    err, text = (tmp_path / "stderr").read_text(), (tmp_path / "stdout").read_text()
    ended = check_outcome(p.returncode, err, text, out, sig)
    print(f"{backend} {sig.name} {moment}: exit {p.returncode}, {ended}")
