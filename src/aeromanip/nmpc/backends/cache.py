"""Entries of the compile cache: a library, its checksum and its lock.

``<cache>/<name>-<key>.so`` is only ever moved into place whole (``os.replace``), with its
SHA-256 in ``<name>-<key>.so.sha256`` written after it; a library is loaded only if its
checksum matches, so a truncated or foreign file (which would crash the process when
loaded) is rebuilt instead. ``<name>-<key>.so.lock`` (``flock``) makes concurrent
processes build an entry once: the first builds, the others wait and load it.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
from collections.abc import Iterator
from pathlib import Path

CHUNK = 1 << 20  # [bytes] read per hashing step


def sha256_of(path: Path) -> str:
    """The SHA-256 of a file's bytes, in hex."""
    h = hashlib.sha256()
    with path.open("rb") as fh:
        while chunk := fh.read(CHUNK):
            h.update(chunk)
    return h.hexdigest()


class CacheEntry:
    """One compiled library in the cache (see the module docstring)."""

    def __init__(self, lib: Path) -> None:
        self.lib = lib
        self.checksum = lib.with_name(lib.name + ".sha256")
        self.lock_path = lib.with_name(lib.name + ".lock")

    def valid(self) -> bool:
        """Whether the library is there, whole, and is the one that was built."""
        try:
            return self.checksum.read_text().strip() == sha256_of(self.lib)
        except OSError:
            return False

    def install(self, built: Path) -> None:
        """Move a freshly built library into place, then record its checksum."""
        digest = sha256_of(built)
        os.replace(built, self.lib)
        tmp = self.checksum.with_name(f"{self.checksum.name}.{os.getpid()}")
        tmp.write_text(digest + "\n")
        os.replace(tmp, self.checksum)

    def discard(self) -> None:
        """Remove the library and its checksum (a damaged entry)."""
        for p in (self.checksum, self.lib):
            p.unlink(missing_ok=True)

    @contextlib.contextmanager
    def locked(self) -> Iterator[None]:
        """Hold the entry's lock (waiting for another process that builds it)."""
        self.lib.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            yield
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)
