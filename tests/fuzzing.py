"""What the command-line fuzz tests share: hypothesis' settings, and a watchdog that turns
a hang of an in-process call into an error."""

import contextlib
import signal
from collections.abc import Iterator

from hypothesis import HealthCheck, settings

# hypothesis' own deadline is per example and flaky on a loaded machine: the watchdog
# bounds each call instead. No database: nothing is written outside tmp.
# function_scoped_fixture: `tmp_path` and `capsys` are shared by the examples on purpose;
# each example writes into its own fresh sub-directory and reads (and so clears) capsys.
FUZZ = settings(
    derandomize=True,
    database=None,
    deadline=None,
    print_blob=False,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)


class CallTimedOut(BaseException):
    """Raised by the watchdog in a call that took too long (a hang)."""


@contextlib.contextmanager
def watchdog(limit_s: float) -> Iterator[None]:
    """Raise ``CallTimedOut`` in the block after ``limit_s`` seconds (main thread)."""

    def fire(signum: int, frame: object) -> None:
        raise CallTimedOut(f"still running after {limit_s:g} s")

    previous = signal.signal(signal.SIGALRM, fire)
    signal.setitimer(signal.ITIMER_REAL, limit_s)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
