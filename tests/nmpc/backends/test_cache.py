"""The compile cache: damaged libraries are rebuilt, never loaded; one build per entry.

Each ``compiled()`` call on a damaged cache runs in a fresh subprocess: loading a
truncated library could kill the process that maps it (SIGBUS), which is exactly what
must not happen, and it must not happen to the test process either. The Function is
handed to the subprocess serialised, so its cache key is the test's.
"""

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from aeromanip.nmpc.backends.cache import sha256_of

pytestmark = pytest.mark.codegen

CHILD_TIMEOUT_S = 120  # [s] a compile of a tiny Function takes well under a second
X = [0.3, -1.2, 2.0]

# argv: the point X (JSON), then serialised Function files; prints per Function: compiled?,
# values; then the libraries mapped and since replaced ("(deleted)") and the time it took
CHILD = """
import json, os, sys, time
import casadi as ca
from aeromanip.nmpc.backends.codegen import compiled
go = os.environ.get("GO_FILE")
if go:
    open(os.environ["READY_FILE"], "w").close()
    while not os.path.exists(go):
        time.sleep(0.005)
t0 = time.monotonic()
out = []
x = json.loads(sys.argv[1])
for path in sys.argv[2:]:
    f = ca.Function.deserialize(open(path).read())
    g = compiled(f)
    values = [ca.DM(v).full().ravel().tolist() for v in g(x)]
    out.append({"name": f.name(), "compiled": g is not f, "values": values})
done = time.monotonic() - t0
maps = [ln.split()[-2] for ln in open("/proc/self/maps") if ln.rstrip().endswith("(deleted)")]
print(json.dumps({"functions": out, "deleted_maps": maps, "seconds": done}))
"""


def make_function(name: str, scale: float = 1.0) -> ca.Function:
    x = ca.SX.sym("x", 3)
    return ca.Function(name, [x], [scale * ca.sin(x) * ca.sumsqr(x), ca.jacobian(x**3, x)])


def values_of(f: ca.Function) -> list[list[float]]:
    return [ca.DM(v).full().ravel().tolist() for v in f(X)]


def child_env(cache: Path, **extra: str) -> dict[str, str]:
    return {**os.environ, "AEROMANIP_CODEGEN": "1", "AEROMANIP_CACHE": str(cache), **extra}


def start_child(fn_files: list[Path], env: dict[str, str]) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-c", CHILD, json.dumps(X), *map(str, fn_files)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def finish_child(p: subprocess.Popen) -> dict:
    try:
        out, err = p.communicate(timeout=CHILD_TIMEOUT_S)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    assert p.returncode == 0, f"child ended with {p.returncode} (negative: a signal): {err}"
    return json.loads(out.strip().splitlines()[-1])


def run_child(fn_files: list[Path], cache: Path) -> dict:
    return finish_child(start_child(fn_files, child_env(cache)))


def save(f: ca.Function, where: Path) -> Path:
    path = where / f"{f.name()}.casadi"
    path.write_text(f.serialize())
    return path


def library(cache: Path, name: str) -> Path:
    (lib,) = cache.glob(f"{name}-*.so")
    return lib


def assert_whole_and_agrees(result: dict, f: ca.Function, cache: Path) -> None:
    """The child got the compiled Function, with ``f``'s values, and loaded no library that
    was then replaced; the entry's library matches its recorded checksum."""
    (got,) = result["functions"]
    assert got["compiled"], "fell back to the in-process Function instead of rebuilding"
    for a, b in zip(values_of(f), got["values"], strict=True):
        np.testing.assert_allclose(b, a, rtol=1e-14, atol=1e-14)
    assert not [m for m in result["deleted_maps"] if m.startswith(str(cache))]
    lib = library(cache, f.name())
    recorded = lib.with_name(lib.name + ".sha256").read_text().strip()
    assert recorded == sha256_of(lib)
    assert not list(cache.glob("build-*"))


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """A cache holding the libraries of two Functions (built once, in a subprocess)."""
    root = tmp_path_factory.mktemp("cache_template")
    cache = root / "cache"
    f = make_function("aeromanip_test_cache_f")
    h = make_function("aeromanip_test_cache_h", scale=2.0)
    files = [save(f, root), save(h, root)]
    result = run_child(files, cache)
    assert [r["compiled"] for r in result["functions"]] == [True, True]
    return root, cache, f, h


@pytest.fixture
def cache(built, tmp_path, monkeypatch):
    """A fresh copy of the built cache, as ``AEROMANIP_CACHE``."""
    _, template, _, _ = built
    cache = tmp_path / "cache"
    shutil.copytree(template, cache)
    monkeypatch.setenv("AEROMANIP_CACHE", str(cache))
    return cache


def _truncate_to_half(lib: Path, other: Path) -> None:
    os.truncate(lib, lib.stat().st_size // 2)


def _empty(lib: Path, other: Path) -> None:
    lib.unlink()
    lib.touch()


def _foreign_library(lib: Path, other: Path) -> None:
    shutil.copyfile(other, lib)


def _no_checksum(lib: Path, other: Path) -> None:
    lib.with_name(lib.name + ".sha256").unlink()


@pytest.mark.parametrize(
    "damage",
    [_truncate_to_half, _empty, _foreign_library, _no_checksum],
    ids=["truncated", "empty", "another-functions-library", "no-checksum-file"],
)
def test_a_damaged_or_unverified_library_is_rebuilt_not_loaded(built, cache, damage):
    root, _, f, h = built
    lib = library(cache, f.name())
    damage(lib, library(cache, h.name()))
    damaged = (lib.stat().st_ino, lib.stat().st_mtime_ns, lib.read_bytes())
    result = run_child([root / f"{f.name()}.casadi"], cache)
    assert_whole_and_agrees(result, f, cache)
    # a new file was moved into place: rebuilt (an inode number may be reused: compare all)
    now = (lib.stat().st_ino, lib.stat().st_mtime_ns, lib.read_bytes())
    assert now != damaged


def test_a_valid_library_is_loaded_without_a_rebuild(built, cache):
    root, _, f, _ = built
    lib = library(cache, f.name())
    inode, mtime = lib.stat().st_ino, lib.stat().st_mtime_ns
    assert_whole_and_agrees(run_child([root / f"{f.name()}.casadi"], cache), f, cache)
    assert (lib.stat().st_ino, lib.stat().st_mtime_ns) == (inode, mtime)


SLOW_CC_S = 2.0  # [s] the wrapper compiler's sleep before it runs gcc


def test_concurrent_builders_of_one_entry_compile_it_once(tmp_path):
    gcc = shutil.which("gcc")
    if gcc is None:
        pytest.skip("no gcc")
    cache, calls = tmp_path / "cache", tmp_path / "cc-calls.log"
    wrapper = tmp_path / "slow-cc"
    wrapper.write_text(
        f'#!/bin/sh\necho "$$ $*" >> "{calls}"\nsleep {SLOW_CC_S}\nexec "{gcc}" "$@"\n'
    )
    wrapper.chmod(0o755)
    f = make_function("aeromanip_test_cache_concurrent")
    files = [save(f, tmp_path)]
    go = tmp_path / "go"
    ready = [tmp_path / f"ready-{i}" for i in range(2)]
    children = [
        start_child(
            files,
            child_env(cache, CC=str(wrapper), GO_FILE=str(go), READY_FILE=str(r)),
        )
        for r in ready
    ]
    try:
        deadline = time.monotonic() + CHILD_TIMEOUT_S
        while not all(r.exists() for r in ready):  # both imported, waiting to start
            assert time.monotonic() < deadline, "the children did not start"
            assert all(c.poll() is None for c in children), "a child ended before it started"
            time.sleep(0.01)
        go.touch()
        results = [finish_child(c) for c in children]
    finally:
        for c in children:
            if c.poll() is None:
                c.kill()
                c.wait()
    assert len(calls.read_text().splitlines()) == 1  # the compiler ran once
    for result in results:
        assert_whole_and_agrees(result, f, cache)
    # one build each way would take two slow compiles; one build and a wait take one
    assert max(r["seconds"] for r in results) < 2 * SLOW_CC_S, results
