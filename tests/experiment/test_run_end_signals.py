"""A signal in the moments between a run's flight and its move into place keeps the run.

The signal is sent to this process (real delivery, ``os.kill``) at moments chosen by
wrapping the steps of ``run_scenarios``: the flight itself is a stand-in that stages a
summary, since what is checked is the bookkeeping around it. A signal that the handler
raised between the flight's ``except`` and the commit used to leave the staging
directory ``DIR.partial-<pid>`` behind (seen once in a full run of the random-moment
test in ``tests/cli/test_fault_signals.py``).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import threading
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace

import pytest

from aeromanip import interrupts
from aeromanip.experiment import runner
from aeromanip.interrupts import RunInterrupted, deferred, interruptible, stop_on_signals

pytestmark = pytest.mark.skipif(
    threading.current_thread() is not threading.main_thread(),
    reason="signal handlers run in the main thread only",
)


def signal_self(sig: signal.Signals = signal.SIGINT) -> None:
    """Deliver ``sig`` to this process now (its handler runs before the next line)."""
    os.kill(os.getpid(), sig)


def test_a_signal_after_the_interruptible_block_waits_for_the_deferral_to_end():
    reached = []
    with stop_on_signals(), pytest.raises(RunInterrupted) as stopped, deferred():
        with interruptible():
            pass
        signal_self()
        reached.append("after the signal")
    assert reached == ["after the signal"]
    assert stopped.value.signum == signal.SIGINT


def test_a_signal_before_the_interruptible_block_stops_it_as_it_starts():
    with stop_on_signals(), deferred():
        signal_self(signal.SIGTERM)
        entered = []
        try:
            with interruptible():
                entered.append(True)
        except RunInterrupted as e:
            caught = e.signum
        interrupts.clear()
    assert entered == [] and caught == signal.SIGTERM


def test_a_signal_inside_the_interruptible_block_is_raised_where_it_lands():
    lines = []
    with stop_on_signals(), deferred():
        try:
            with interruptible():
                signal_self()
                lines.append("not reached")
        except RunInterrupted:
            lines.append("caught inside the deferral")
        interrupts.clear()
    assert lines == ["caught inside the deferral"]


def staged_flight(sc: SimpleNamespace, out_dir: Path, progress: bool, figures: bool) -> dict:
    """``run_one``'s stand-in: a summary of two steps, staged."""
    out_dir.mkdir(parents=True, exist_ok=True)
    summary = {"scenario": sc.name, "steps": 2}
    (out_dir / "summary.json").write_text(json.dumps(summary))
    return summary


def signalling_after_the_flight() -> contextlib.AbstractContextManager:
    @contextlib.contextmanager
    def block() -> Iterator[None]:
        with interruptible():
            yield
        signal_self()  # right after the flight's block, before the commit

    return block()


def commit_signalled(commit):
    def signalled(self):
        signal_self(signal.SIGTERM)  # while the run is moved into place
        return commit(self)

    return signalled


@pytest.mark.parametrize("moment", ["after the flight", "during the commit"])
def test_a_signal_at_the_end_of_a_run_keeps_it_in_place(tmp_path, monkeypatch, moment):
    monkeypatch.setattr(runner, "run_one", staged_flight)
    if moment == "after the flight":
        monkeypatch.setattr(runner, "interruptible", signalling_after_the_flight)
    else:
        commit = runner.RunDirectory.commit
        monkeypatch.setattr(runner.RunDirectory, "commit", commit_signalled(commit))
    out = tmp_path / "out"
    with stop_on_signals():
        result = runner.run_scenarios({"": SimpleNamespace(name="waypoints")}, out)
    assert result.interrupted is not None
    assert result.out_dir == out.absolute()
    assert json.loads((out / "summary.json").read_text())["steps"] == 2
    assert not list(tmp_path.glob("out.partial-*")), "staging directory left"
    assert not list(tmp_path.glob("out.lock"))
    assert interrupts.interrupted() is None  # handled: the caller decides
