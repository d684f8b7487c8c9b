"""Test-wide settings.

CasADi Functions run in-process (``AEROMANIP_CODEGEN=0``) unless a test is about compiled
code (marker ``codegen``): the answers are the same, and the suite tests rather than
compiles. ``AEROMANIP_CODEGEN=1 python -m pytest`` runs every test on compiled code.
The generated code is compiled at ``-O0`` (``AEROMANIP_CODEGEN_OPT``): the same arithmetic
as the default ``-O2`` on the compiler's default target, in a quarter of the build time
(``AEROMANIP_CODEGEN_OPT=2 python -m pytest`` tests the default's build).

The suite runs on every core (``pytest -n auto``, pytest-xdist). A test marked
``realtime`` (processes flying against the wall clock) has the machine to itself: while
it runs, no other worker starts a test (``MachineLock``), as a loaded machine makes the
real-time processes late and their figures worse than the code's.
"""

import fcntl
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from aeromanip.nmpc.constraints import Bounds
from aeromanip.nmpc.problem import Problem
from aeromanip.references import Constant
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import ControlRate, EndEffectorTracking

os.environ.setdefault("AEROMANIP_CODEGEN", "0")
os.environ.setdefault("AEROMANIP_CODEGEN_OPT", "0")

LOCK_DIR_KEY = "aeromanip_lock_dir"


def pytest_configure(config):
    config.addinivalue_line("markers", "codegen: the test builds C code (codegen on for it)")
    config.addinivalue_line(
        "markers", "realtime: the test flies against the wall clock (no other test meanwhile)"
    )
    if getattr(config.option, "numprocesses", None) and not hasattr(config, "workerinput"):
        config.aeromanip_lock_dir = tempfile.mkdtemp(prefix="aeromanip-tests-")  # -n's controller


def pytest_unconfigure(config):
    if d := getattr(config, "aeromanip_lock_dir", None):
        shutil.rmtree(d, ignore_errors=True)


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node):
    """pytest-xdist: every worker gets the controller's lock directory."""
    node.workerinput[LOCK_DIR_KEY] = node.config.aeromanip_lock_dir


class MachineLock:
    """Tests share the machine; a real-time test holds it alone. Two ``flock`` files:
    ``room`` (shared by running tests, exclusive for a real-time one) and ``gate``, which
    a real-time test closes first so that no new test keeps it waiting forever."""

    def __init__(self, directory: str) -> None:
        self.gate = open(Path(directory) / "gate", "a+")  # noqa: SIM115 (held for the session)
        self.room = open(Path(directory) / "room", "a+")  # noqa: SIM115

    @contextmanager
    def held(self, alone: bool) -> Iterator[None]:
        if alone:
            fcntl.flock(self.gate, fcntl.LOCK_EX)
            fcntl.flock(self.room, fcntl.LOCK_EX)
            fcntl.flock(self.gate, fcntl.LOCK_UN)
        else:
            fcntl.flock(self.gate, fcntl.LOCK_SH)
            fcntl.flock(self.room, fcntl.LOCK_SH)
            fcntl.flock(self.gate, fcntl.LOCK_UN)
        try:
            yield
        finally:
            fcntl.flock(self.room, fcntl.LOCK_UN)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    workerinput = getattr(item.config, "workerinput", None)
    if workerinput is None:  # one process: nothing runs beside the test
        yield
        return
    if not hasattr(item.config, "aeromanip_lock"):
        item.config.aeromanip_lock = MachineLock(workerinput[LOCK_DIR_KEY])
    with item.config.aeromanip_lock.held(item.get_closest_marker("realtime") is not None):
        yield


@pytest.fixture(autouse=True)
def _codegen_for_marked_tests(request, monkeypatch):
    if request.node.get_closest_marker("codegen"):
        monkeypatch.setenv("AEROMANIP_CODEGEN", "1")


@pytest.fixture(scope="module")
def small_problem():
    """A 3-step x8-3dof problem: the end effector to a constant point, a rate regulariser."""
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 3, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0)
    pb.add_task(ControlRate(), weight=0.1, level=None)
    return pb
