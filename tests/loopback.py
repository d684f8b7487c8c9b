"""Test helpers for links on 127.0.0.1: a free UDP port, and a SITL flying in a thread
for a bounded time."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

HOST = "127.0.0.1"
CLI = [sys.executable, "-m", "aeromanip.cli"]


def free_udp_port() -> int:
    """A free UDP port on 127.0.0.1."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


@contextmanager
def sitl_in_thread(sitl: Any, fly_s: float) -> Iterator[list[dict]]:
    """``sitl.run`` for ``fly_s`` [s] in a thread; yields the rows it logs. On leaving:
    the thread joined (at most ``fly_s + 5`` s), the SITL closed, and what it raised (or
    a thread still running) fails the test."""
    rows: list[dict] = []
    failures: list[BaseException] = []

    def serve() -> None:
        try:
            sitl.run(rows.append, max_time_s=fly_s)
        except BaseException as e:  # reported below
            failures.append(e)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield rows
    finally:
        thread.join(timeout=fly_s + 5)
        sitl.close()
    assert not failures and not thread.is_alive(), failures


def start_sitl(out: Path, port: int, max_s: float) -> subprocess.Popen:
    """``aeromanip sitl flight`` sending to ``port`` on 127.0.0.1, its truth log in
    ``out``, stopping by itself after ``max_s`` [s] whatever happens."""
    return subprocess.Popen(
        [*CLI, "sitl", "flight", "--link", f"udpout:{HOST}:{port}", "--out", str(out),
         "--max-time", str(max_s)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
