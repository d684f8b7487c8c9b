"""Compile CasADi Functions to C once and cache the shared library on disk.

``compiled(f)`` returns a Function that evaluates ``f`` from machine code: the C source
CasADi generates is built with the system C compiler (``$CC``, default ``gcc``) at
``-O2`` into ``<cache>/<name>-<hash>.so``, where the hash covers the Function's
serialisation (so it changes with the problem: robot, tasks, weights, horizon...), the
CasADi version and the compiler flags. Later processes load the cached library at once.

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
import subprocess
import sys
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

import casadi as ca
import numpy as np

log = logging.getLogger(__name__)

CFLAGS = ("-O2", "-fPIC", "-shared")
_warned: set[str] = set()


def cache_dir() -> Path:
    """Where compiled libraries live: ``$AEROMANIP_CACHE`` or ``~/.cache/aeromanip``."""
    env = os.environ.get("AEROMANIP_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "aeromanip"


def _compiler() -> str | None:
    cc = os.environ.get("CC", "gcc")
    return shutil.which(cc)


def _key(f: ca.Function, cc: str) -> str:
    h = hashlib.sha256()
    h.update(f.serialize().encode())
    h.update(ca.__version__.encode())
    h.update(" ".join((Path(cc).name, *CFLAGS)).encode())
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
    """``compiled`` for several Functions, the missing ones built in parallel."""
    if not enabled or os.environ.get("AEROMANIP_CODEGEN", "1") == "0":
        return list(fs)
    cc = _compiler()
    if cc is None:
        _warn_once("codegen: no C compiler found; evaluating CasADi Functions in-process")
        return list(fs)
    jobs = []
    for f in fs:
        lib = cache_dir() / f"{f.name()}-{_key(f, cc)}.so"
        job = None
        if not lib.is_file():
            try:
                job = _start(f, cc, lib)
            except OSError as e:
                _warn_once(f"codegen: compiling {f.name()} failed ({e}); evaluating in-process")
                jobs.append((f, None, None))
                continue
        jobs.append((f, lib, job))
    out = []
    for f, lib, job in jobs:
        if job is not None and not _finish(f, lib, *job):
            lib = None
        out.append(f if lib is None else ca.external(f.name(), str(lib)))
    return out


def _start(f: ca.Function, cc: str, lib: Path) -> tuple[subprocess.Popen, str, Path]:
    """Generate the C source of ``f`` and start compiling it."""
    lib.parent.mkdir(parents=True, exist_ok=True)
    tmp = tempfile.mkdtemp(dir=lib.parent)
    src = f"{f.name()}.c"
    cg = ca.CodeGenerator(src, {"with_header": False})
    cg.add(f)
    cg.generate(tmp + os.sep)
    out = Path(tmp) / lib.name
    cmd = [cc, *CFLAGS, str(Path(tmp) / src), "-o", str(out), "-lm"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    return proc, tmp, out


def _finish(f: ca.Function, lib: Path, proc: subprocess.Popen, tmp: str, out: Path) -> bool:
    """Wait for a build; move the library into the cache (atomically). Success?"""
    try:
        log_text, _ = proc.communicate(timeout=1200)
        if proc.returncode != 0:
            msg = log_text.decode(errors="replace").strip().splitlines()[-1:] or ["?"]
            _warn_once(f"codegen: compiling {f.name()} failed ({msg[0]}); evaluating in-process")
            return False
        os.replace(out, lib)  # concurrent builders never see a partial file
        return True
    except subprocess.TimeoutExpired:
        proc.kill()
        _warn_once(f"codegen: compiling {f.name()} timed out; evaluating in-process")
        return False
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


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
