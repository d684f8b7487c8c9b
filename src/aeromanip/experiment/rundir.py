"""Run directories that are never half-written and never lost.

A run is written into a fresh staging directory beside its destination
(``DIR.partial-<pid>``) while it flies; when it ends (complete, or interrupted with what
it flew) the staging directory is moved into place, and a run already at ``DIR`` is kept
aside as ``DIR.previous``. A process killed outright leaves its staging directory, with
the rows streamed so far, for the user to look at. A lock file (``DIR.lock``) keeps two
runs from writing the same destination at once.
"""

from __future__ import annotations

import fcntl
import os
import shutil
from pathlib import Path
from types import TracebackType

from aeromanip.errors import ConfigError
from aeromanip.interrupts import RunInterrupted, deferred

PREVIOUS = ".previous"  # suffix of the run kept aside when a new one takes its place


def check_writable(path: Path, what: str = "--out") -> None:
    """Fail now, not after the run, if ``path`` cannot become a directory we can write.

    The nearest existing ancestor must be a writable directory and ``path`` itself, if
    it exists, a directory.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{what}: {path} exists and is not a directory")
    parent = path.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ConfigError(f"{what}: {path} cannot be created: {parent} is not a directory")
    _probe(parent, f"{what}: {path} cannot be created in {parent}")


def _probe(directory: Path, refusal: str) -> None:
    """Create and remove an entry in ``directory``, or a ``ConfigError`` ``refusal: why``
    (``os.access`` says yes to root everywhere, even under /proc: try for real)."""
    probe = directory / f".aeromanip-probe-{os.getpid()}"
    try:
        probe.mkdir()
        probe.rmdir()
    except OSError as e:
        raise ConfigError(f"{refusal}: {e.strerror}") from None


def check_file_writable(path: Path, what: str = "--out") -> None:
    """Fail now, not after the work, if the file ``path`` cannot be written (its
    directory may be created): not a directory itself, and its directory writable."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{what}: {path} is a directory; name a file")
    parent = path.parent
    if not parent.exists() or not parent.is_dir():
        check_writable(parent, what)
        return
    _probe(parent, f"{what}: {path} cannot be written in {parent}")


class RunDirectory:
    """Stage a run in ``<dest>.partial-<pid>`` and move it to ``dest`` when done.

    Use as a context manager: on entry the destination is locked (``ConfigError`` if
    another run holds it) and the staging directory created; ``staging`` is where to
    write. ``commit()`` moves it into place (keeping an existing run as
    ``<dest>.previous``); leaving the block without ``commit()`` leaves the staging
    directory where it is, and its path is reported by ``left_behind``.
    """

    def __init__(self, dest: Path) -> None:
        self.dest = Path(dest).absolute()
        self.staging = self.dest.with_name(f"{self.dest.name}.partial-{os.getpid()}")
        self.lock_path = self.dest.with_name(f"{self.dest.name}.lock")
        self._lock_fd: int | None = None
        self.committed = False

    def __enter__(self) -> RunDirectory:
        check_writable(self.dest)
        try:
            with deferred():  # a signal meanwhile: nothing half-made left behind
                self.dest.parent.mkdir(parents=True, exist_ok=True)
                self._lock_fd = self._lock()
                if self.staging.exists():  # a crashed run of a process with our pid
                    shutil.rmtree(self.staging)
                self.staging.mkdir()
        except RunInterrupted:
            self.__exit__(None, None, None)
            shutil.rmtree(self.staging, ignore_errors=True)
            raise
        return self

    def _lock(self) -> int:
        """Hold ``DIR.lock`` (retried if another run removed it between open and lock)."""
        while True:
            fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                raise ConfigError(
                    f"--out: {self.dest} is being written by another run (lock {self.lock_path})"
                ) from None
            try:
                if os.stat(self.lock_path).st_ino == os.fstat(fd).st_ino:
                    return fd
            except FileNotFoundError:
                pass
            os.close(fd)

    def commit(self) -> Path:
        """Move the staged run to ``dest`` (an existing run there goes to ``.previous``)."""
        previous = self.dest.with_name(self.dest.name + PREVIOUS)
        if self.dest.exists():
            if previous.exists():
                shutil.rmtree(previous)
            os.replace(self.dest, previous)
        os.replace(self.staging, self.dest)
        self.committed = True
        return self.dest

    @property
    def left_behind(self) -> Path | None:
        """The staging directory, if the run ended without ``commit()``."""
        return None if self.committed or not self.staging.exists() else self.staging

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self._lock_fd is not None:
            fcntl.flock(self._lock_fd, fcntl.LOCK_UN)
            os.close(self._lock_fd)
            self._lock_fd = None
            self.lock_path.unlink(missing_ok=True)
