"""Hand-written C shipped with the package, built once per machine into the compile
cache and loaded with ``ctypes``.

A library is keyed by its sources' and headers' bytes, the compiler, the flags and
CasADi's version (its headers and DAQP library may be linked in), and checked like
every cache entry (``cache.CacheEntry``): a damaged file is rebuilt, not loaded. No
compiler, a failed build (one warning) or, for a part that runs the generated model,
``AEROMANIP_CODEGEN=0`` gives ``None``; the caller then runs its fallback.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import logging
import os
import platform
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import casadi as ca

from aeromanip.interrupts import deferred
from aeromanip.nmpc.backends.cache import CacheEntry
from aeromanip.nmpc.backends.codegen import (
    BUILD_TIMEOUT_S,
    cache_dir,
    start_compiler,
    stop_compiler,
)

log = logging.getLogger(__name__)

CFLAGS = ("-O2", "-fPIC", "-shared")
#: for this CPU, inner loops vectorised and unrolled (the solvers' row loops: 10-40 %
#: faster than -O2; unrolled, the condensed loop's short triangular rows 8-10 % more)
NATIVE_CFLAGS = ("-O3", "-march=native", "-funroll-loops", "-fPIC", "-shared")


@dataclass(frozen=True)
class CSources:
    """A library's C sources (compiled together) and headers in ``directory``, the
    libraries it links (paths), its purpose (for the warning on a failed build), and
    whether ``AEROMANIP_CODEGEN=0`` (the model's Functions in-process) turns it off
    too (a part that runs the generated model does; a solver of its own does not).
    ``includes``: header directories in ``directory``, searched before CasADi's."""

    name: str
    directory: Path
    sources: Sequence[str]
    headers: Sequence[str]
    link: Sequence[str] = ()
    includes: Sequence[str] = ()
    purpose: str = "a compiled part"
    cflags: Sequence[str] = CFLAGS
    follows_codegen: bool = True


def casadi_dir() -> Path:
    """Where CasADi's wheel keeps its headers and libraries."""
    return Path(ca.__file__).parent


def compiler(follows_codegen: bool = True) -> str | None:
    """The C compiler (``$CC``, else ``gcc``), or ``None`` (none, or code generation off
    and ``follows_codegen``)."""
    cc = shutil.which(os.environ.get("CC", "gcc"))
    if cc is None or (follows_codegen and os.environ.get("AEROMANIP_CODEGEN", "1") == "0"):
        return None
    return cc


def entry_of(spec: CSources, cc: str) -> CacheEntry:
    """The cache entry of ``spec`` built by ``cc`` (and, for code built for this CPU
    (``-march=native``), this CPU: a cache shared by other machines does not hand it
    instructions they lack)."""
    h = hashlib.sha256()
    for name in (*spec.sources, *spec.headers):
        h.update((spec.directory / name).read_bytes())
    links = (f"link:{name}" for name in spec.link)
    includes = (f"include:{name}" for name in spec.includes)
    h.update(" ".join((ca.__version__, Path(cc).name, *spec.cflags, *links, *includes)).encode())
    if "-march=native" in spec.cflags:
        h.update(cpu_identity().encode())
    return CacheEntry(cache_dir() / f"{spec.name}-{h.hexdigest()[:20]}.so")


@functools.cache
def cpu_identity() -> str:
    """This CPU's model and instruction-set flags (Linux's ``/proc/cpuinfo``; elsewhere
    what ``platform`` says)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return " ".join((platform.machine(), platform.processor()))
    keys = ("model name", "flags", "Features", "CPU part")  # x86, then ARM's names
    lines = (line for line in text.splitlines() if line.split(":")[0].strip() in keys)
    return "\n".join(dict.fromkeys(lines))  # once, not once per core


def load(spec: CSources) -> ctypes.CDLL | None:
    """The library of ``spec`` (built into the cache on first use), or ``None``."""
    cc = compiler(spec.follows_codegen)
    if cc is None:
        return None
    entry = entry_of(spec, cc)
    if not entry.valid():
        with entry.locked():
            if not entry.valid() and not _build(spec, entry, cc):
                return None
    return ctypes.CDLL(str(entry.lib))


def _build(spec: CSources, entry: CacheEntry, cc: str) -> bool:
    """Compile ``spec`` into the cache entry. The compiler runs in its own process group
    with its temporary files in the build directory, as ``codegen``'s do: an interrupt
    kills gcc's cc1 and as too, and leaves no file behind."""
    with tempfile.TemporaryDirectory(prefix=f"build-{spec.name}-", dir=entry.lib.parent) as tmp:
        out = Path(tmp) / entry.lib.name
        sources = [str(spec.directory / name) for name in spec.sources]
        includes = [f"-I{spec.directory / d}" for d in spec.includes]
        cmd = [cc, *spec.cflags, *sources, *includes, f"-I{casadi_dir() / 'include'}", "-o",
               str(out), *spec.link, "-lm"]  # fmt: skip
        proc = None
        try:
            with deferred():  # the compiler is started and recorded, or neither
                proc = start_compiler(cmd, tmp)
            text, _ = proc.communicate(timeout=BUILD_TIMEOUT_S)
        except (OSError, subprocess.TimeoutExpired) as e:
            log.warning("codegen: building %s failed (%s); Python instead", spec.purpose, e)
            return False
        finally:  # an interrupt or a timeout: no compiler left running
            stop_compiler(proc)
        if proc.returncode != 0:
            last = (text.decode(errors="replace").strip().splitlines() or ["?"])[-1]
            log.warning("codegen: building %s failed (%s); Python instead", spec.purpose, last)
            return False
        entry.install(out)
    return True
