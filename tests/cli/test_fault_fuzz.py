"""Fuzzing the command line where it meets the operating system and the network.

The rule under test: every fault ends in ONE line on stderr naming the cause, a documented
exit code (``aeromanip.errors.ExitCode``), no traceback, no hang, no silent exit 0, and
what was flown kept on disk. Generated here (hypothesis, derandomized, no database):

* ``fly`` / ``sitl`` on links that cannot open: a loopback port in use, a loopback port
  where nobody listens, unknown host names, serial without pyserial, malformed URLs:
  refused before anything is built (the flight and the physics are never constructed);
* ``sitl --max-time``, ``replay --speed`` / ``--out`` / damaged runs, ``sweep --address``
  on loopback listeners that are not Ray (silent, echoing, closing) or nobody;
* runs whose writes the operating system refuses (an injected ``OSError``: ENOSPC,
  EDQUOT, EPERM, EACCES, EROFS, EIO) after a random number of bytes: exit 5, every row
  the writer accepted readable, the summary saying why it stopped.

Signals at random moments (real processes) are in ``test_fault_signals.py``. Network
traffic stays on 127.0.0.1; every listener is closed by its fixture.
"""

from __future__ import annotations

import contextlib
import errno
import importlib.util
import json
import os
import re
import signal
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import aeromanip.experiment.logwriter as logwriter
from aeromanip.cli import main
from aeromanip.errors import ExitCode
from aeromanip.experiment.runlog import RunLog

FUZZ = settings(
    derandomize=True,
    database=None,
    deadline=None,
    print_blob=False,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
CALL_LIMIT_S = 20.0  # [s] one refused command (normally < 0.1 s; a probe times out in 5)
RUN_LIMIT_S = 120.0  # [s] one short run with a refused write (normally ~1 s)


class CallTimedOut(BaseException):
    """Raised by the watchdog in a call that took too long (a hang)."""


@contextlib.contextmanager
def watchdog(limit_s: float) -> Iterator[None]:
    def fire(signum: int, frame: object) -> None:
        raise CallTimedOut(f"still running after {limit_s:g} s")

    previous = signal.signal(signal.SIGALRM, fire)
    signal.setitimer(signal.ITIMER_REAL, limit_s)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def call(argv: list[str], capsys: Any, limit_s: float = CALL_LIMIT_S) -> tuple[int, str, str]:
    """``main(argv)`` in-process: (exit code, stdout, stderr); a hang or an escaping
    exception fails the test, naming the argv."""
    capsys.readouterr()
    try:
        with watchdog(limit_s):
            rc = main(argv)
    except CallTimedOut as e:
        raise AssertionError(f"hang: {e}\nargv: {argv!r}") from None
    except BaseException as e:
        raise AssertionError(f"{type(e).__name__} escaped main: {e}\nargv: {argv!r}") from e
    out, err = capsys.readouterr()
    return rc, out, err


def assert_one_line(err: str, codes: set[int], rc: int, argv: list[str]) -> str:
    """One stderr line starting ``aeromanip: error: ``, exit code among ``codes``."""
    what = f"argv: {argv!r}\nstderr: {err!r}"
    assert rc in codes, f"exit {rc}, expected one of {sorted(codes)}\n{what}"
    assert "Traceback" not in err, what
    lines = err.strip().splitlines()
    assert len(lines) == 1, f"{len(lines)} stderr lines\n{what}"
    assert lines[0].startswith("aeromanip: error: "), what
    return lines[0]


# ------------------------------------------------------------------ links that cannot open


@pytest.fixture
def busy_udp_port() -> Iterator[int]:
    """A loopback UDP port held by the test (another program listens there)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        yield s.getsockname()[1]


@pytest.fixture
def free_tcp_port() -> int:
    """A loopback TCP port nobody listens on (bound, then closed)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def nothing_built(monkeypatch: pytest.MonkeyPatch) -> None:
    """Building the real-time flight or the SITL's physics fails the test."""

    def built(*args: object, **kwargs: object) -> None:
        raise AssertionError("built before the link was opened")

    monkeypatch.setattr("aeromanip.runtime.loop.RealtimeFlight", built)
    monkeypatch.setattr("aeromanip.mavlink.sitl.PhysicsSimulator.from_options", built)


HOSTS = st.sampled_from(("nosuch.invalid", "a.b.c.invalid", "x-y.invalid", "::1", "256.1.1.1"))


def bad_links(busy: int, free: int) -> st.SearchStrategy[tuple[str, set[int]]]:
    """(link URL, exit codes allowed): opening each fails."""
    loop = ("udpin", "udp")
    return st.one_of(
        st.sampled_from(loop).map(lambda s: (f"{s}:127.0.0.1:{busy}", {ExitCode.LINK})),
        st.just((f"tcp:127.0.0.1:{free}", {ExitCode.LINK})),
        st.tuples(st.sampled_from(("udpout", "tcp", "udpin")), HOSTS).map(
            lambda sh: (f"{sh[0]}:{sh[1]}:14540", {ExitCode.LINK})
        ),
        st.sampled_from(("/dev/ttyUSB9", "/dev/nosuch")).map(
            lambda d: (f"serial:{d}:57600", {ExitCode.BAD_INPUT, ExitCode.LINK})
        ),
        st.sampled_from(("udpin:", "tcp:127.0.0.1", "udp:h:0", "serial:x", "x:1:2", "tcp::1")).map(
            lambda u: (u, {ExitCode.BAD_INPUT})
        ),
    )


@settings(FUZZ, max_examples=120)
@given(data=st.data(), command=st.sampled_from(("fly", "sitl")))
def test_links_that_cannot_open_are_one_line_before_anything_is_built(
    data, command, busy_udp_port, free_tcp_port, nothing_built, tmp_path, capsys
):
    link, codes = data.draw(bad_links(busy_udp_port, free_tcp_port))
    out = tmp_path / "out"
    argv = [command, "planar", "--variant", "cond-off", "--link", link, "--out", str(out)]
    t0 = time.monotonic()
    rc, _, err = call(argv, capsys)
    line = assert_one_line(err, codes, rc, argv)
    assert "--link" in line, line
    assert time.monotonic() - t0 < 10.0, f"took {time.monotonic() - t0:.1f} s: {argv}"
    assert not out.exists(), f"{out} created for a link that did not open: {argv}"


def test_serial_without_pyserial_says_how_to_install_it(nothing_built, tmp_path, capsys):
    if importlib.util.find_spec("serial") is not None:
        pytest.skip("pyserial is installed")
    argv = ["sitl", "planar", "--variant", "cond-off", "--link", "serial:/dev/ttyUSB0:57600"]
    rc, _, err = call(argv, capsys)
    assert "pip install pyserial" in assert_one_line(err, {ExitCode.BAD_INPUT}, rc, argv)
