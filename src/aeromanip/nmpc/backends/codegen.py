"""Compile CasADi Functions to C once and cache the shared library on disk.

``compiled(f)`` returns a Function that evaluates ``f`` from machine code: the C source
CasADi generates is built with the system C compiler (``$CC``, default ``gcc``) at
``-O2`` (or ``-O$AEROMANIP_CODEGEN_OPT``) into ``<cache>/<name>-<hash>.so``, where the
hash covers the Function's serialisation (so it changes with the problem: robot, tasks,
weights, horizon...), the CasADi version and the compiler flags. Later processes load
the cached library at once, after checking it against its recorded checksum
(``nmpc.backends.cache``: damaged entries are rebuilt, concurrent builders of one entry
wait for each other).

The cache directory is ``$AEROMANIP_CACHE`` or ``~/.cache/aeromanip``. Without a working
compiler (or with ``AEROMANIP_CODEGEN=0``) the in-process Function is returned unchanged,
with one warning: slower, same results. Nothing is downloaded.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import logging
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.interrupts import deferred
from aeromanip.nmpc.backends.cache import CacheEntry

log = logging.getLogger(__name__)

OPT_LEVEL = "2"  # gcc's -O level of the generated code, unless $AEROMANIP_CODEGEN_OPT says
OPT_LEVELS = ("0", "1", "2", "3", "s")
BUILD_TIMEOUT_S = 1200  # [s] a compiler running longer is killed (the Function runs in-process)
# instructions to compile beyond which a build is announced: the condensed SQP model at
# N = 20 (~0.4 M) takes gcc minutes and GiBs of memory, and it grows like N^2
LARGE_BUILD = 200_000
_warned: set[str] = set()


def cache_dir() -> Path:
    """Where compiled libraries live: ``$AEROMANIP_CACHE`` or ``~/.cache/aeromanip``."""
    env = os.environ.get("AEROMANIP_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "aeromanip"


def cflags() -> tuple[str, ...]:
    """The flags the generated code is compiled with: ``-O`` of ``$AEROMANIP_CODEGEN_OPT``
    (default ``OPT_LEVEL``). On the compiler's default target the arithmetic is the same at
    every level (no contraction into fused multiply-adds), the build time is not: the
    condensed SQP model at N = 10 builds in ~12 s at ``-O0``, ~48 s at ``-O2``, ~150 s at
    ``-O1``."""
    level = os.environ.get("AEROMANIP_CODEGEN_OPT", OPT_LEVEL)
    if level not in OPT_LEVELS:
        raise ConfigError(
            f"AEROMANIP_CODEGEN_OPT = {level!r}: the generated code's -O level is one of "
            + ", ".join(OPT_LEVELS)
        )
    return (f"-O{level}", "-fPIC", "-shared")


def _compiler() -> str | None:
    cc = os.environ.get("CC", "gcc")
    return shutil.which(cc)


def _key(f: ca.Function, cc: str) -> str:
    h = hashlib.sha256()
    h.update(f.serialize().encode())
    h.update(ca.__version__.encode())
    h.update(" ".join((Path(cc).name, *cflags())).encode())
    return h.hexdigest()[:20]


def _warn_once(msg: str) -> None:
    if msg not in _warned:
        _warned.add(msg)
        log.warning(msg)


def compiled(f: ca.Function, enabled: bool = True) -> ca.Function:
    """``f`` evaluated from C code compiled once and cached (see module docstring).

    Args:
        f: a CasADi Function (SX or MX graph without external calls).
        enabled: ``False`` returns ``f`` unchanged.
    """
    return compiled_all([f], enabled)[0]


def compiled_all(fs: Sequence[ca.Function], enabled: bool = True) -> list[ca.Function]:
    """``compiled`` for several Functions, the missing ones built in parallel.

    Every entry is verified before it is loaded (a damaged one is rebuilt); entries
    another process is building are waited for, then loaded; an interrupt kills the
    compilers and removes their build directories before it goes on up.
    """
    if not enabled or os.environ.get("AEROMANIP_CODEGEN", "1") == "0":
        return list(fs)
    cc = _compiler()
    if cc is None:
        _warn_once("codegen: no C compiler found; evaluating CasADi Functions in-process")
        return list(fs)
    entries = [CacheEntry(cache_dir() / f"{f.name()}-{_key(f, cc)}.so") for f in fs]
    missing = sorted({e.lib for e in entries if not e.valid()})  # one lock order: no deadlock
    with contextlib.ExitStack() as locks:
        for lib in missing:
            locks.enter_context(CacheEntry(lib).locked())
        todo = [(f, e) for f, e in zip(fs, entries, strict=True) if not e.valid()]
        announce_large_build([f for f, _ in todo])
        failed = _build_all(todo, cc)
    return [_load(f, e, f.name() not in failed) for f, e in zip(fs, entries, strict=True)]


def library_of(f: ca.Function) -> Path | None:
    """The cached, verified library that ``compiled(f)`` loaded ``f`` from (``None``: it
    evaluates in-process); its symbols are ``f.name()`` and ``f.name() + "_work"``."""
    cc = _compiler()
    if cc is None or os.environ.get("AEROMANIP_CODEGEN", "1") == "0":
        return None
    entry = CacheEntry(cache_dir() / f"{f.name()}-{_key(f, cc)}.so")
    return entry.lib if entry.valid() else None


def announce_large_build(fs: Sequence[ca.Function]) -> bool:
    """Warn before compiling Functions of more than ``LARGE_BUILD`` instructions in all
    (the compiler's time and memory grow with them); return whether it warned."""
    sizes = {f.name(): f.n_instructions() for f in fs}
    total = sum(sizes.values())
    if total <= LARGE_BUILD:
        return False
    largest = max(sizes, key=sizes.__getitem__)
    log.warning(
        "codegen: compiling %d functions of %.2g M instructions (largest %s, %.2g M): "
        "this may take minutes and GiBs of memory, once (then cached in %s); at long "
        "horizons solver_options.qpsol = 'hpipm' keeps the code small",
        len(sizes), total / 1e6, largest, sizes[largest] / 1e6, cache_dir(),
    )  # fmt: skip
    return True


def start_compiler(cmd: list[str], tmp: str) -> subprocess.Popen:
    """Start the compiler ``cmd`` in its own process group (an interrupt kills gcc's cc1
    and as too: ``stop_compiler``), its temporary files in the build directory ``tmp``;
    call it inside ``deferred()`` so that it is started and recorded, or neither."""
    return subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        start_new_session=True,
        env={**os.environ, "TMPDIR": tmp},
    )


def stop_compiler(proc: subprocess.Popen | None) -> None:
    """Kill a compiler still running, with its process group, and reap it."""
    if proc is not None and proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def _build_all(todo: list[tuple[ca.Function, CacheEntry]], cc: str) -> set[str]:
    """Build the entries (their locks held); return the names that failed."""
    jobs: list[tuple[ca.Function, CacheEntry, subprocess.Popen | None, str, Path]] = []
    failed: set[str] = set()
    try:
        for f, entry in todo:
            entry.discard()
            tmp = tempfile.mkdtemp(prefix=f"build-{entry.lib.stem}-", dir=entry.lib.parent)
            jobs.append((f, entry, None, tmp, Path(tmp) / entry.lib.name))
            try:
                cmd = _generate(f, cc, Path(tmp), entry.lib.name)
                with deferred():  # the compiler is started and recorded, or neither
                    proc = start_compiler(cmd, tmp)  # its files go into tmp (removed below)
                    jobs[-1] = (*jobs[-1][:2], proc, *jobs[-1][3:])
            except OSError as e:
                _warn_once(f"codegen: compiling {f.name()} failed ({e}); evaluating in-process")
                failed.add(f.name())
        for f, entry, proc, _, out in jobs:
            if proc is not None and not _finish(f, entry, proc, out):
                failed.add(f.name())
    finally:  # normal end or an interrupt: no compiler left running, no build directory
        for _, _, proc, tmp, _ in jobs:
            stop_compiler(proc)
            shutil.rmtree(tmp, ignore_errors=True)
    return failed


def _load(f: ca.Function, entry: CacheEntry, ok: bool) -> ca.Function:
    """The compiled twin of ``f`` from a verified entry, or ``f`` itself if none."""
    if not ok or not entry.valid():
        return f
    try:
        return ca.external(f.name(), str(entry.lib))
    except RuntimeError as e:  # a verified library that will not load: not ours
        entry.discard()
        first = str(e).strip().splitlines()[-1:] or ["?"]
        _warn_once(f"codegen: loading {entry.lib.name} failed ({first[0]}); evaluating in-process")
        return f


def _generate(f: ca.Function, cc: str, tmp: Path, lib_name: str) -> list[str]:
    """Write the C source of ``f`` into ``tmp``; return the compiler command.

    CasADi generates the source in C++ without giving Python control back: a signal
    that arrives meanwhile is handled when it returns (seconds for the largest
    Functions)."""
    src = f"{f.name()}.c"
    cg = ca.CodeGenerator(src, {"with_header": False})
    cg.add(f)
    cg.generate(str(tmp) + os.sep)
    return [cc, *cflags(), str(tmp / src), "-o", str(tmp / lib_name), "-lm"]


def _finish(f: ca.Function, entry: CacheEntry, proc: subprocess.Popen, out: Path) -> bool:
    """Wait for a build and install the library into the cache. Success?"""
    try:
        log_text, _ = proc.communicate(timeout=BUILD_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        _warn_once(f"codegen: compiling {f.name()} timed out; evaluating in-process")
        return False
    if proc.returncode != 0:
        msg = log_text.decode(errors="replace").strip().splitlines()[-1:] or ["?"]
        _warn_once(f"codegen: compiling {f.name()} failed ({msg[0]}); evaluating in-process")
        return False
    entry.install(out)
    return True


_BLAS_SETTERS = (
    "openblas_set_num_threads",
    "openblas_set_num_threads64_",
    "scipy_openblas_set_num_threads64_",
    "scipy_openblas_set_num_threads",
)


def limit_blas_threads(n: int = 1) -> list[str]:
    """Set every OpenBLAS loaded in this process (NumPy's, CasADi's) to ``n`` threads.

    On the small matrices of an NMPC step, BLAS threads only add latency, and two thread
    pools (NumPy's and CasADi's) spinning on a 2-core machine slow a step tenfold. Like
    ``OPENBLAS_NUM_THREADS=n``, but effective after the libraries are loaded (Linux: reads
    ``/proc/self/maps``; elsewhere does nothing). Returns the libraries changed.
    """
    try:
        with open("/proc/self/maps") as fh:
            paths = {ln.split()[-1] for ln in fh if "openblas" in ln.lower() and "/" in ln}
    except OSError:
        return []
    done = []
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for sym in _BLAS_SETTERS:
            fn = getattr(lib, sym, None)
            if fn is not None:
                fn(ctypes.c_int(n))
                done.append(path)
                break
    return done


@contextlib.contextmanager
def quiet_stdout() -> Iterator[None]:
    """Silence C-level writes to standard output (e.g. qpOASES's banner) in this block."""
    sys.stdout.flush()
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # no real file descriptor: nothing to do
        yield
        return
    saved = os.dup(fd)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), fd)
            yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, fd)
        os.close(saved)


class Buffered:
    """Zero-copy evaluation of a Function on preallocated NumPy arrays.

    ``args`` and ``res`` hold the inputs' and outputs' nonzeros (column-major for dense
    matrices); ``__call__`` copies its arguments in, runs, and returns ``res`` (overwritten
    by the next call: copy what you keep).
    """

    def __init__(self, f: ca.Function) -> None:
        self.f = f
        self.buf, self.run = f.buffer()
        self.args = [np.zeros(f.nnz_in(i)) for i in range(f.n_in())]
        self.res = [np.zeros(f.nnz_out(i)) for i in range(f.n_out())]
        for i, a in enumerate(self.args):
            self.buf.set_arg(i, memoryview(a))
        for i, r in enumerate(self.res):
            self.buf.set_res(i, memoryview(r))

    def __call__(self, *args: np.ndarray) -> list[np.ndarray]:
        """Evaluate at ``args``."""
        for a, v in zip(self.args, args, strict=True):
            a[:] = v
        self.run()
        return self.res
