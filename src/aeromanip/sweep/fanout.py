"""The fan-out: runs as Ray tasks, on an embedded local Ray or a cluster, with a progress bar.

``ray_session`` joins the cluster at ``address`` or starts a local Ray of ``workers`` CPUs
(on loopback, no dashboard, worker output kept in Ray's logs, nothing downloaded: the package is
installed, so no working directory is shipped). ``fan_out`` submits each run as a task of
one CPU, at most a few per CPU at a time, and hands every result to a callback as it
comes: a task whose worker died is retried by Ray (``max_retries``), one that still
fails is reported as failed with Ray's reason. A signal (``RunInterrupted``) goes on up;
the tasks under way end with the session (``ray.shutdown`` stops their workers; a Ray the
campaign did not start gets a cancel), and what they left staged is cleared on resume.
"""

from __future__ import annotations

import contextlib
import importlib.util
import logging
import os
import signal
import socket
import sys
import time
from collections.abc import Callable, Iterator
from typing import Any, NamedTuple

from aeromanip.errors import ConfigError
from aeromanip.interrupts import raise_if_interrupted
from aeromanip.sweep.tasks import DONE, FAILED, RunTask, execute

MAX_RETRIES = 3  # a run whose worker dies is tried again this many times
IN_FLIGHT_PER_CPU = 2  # tasks submitted ahead of the free CPUs (keeps workers busy)
WAIT_S = 0.5  # [s] how often the driver looks up from waiting (signals, progress)
OBJECT_STORE_BYTES = 128 * 2**20  # local Ray: results are small dicts
LOCAL_IP = "127.0.0.1"  # an embedded Ray listens on loopback only
BAR_WIDTH = 24  # characters of the progress bar
CONNECT_S = 5.0  # [s] a cluster address must answer within this
HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n"
HTTP2_SETTINGS = 4  # the frame type a gRPC server answers the preface with


NO_RAY = "aeromanip sweep needs Ray, not installed: pip install 'aeromanip[sweep]'"


def _ray() -> Any:
    try:
        import ray
    except ImportError:
        raise ConfigError(NO_RAY) from None
    return ray


def check_ray(address: str | None) -> None:
    """Before any expensive work: Ray is installed, and a ``HOST:PORT`` or
    ``ray://HOST:PORT`` cluster address answers a TCP connection within ``CONNECT_S`` (Ray
    itself would wait minutes); ``auto`` is left to Ray."""
    if importlib.util.find_spec("ray") is None:
        raise ConfigError(NO_RAY)
    if not address or address == "auto":
        return
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ConfigError(
            f"--address {address}: expected HOST:PORT, ray://HOST:PORT or auto "
            f"(or no --address for a local Ray)"
        )
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_S) as c:
            if not os.environ.get("RAY_USE_TLS") and not _speaks_http2(c):
                raise ConfigError(
                    f"--address {address}: something listens there, but not a Ray cluster "
                    "(no gRPC answer); check the port (ray status shows it)"
                )
    except OSError as e:
        reason = e.strerror or type(e).__name__
        raise ConfigError(
            f"--address {address}: no Ray cluster answers there ({reason}); start one "
            f"(ray start --head) or drop --address for a local Ray"
        ) from None


def _speaks_http2(conn: socket.socket) -> bool:
    """Does the peer answer an HTTP/2 preface with a SETTINGS frame (as Ray's gRPC servers
    do) within the socket's timeout?"""
    conn.sendall(HTTP2_PREFACE + b"\x00\x00\x00\x04\x00\x00\x00\x00\x00")  # empty SETTINGS
    head = b""
    while len(head) < 9:
        chunk = conn.recv(9 - len(head))
        if not chunk:
            return False
        head += chunk
    return head[3] == HTTP2_SETTINGS


class Session(NamedTuple):
    """A Ray session of a campaign: runs at once, and whether the campaign started it."""

    parallelism: int
    owned: bool


@contextlib.contextmanager
def ray_session(address: str | None, workers: int | None) -> Iterator[Session]:
    """Ray for the campaign; yields how many runs fly at once and whether the session is
    ours (shut down at the end). An already initialised Ray (e.g. from Python) is used as
    it is and left running."""
    ray = _ray()
    if ray.is_initialized():
        yield Session(_parallelism(ray, workers), owned=False)
        return
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no usage report sent anywhere
    sigterm = signal.getsignal(signal.SIGTERM)  # ray.init replaces it: ours stops the sweep
    common: dict[str, Any] = {
        "include_dashboard": False,
        "log_to_driver": False,
        "logging_level": logging.WARNING,
    }
    try:
        if address:
            ray.init(address=address, **common)
        else:
            local = {"num_cpus": workers or os.cpu_count() or 1, "_node_ip_address": LOCAL_IP}
            ray.init(address="local", object_store_memory=OBJECT_STORE_BYTES, **local, **common)
    except (ConnectionError, RuntimeError, ValueError) as e:
        if not address:
            raise
        first = str(e).strip().splitlines()[:1] or ["?"]
        raise ConfigError(f"--address {address}: cannot join the Ray cluster: {first[0]}") from None
    finally:
        signal.signal(signal.SIGTERM, sigterm)
    try:
        yield Session(_parallelism(ray, workers), owned=True)
    finally:
        ray.shutdown()


def _parallelism(ray: Any, workers: int | None) -> int:
    cpus = int(ray.cluster_resources().get("CPU", 1))
    return max(1, min(workers, cpus) if workers else cpus)


class ProgressLine:
    """The campaign's progress on standard error: ``[####----] 3/8  3 done, 0 failed,
    5 left, eta 40 s``. On a terminal a bar redrawn in place (a failed run's error printed
    above it); elsewhere (a log file, CI) one such line per finished run, with its id,
    values and wall time."""

    def __init__(self, total: int, quiet: bool = False, tty: bool | None = None) -> None:
        self.total, self.quiet = total, quiet
        self.tty = sys.stderr.isatty() if tty is None else tty
        self.done = self.failed = 0
        self.t0 = time.perf_counter()
        if self.tty and not quiet:
            sys.stderr.write(self.status())
            sys.stderr.flush()

    def status(self) -> str:
        """The bar and the counts: done, failed, left, and the ETA [s] at the mean rate."""
        finished = self.done + self.failed
        left = self.total - finished
        elapsed = time.perf_counter() - self.t0
        eta = f"{elapsed / finished * left:.0f} s" if finished else "?"
        filled = BAR_WIDTH * finished // max(self.total, 1)
        bar = "#" * filled + "-" * (BAR_WIDTH - filled)
        return (
            f"sweep [{bar}] {finished}/{self.total}  {self.done} done, {self.failed} failed, "
            f"{left} left, eta {eta if left else '0 s'}"
        )

    def update(self, result: dict[str, Any], label: str) -> None:
        """Count ``result`` and show the progress."""
        ok = result["status"] == DONE
        self.done += ok
        self.failed += not ok
        if self.quiet:
            return
        what = "ok" if ok else f"FAILED: {result.get('error', '')[:120]}"
        run = f"{result['run_id']} {label} ({result.get('elapsed_s', 0):.1f} s) {what}"
        if not self.tty:
            print(f"{self.status()} | {run}", file=sys.stderr, flush=True)
            return
        above = "" if ok else f"{run}\n"
        end = "\n" if self.done + self.failed == self.total else ""
        sys.stderr.write(f"\r\033[K{above}{self.status()}{end}")
        sys.stderr.flush()


def _from_ray_error(task: RunTask, e: Exception, retries: int) -> dict[str, Any]:
    """The result of a task Ray could not complete (worker died after its retries...)."""
    cause = getattr(e, "cause", None)  # a RayTaskError wraps what the task raised
    first = (str(cause or e).strip().splitlines() or ["?"])[0]
    kind = type(cause or e).__name__
    if "died" in first or "WorkerCrashed" in kind or "NodeDied" in kind:
        first = f"worker died, {retries} retries used: {first}"
    return {"run_id": task.run_id, "status": FAILED, "error": f"{kind}: {first}"[:500]}


def fan_out(
    tasks: list[RunTask],
    on_result: Callable[[RunTask, dict[str, Any]], None],
    *,
    session: Session,
    env: dict[str, str],
    max_retries: int = MAX_RETRIES,
) -> None:
    """Run ``tasks`` on Ray, ``on_result(task, result)`` as each ends (module docstring)."""
    ray = _ray()
    options: dict[str, Any] = {"num_cpus": 1, "max_retries": max_retries}
    if env:
        options["runtime_env"] = {"env_vars": env}
    remote = ray.remote(execute).options(**options)
    queue = list(reversed(tasks))
    pending: dict[Any, RunTask] = {}
    try:
        while queue or pending:
            while queue and len(pending) < IN_FLIGHT_PER_CPU * session.parallelism:
                task = queue.pop()
                pending[remote.remote(task)] = task
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=WAIT_S)
            raise_if_interrupted()
            for ref in ready:
                task = pending.pop(ref)
                try:
                    result = ray.get(ref)
                except ray.exceptions.RayError as e:
                    result = _from_ray_error(task, e, max_retries)
                on_result(task, result)
    finally:  # interrupted (or failing): what is under way is resumed next time
        # a session of ours ends its tasks at ray.shutdown; in another, cancel them (not
        # force=True: that races a task's completion inside Ray and can abort the driver)
        if not session.owned:
            for ref in pending:
                with contextlib.suppress(Exception):
                    ray.cancel(ref)
