"""Stopping a run on SIGINT (Ctrl-C) or SIGTERM, wherever the signal lands.

Python raises ``KeyboardInterrupt`` where the main thread runs Python code, but a signal
that lands inside a CasADi solve is caught by CasADi, which ends the solve as a failure
(IPOPT: ``KeyboardInterruptException``) and carries on: a controller would fall back and
the run would go on. ``stop_on_signals()`` installs handlers that remember the signal and
raise ``RunInterrupted`` (a ``KeyboardInterrupt``), except inside ``deferred()`` blocks
(solver calls, moving a run directory into place), where the signal is only remembered
and raised when the block ends: the solve finishes (IPOPT: a few milliseconds) and the
stop is never mistaken for a solver failure.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from types import FrameType
from typing import Any

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class RunInterrupted(KeyboardInterrupt):
    """A run stopped by a signal; ``signum`` is the signal, ``exit_code`` 128 + it."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        self.exit_code = 128 + int(signum)  # the shell's convention: 130, 143
        super().__init__(signal.Signals(signum).name)


_pending: list[int] = []  # the signals received and not yet raised
_deferring: list[bool] = []  # non-empty inside ``deferred()`` blocks


def _handler(signum: int, frame: FrameType | None) -> None:
    _pending.append(signum)
    if not _deferring:
        raise RunInterrupted(signum)


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """A block a signal does not break: it is raised when the block ends."""
    _deferring.append(True)
    try:
        yield
    finally:
        _deferring.pop()
    raise_if_interrupted()


@contextlib.contextmanager
def interruptible() -> Iterator[None]:
    """Within ``deferred()`` blocks, a block a signal stops at once again (one that came
    since the deferral began stops it as it starts). Wrap the work that may be cut short
    in it and its ``except RunInterrupted`` outside it: a signal anywhere after the block
    is then remembered, not raised between the handler and the code that keeps the run."""
    saved = _deferring[:]
    _deferring.clear()
    try:
        raise_if_interrupted()
        yield
    finally:
        _deferring.extend(saved)


def interrupted() -> int | None:
    """The signal received, if any (until ``clear()``)."""
    return _pending[0] if _pending else None


def raise_if_interrupted() -> None:
    """Raise ``RunInterrupted`` if a signal arrived (e.g. while C code held the thread)."""
    if _pending:
        raise RunInterrupted(_pending[0])


def clear() -> None:
    """Forget received signals (a new run starts)."""
    _pending.clear()


@contextlib.contextmanager
def stop_on_signals(keep: bool = False) -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM raise ``RunInterrupted`` (main thread only;
    elsewhere the block changes nothing). The previous handlers are restored after, or,
    with ``keep`` (a process about to exit: its last file is written), signals are
    ignored from then on: a Python handler would be reset to the default while the
    interpreter shuts down, and a signal then would kill the process without a word."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    clear()
    previous = {s: signal.signal(s, _handler) for s in SIGNALS}
    previous_hook, sys.unraisablehook = sys.unraisablehook, _quiet_unraisable(sys.unraisablehook)
    try:
        yield
    finally:
        sys.unraisablehook = previous_hook
        for s, h in previous.items():
            signal.signal(s, signal.SIG_IGN if keep else h)


def _quiet_unraisable(hook: Callable[[Any], None]) -> Callable[[Any], None]:
    """``sys.unraisablehook`` that says nothing of a ``RunInterrupted`` raised where
    Python cannot raise (a weakref callback, a ``__del__``): the signal stays pending and
    is raised at the next check (``raise_if_interrupted``, the end of ``deferred()``)."""

    def quiet(unraisable: Any) -> None:
        if not isinstance(unraisable.exc_value, RunInterrupted):
            hook(unraisable)

    return quiet
