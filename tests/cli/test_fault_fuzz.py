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
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import aeromanip.experiment.logwriter as logwriter
from aeromanip.cli import main
from aeromanip.errors import ExitCode
from aeromanip.experiment.runlog import RunLog
from fuzzing import FUZZ, CallTimedOut, watchdog

CALL_LIMIT_S = 20.0  # [s] one refused command (normally < 0.1 s; a probe times out in 5)
RUN_LIMIT_S = 120.0  # [s] one short run with a refused write (normally ~1 s)


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


def planar_argv(out: Path, duration: float) -> list[str]:
    """``aeromanip run planar`` (its ``cond-off`` variant) for ``duration`` s into ``out``."""
    return ["run", "planar", "--variant", "cond-off", "--set", f"duration={duration:g}",
            "--quiet", "--no-mcap", "--out", str(out)]  # fmt: skip


def steps_kept(line: str, out: Path) -> tuple[int, Path]:
    """The steps a stop's line says were flown (the line naming ``out``) and the run."""
    m = re.search(r"; (\d+) of (\d+) steps flown, kept in (.+)$", line)
    assert m and Path(m[3]) == out.absolute(), line
    return int(m[1]), out / "cond-off" if (out / "cond-off").is_dir() else out


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


@settings(FUZZ, max_examples=160)
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


# ------------------------------------------------------------ options, outputs, addresses


@pytest.fixture(scope="module")
def saved_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A short run of ``planar`` on disk (flown once for the module)."""
    out = tmp_path_factory.mktemp("saved") / "run"
    argv = ["run", "planar", "--variant", "cond-off", "--set", "duration=0.3", "--quiet"]
    assert main([*argv, "--no-mcap", "--out", str(out)]) == 0
    return out / "cond-off" if (out / "cond-off").is_dir() else out


@contextlib.contextmanager
def listener(mode: str) -> Iterator[int]:
    """A loopback TCP listener that is not Ray: ``silent`` (accepts, says nothing),
    ``echo`` (sends back what it reads) or ``close`` (hangs up); its port."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        s.settimeout(10.0)

        def serve() -> None:
            with contextlib.suppress(OSError), s.accept()[0] as c:
                if mode == "echo":
                    c.sendall(c.recv(64))
                if mode != "close":
                    c.settimeout(10.0)
                    c.recv(1)  # until the client hangs up

        t = threading.Thread(target=serve, daemon=True)
        t.start()
        yield s.getsockname()[1]
    t.join(11.0)


def option_faults(run: Path, tmp: Path) -> st.SearchStrategy[list[str]]:
    """Command lines with one faulty option each (all refused before any real work)."""
    a_file = tmp / "a-file"
    a_file.write_text("x")
    floats = st.sampled_from((0.0, -1.0, float("inf"), float("-inf"), float("nan"), 1e-300))
    return st.one_of(
        floats.map(
            lambda x: ["sitl", "planar", "--link", "udpin:127.0.0.1:9", "--max-time", str(x)]
        ),
        st.sampled_from(("1e-300", "5e-324", "1e-12", "0", "-1", "inf", "nan", "1e308")).map(
            lambda x: ["replay", str(run), "--speed", x, "--out", str(tmp / "v.mp4")]
        ),
        st.sampled_from(
            ("/proc/x.mp4", "/proc/1/x.gif", f"{a_file}/x.mp4", f"{a_file}/d/x.png", str(tmp))
        ).map(lambda o: ["replay", str(run), "--out", o]),
        st.sampled_from(("--speed=x", "--fps", "--nosuch", "--size=0x0", "--quality=x")).map(
            lambda o: ["replay", str(run), o]
        ),
        st.tuples(st.sampled_from(("--metrics", "--pareto")), st.sampled_from(BAD_METRICS)).map(
            lambda om: [*SWEEP, "--out", str(tmp / "c"), om[0], f"{om[1]},ee_rmse_m"]
        ),
    )


SWEEP = ["sweep", "waypoints", "--variant", "hierarchical", "--grid", "duration=1,2", "--check"]
BAD_METRICS = ("nosuch", "ee_rmse", "EE_RMSE_M", "levels", "duration.x", " ", "run_id.0")


@settings(FUZZ, max_examples=90)
@given(data=st.data())
def test_faulty_options_and_outputs_are_one_line(data, saved_run, tmp_path, capsys):
    argv = data.draw(option_faults(saved_run, tmp_path))
    rc, _, err = call(argv, capsys)
    assert_one_line(err, {ExitCode.BAD_INPUT}, rc, argv)
    assert not list(tmp_path.glob("*.mp4")), argv


@pytest.mark.parametrize("damage", ["cut-short", "no-meta"])
def test_replay_of_a_damaged_run_says_what_is_wrong(damage, saved_run, tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    for f in saved_run.iterdir():
        if f.is_file():
            (run / f.name).write_bytes(f.read_bytes())
    if damage == "cut-short":
        text = (run / "log.csv").read_text()
        (run / "log.csv").write_text(text[: text.rindex("\n") - 3])
    else:
        (run / "meta.json").unlink()
    argv = ["replay", str(run), "--out", str(tmp_path / "still.png"), "--quiet"]
    rc, _, err = call(argv, capsys)
    line = assert_one_line(err, {ExitCode.BAD_INPUT}, rc, argv)
    assert ("cut short" if damage == "cut-short" else "no meta.json") in line
    assert (tmp_path / "still.png").is_file()  # what is whole is still rendered


@pytest.mark.parametrize("mode", ["silent", "echo", "close", "nobody"])
def test_sweep_address_that_is_not_ray_is_refused_in_bounded_time(mode, tmp_path, capsys):
    ctx = listener(mode) if mode != "nobody" else contextlib.nullcontext(_unused_port())
    with ctx as port:
        argv = ["sweep", "planar", "--grid", "tasks.cond.weight=1,2", "--out", str(tmp_path / "c")]
        argv += ["--address", f"127.0.0.1:{port}"]
        t0 = time.monotonic()
        rc, _, err = call(argv, capsys)
    line = assert_one_line(err, {ExitCode.BAD_INPUT}, rc, argv)
    assert "--address" in line and time.monotonic() - t0 < 8.0, line


def _unused_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_sweep_address_probe_accepts_a_grpc_peer():
    """A peer answering the HTTP/2 preface with SETTINGS (RFC 7540 3.5, as gRPC does)."""
    from aeromanip.sweep.fanout import check_ray

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()

        def serve() -> None:
            with s.accept()[0] as c:
                c.recv(24)
                c.sendall(b"\x00\x00\x00\x04\x00\x00\x00\x00\x00")

        t = threading.Thread(target=serve, daemon=True)
        t.start()
        check_ray(f"127.0.0.1:{s.getsockname()[1]}")
        t.join(5.0)


# ---------------------------------------------------------------- writes the OS refuses

REFUSALS = ("ENOSPC", "EDQUOT", "EPERM", "EACCES", "EROFS", "EIO")


class RefusingFile:
    """A log stream that writes through until ``budget`` characters, writes the part of
    the next write that fits, then refuses with ``OSError(code)`` (as a full disk does)."""

    def __init__(self, f: Any, budget: int, code: int) -> None:
        self.f, self.budget, self.code = f, budget, code

    def write(self, text: str) -> int:
        if len(text) > self.budget:
            self.f.write(text[: self.budget])
            self.f.flush()
            self.budget = 0
            raise OSError(self.code, os.strerror(self.code))
        self.budget -= len(text)
        return self.f.write(text)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.f, name)


@contextlib.contextmanager
def refusing_writes(budget: int, code: int) -> Iterator[list[logwriter.LogWriter]]:
    """Every log stream refuses after ``budget`` characters; yields the writers made."""
    made: list[logwriter.LogWriter] = []
    real_open, real_init = logwriter.open_stream, logwriter.LogWriter.__init__

    def init(self: logwriter.LogWriter, *args: Any, **kwargs: Any) -> None:
        made.append(self)
        real_init(self, *args, **kwargs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(logwriter, "open_stream", lambda p: RefusingFile(real_open(p), budget, code))
        mp.setattr(logwriter.LogWriter, "__init__", init)
        yield made


@settings(FUZZ, max_examples=36)
@given(refusal=st.sampled_from(REFUSALS), budget=st.integers(0, 3500))
def test_a_refused_write_stops_the_run_cleanly_and_loses_no_row(refusal, budget, tmp_path, capsys):
    out = Path(tmp_path) / f"run-{refusal}-{budget}"
    argv = planar_argv(out, 1.0)
    with refusing_writes(budget, getattr(errno, refusal)) as accepted:
        rc, _, err = call(argv, capsys, RUN_LIMIT_S)
    line = assert_one_line(err, {ExitCode.IO}, rc, argv)
    assert f"({refusal})" in line and "log.csv" in line, line
    flown, run = steps_kept(line, out)
    rows = len(RunLog.load(run)) if (run / "log.csv").stat().st_size else 0
    assert rows == accepted[0].rows == flown, (rows, accepted[0].rows, line)
    summary = json.loads((run / "summary.json").read_text())
    assert refusal in summary["stopped_by"] and summary["steps"] == rows
    assert not list(out.parent.glob(f"{out.name}.partial-*"))


@pytest.fixture
def small_tmpfs(tmp_path: Path) -> Iterator[Path]:
    """A 48 KiB tmpfs (skipped where mounting is not permitted, e.g. unprivileged CI)."""
    import shutil
    import subprocess

    mnt = tmp_path / "small"
    mnt.mkdir()
    if shutil.which("mount") is None:
        pytest.skip("no mount command")
    cmd = ["mount", "-t", "tmpfs", "-o", "size=48k", "tmpfs", str(mnt)]
    if subprocess.run(cmd, capture_output=True).returncode != 0:
        pytest.skip("mounting a tmpfs is not permitted here")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def test_a_full_filesystem_stops_the_run_cleanly(small_tmpfs, capsys):
    out = small_tmpfs / "run"
    argv = planar_argv(out, 20.0)
    rc, _, err = call(argv, capsys, RUN_LIMIT_S)
    line = assert_one_line(err, {ExitCode.IO}, rc, argv)
    assert "(ENOSPC)" in line, line
    flown, run = steps_kept(line, out)
    rows = len(RunLog.load(run)) if (run / "log.csv").is_file() else 0
    assert rows == flown and rows > 0, line
    if (run / "summary.json").is_file():  # when the disk still took it
        assert json.loads((run / "summary.json").read_text())["steps"] == rows


@pytest.mark.parametrize("after", [0, 3])
def test_a_state_gone_bad_mid_run_stops_it_cleanly_and_loses_no_row(
    after, tmp_path, capsys, monkeypatch
):
    """The simulated state turns not finite after ``after`` steps (physics blown up, a
    sensor's NaN): one line, exit 3, the run in place with its rows and a summary that
    says why."""
    from aeromanip.sim.kinematic import KinematicSimulator

    advance, calls = KinematicSimulator.advance, []

    def blows_up(self, u, plan_x, dt):
        advance(self, u, plan_x, dt)
        calls.append(1)
        if len(calls) > after:
            self.x[0] = np.nan

    monkeypatch.setattr(KinematicSimulator, "advance", blows_up)
    out = Path(tmp_path) / "run"
    argv = planar_argv(out, 4.0)
    rc, _, err = call(argv, capsys, RUN_LIMIT_S)
    line = assert_one_line(err, {ExitCode.DID_NOT_FLY}, rc, argv)
    assert "the run stopped: state: y is not finite (nan)" in line, line
    flown, run = steps_kept(line, out)
    rows = len(RunLog.load(run))
    assert rows == flown == after + 1, (rows, line)
    summary = json.loads((run / "summary.json").read_text())
    assert "not finite" in summary["stopped_by"] and summary["steps"] == rows
    assert not summary["interrupted"]
    assert not list(out.parent.glob(f"{out.name}.partial-*"))


def test_a_fault_before_the_first_step_keeps_the_error_code(tmp_path, capsys, monkeypatch):
    """Nothing flown (the simulator refused at its build): the error's own exit code, the
    run directory in place with its summary saying why."""
    from aeromanip.errors import ConfigError
    from aeromanip.experiment import runner

    def refused(sc):
        raise ConfigError("physics: refused at build")

    monkeypatch.setattr(runner, "make_simulator", refused)
    out = Path(tmp_path) / "run"
    argv = planar_argv(out, 1.0)
    rc, _, err = call(argv, capsys, RUN_LIMIT_S)
    line = assert_one_line(err, {ExitCode.BAD_INPUT}, rc, argv)
    flown, run = steps_kept(line, out)
    assert flown == 0 and "the run stopped: physics: refused at build" in line, line
    summary = json.loads((run / "summary.json").read_text())
    assert summary["steps"] == 0 and summary["stopped_by"] == "physics: refused at build"
