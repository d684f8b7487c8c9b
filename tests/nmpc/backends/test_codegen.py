"""Compiled CasADi Functions: built once, cached on disk, the same answers as in-process."""

import json
import os
import sys
import time
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends import codegen
from aeromanip.nmpc.backends.cache import CacheEntry, sha256_of
from aeromanip.nmpc.backends.codegen import compiled
from aeromanip.nmpc.controller import Controller
from nmpc_helpers import FAST, X0, make_problem

pytestmark = pytest.mark.codegen


def test_compiled_functions_are_cached_and_agree(tmp_path, monkeypatch):
    monkeypatch.setenv("AEROMANIP_CACHE", str(tmp_path))
    x = ca.SX.sym("x", 3)
    f = ca.Function("aeromanip_test_f", [x], [ca.sin(x) * ca.sumsqr(x), ca.jacobian(x**3, x)])
    g = compiled(f)
    assert f.class_name() == "SXFunction" and g.class_name() != "SXFunction"  # the library
    libs = list(tmp_path.glob("aeromanip_test_f-*.so"))
    assert len(libs) == 1
    v = np.array([0.3, -1.2, 2.0])
    for a, b in zip(f(v), g(v), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-14, atol=1e-14)
    mtime = libs[0].stat().st_mtime_ns
    compiled(f)  # the same Function again: loaded, not rebuilt
    assert libs[0].stat().st_mtime_ns == mtime
    assert len(list(tmp_path.glob("*.so"))) == 1


def test_compiled_sqp_matches_in_process(tmp_path, monkeypatch):
    monkeypatch.setenv("AEROMANIP_CACHE", str(tmp_path))
    pb = make_problem(levels=(0, 0), horizon=3)
    a = Controller(pb, "weighted", "sqp").step(X0, 0.0)
    b = Controller(pb, "weighted", "sqp", FAST).step(X0, 0.0)
    assert list(tmp_path.glob("*.so"))
    np.testing.assert_allclose(a.plan_u, b.plan_u, atol=1e-9)


def test_the_generated_code_computes_the_same_at_every_optimisation_level(tmp_path, monkeypatch):
    """The suite builds at -O0 (``tests/conftest.py``), users at -O2: a closed loop of
    the SQP on each build gives the same plans, bit for bit."""
    monkeypatch.setenv("AEROMANIP_CACHE", str(tmp_path))
    plans = {}
    for level in ("0", "2"):
        monkeypatch.setenv("AEROMANIP_CODEGEN_OPT", level)
        ctrl = Controller(make_problem(levels=(0, 0), horizon=3), "weighted", "sqp")
        x, plans[level] = X0.copy(), []
        for k in range(4):
            cmd = ctrl.step(x, 0.5 * k)
            plans[level].append(cmd.plan_u)
            x = x + 0.5 * cmd.plan_u[0]
    built = {lib.name.split("-")[0] for lib in tmp_path.glob("aeromanip_sqp_*.so")}
    assert len(list(tmp_path.glob("aeromanip_sqp_*.so"))) == 2 * len(built)  # one per level
    assert np.array_equal(np.array(plans["0"]), np.array(plans["2"]))


def test_a_bad_optimisation_level_is_one_line(monkeypatch):
    monkeypatch.setenv("AEROMANIP_CODEGEN_OPT", "fast")
    with pytest.raises(
        ConfigError, match=r"AEROMANIP_CODEGEN_OPT = 'fast': .* one of 0, 1, 2, 3, s"
    ):
        codegen.cflags()


@pytest.mark.parametrize(
    ("cc", "warning"),
    [
        ("false", "codegen: compiling aeromanip_test_cc failed (?); evaluating in-process"),
        ("no-such-compiler-xyz",
         "codegen: no C compiler found; evaluating CasADi Functions in-process"),
    ],
)  # fmt: skip
def test_without_a_working_compiler_functions_run_in_process(
    tmp_path, monkeypatch, caplog, cc, warning
):
    """A compiler that fails silently, or none at all: the Function runs in-process, with
    one warning saying so, and nothing is left in the cache."""
    monkeypatch.setenv("AEROMANIP_CODEGEN", "1")
    monkeypatch.setenv("AEROMANIP_CACHE", str(tmp_path))
    monkeypatch.setenv("CC", cc)
    monkeypatch.setattr(codegen, "_warned", set())
    x = ca.SX.sym("x", 2)
    f = ca.Function("aeromanip_test_cc", [x], [ca.sumsqr(x)])
    with caplog.at_level("WARNING"):
        assert compiled(f) is f
    assert [r.getMessage() for r in caplog.records] == [warning]
    left = [p.name for p in tmp_path.iterdir() if p.suffix != ".lock"]
    assert not left  # no library, no leftover build directory (a lock file may stay)


def test_a_large_build_is_announced_before_it_starts(caplog):
    from aeromanip.nmpc.backends.codegen import LARGE_BUILD, announce_large_build

    x = ca.SX.sym("x")
    small = ca.Function("aeromanip_small", [x], [ca.sin(x)])
    y = x
    for _ in range(LARGE_BUILD // 2 + 1):  # two instructions per round
        y = ca.sin(y) * x
    large = ca.Function("aeromanip_large", [x], [y])
    assert large.n_instructions() > LARGE_BUILD >= small.n_instructions() * 1000
    with caplog.at_level("WARNING"):
        assert not announce_large_build([small])
        assert not caplog.records
        assert announce_large_build([small, large])
    (record,) = caplog.records
    assert "aeromanip_large" in record.getMessage() and "hpipm" in record.getMessage()


class _Sized:
    """A stand-in Function of a given instruction count (all the announcement reads)."""

    def __init__(self, name, size):
        self._name, self._size = name, size

    def name(self):
        return self._name

    def n_instructions(self):
        return self._size


def test_the_announcement_gives_the_counts_in_millions_and_the_cache(caplog, monkeypatch):
    """Up to ``LARGE_BUILD`` instructions in all nothing is said; above, one warning with
    the count of Functions, the total and the largest in millions (two significant
    digits) and the cache directory."""
    from aeromanip.nmpc.backends.codegen import LARGE_BUILD, announce_large_build

    monkeypatch.setenv("AEROMANIP_CACHE", "/cache/here")
    edge = [_Sized("a", LARGE_BUILD - 1000), _Sized("b", 1000)]
    over = [_Sized("aeromanip_big", 135_000), _Sized("aeromanip_small", LARGE_BUILD - 110_000)]
    with caplog.at_level("WARNING"):
        assert not announce_large_build(edge) and not caplog.records
        assert announce_large_build(over)
    (record,) = caplog.records
    assert record.getMessage() == (  # 225000 and 135000 instructions
        "codegen: compiling 2 functions of 0.23 M instructions (largest aeromanip_big, "
        "0.14 M): this may take minutes and GiBs of memory, once (then cached in "
        "/cache/here); at long horizons solver_options.qpsol = 'hpipm' keeps the code small"
    )


FAKE_CC = """\
import json, os, sys, time
json.dump({"pid": os.getpid(), "sid": os.getsid(0), "tmpdir": os.environ.get("TMPDIR"),
           "args": sys.argv[1:]}, open(os.environ["FAKE_CC_LOG"], "w"))
time.sleep(float(os.environ.get("FAKE_CC_SLEEP", "0")))
if not os.environ.get("FAKE_CC_QUIET"):
    print("fake-cc: reading the source", flush=True)
    sys.stderr.buffer.write(b"fake-cc: \\xff not UTF-8\\n")
    sys.stderr.write("fake-cc: error: nothing compiled here\\n")
if os.environ.get("FAKE_CC_RMDIR"):  # it cleans up after itself, build directory and all
    import shutil
    shutil.rmtree(os.environ["TMPDIR"])
sys.exit(1)
"""


@pytest.fixture
def fake_cc(tmp_path, monkeypatch):
    """A compiler that records how it was started (pid, session, TMPDIR, arguments), may
    sleep, then fails with a message on its standard error (and may remove its TMPDIR)."""
    script = tmp_path / "fake-cc"
    script.write_text(f"#!{sys.executable}\n{FAKE_CC}")
    script.chmod(0o755)
    log = tmp_path / "fake-cc.json"
    monkeypatch.setenv("CC", str(script))
    monkeypatch.setenv("FAKE_CC_LOG", str(log))
    monkeypatch.setenv("AEROMANIP_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(codegen, "_warned", set())
    return log


def test_a_build_runs_in_its_own_directory_and_session_and_its_errors_are_reported(
    fake_cc, tmp_path, caplog
):
    """The compiler runs in a fresh ``build-<library>-*`` directory of the cache, which is
    also its ``TMPDIR`` (where gcc leaves temporary files), in a session of its own (an
    interrupt kills its whole group); the last line it prints ends the warning; the
    Function then runs in-process and no build directory is left."""
    x = ca.SX.sym("x", 2)
    f = ca.Function("aeromanip_fake_cc", [x], [ca.sumsqr(x)])
    with caplog.at_level("WARNING"):
        assert compiled(f) is f
    rec = json.loads(fake_cc.read_text())
    build = Path(rec["tmpdir"])
    assert build.parent == tmp_path / "cache" and build.name.startswith("build-aeromanip_fake_cc-")
    assert any(a.startswith(str(build) + os.sep) and a.endswith(".c") for a in rec["args"])
    assert rec["sid"] == rec["pid"] != os.getsid(0)  # a session leader: its own group
    assert (  # its last line, of both outputs, whatever bytes came before
        "codegen: compiling aeromanip_fake_cc failed (fake-cc: error: nothing compiled "
        "here); evaluating in-process"
    ) in caplog.text
    assert not build.exists() and not list((tmp_path / "cache").glob("build-*"))


def test_a_compiler_that_removed_its_build_directory_still_leaves_the_fallback(
    fake_cc, tmp_path, monkeypatch, caplog
):
    """A build directory already gone when the build is cleaned up: still the one warning
    and the Function in-process, no exception."""
    monkeypatch.setenv("FAKE_CC_RMDIR", "1")
    x = ca.SX.sym("x", 2)
    f = ca.Function("aeromanip_tidy_cc", [x], [ca.sumsqr(x)])
    with caplog.at_level("WARNING"):
        assert compiled(f) is f
    assert not Path(json.loads(fake_cc.read_text())["tmpdir"]).exists()  # it did remove it
    assert "codegen: compiling aeromanip_tidy_cc failed" in caplog.text
    assert not list((tmp_path / "cache").glob("build-*"))


def test_a_build_past_its_time_limit_is_killed_and_the_function_runs_in_process(
    fake_cc, monkeypatch, caplog
):
    monkeypatch.setattr(codegen, "BUILD_TIMEOUT_S", 0.5)
    monkeypatch.setenv("FAKE_CC_SLEEP", "30")
    x = ca.SX.sym("x", 2)
    f = ca.Function("aeromanip_slow_cc", [x], [ca.sumsqr(x)])
    t0 = time.monotonic()
    with caplog.at_level("WARNING"):
        assert compiled(f) is f
    assert time.monotonic() - t0 < 10.0
    assert "compiling aeromanip_slow_cc timed out" in caplog.text
    pid = json.loads(fake_cc.read_text())["pid"]
    with pytest.raises(ProcessLookupError):  # killed and reaped
        os.kill(pid, 0)


def test_a_verified_library_that_will_not_load_is_discarded_and_named(
    tmp_path, monkeypatch, caplog
):
    """A file whose checksum matches but which is no library (not ours): the warning
    names it with the loader's last line, the entry is removed, the Function runs
    in-process."""
    monkeypatch.setenv("AEROMANIP_CACHE", str(tmp_path))
    monkeypatch.setattr(codegen, "_warned", set())
    x = ca.SX.sym("x", 2)
    f = ca.Function("aeromanip_not_a_lib", [x], [ca.sumsqr(x)])
    cc = codegen._compiler()
    if cc is None:
        pytest.skip("no C compiler")
    lib = tmp_path / f"{f.name()}-{codegen._key(f, cc)}.so"
    lib.write_bytes(b"not an ELF file")
    CacheEntry(lib).checksum.write_text(sha256_of(lib) + "\n")
    with caplog.at_level("WARNING"):
        assert compiled(f) is f
    (msg,) = [r.getMessage() for r in caplog.records if "loading" in r.getMessage()]
    assert not lib.exists() and not CacheEntry(lib).checksum.exists()  # discarded
    lib.write_bytes(b"not an ELF file")
    with pytest.raises(RuntimeError) as err:  # the loader's own words, last line
        ca.external(f.name(), str(lib))
    last = str(err.value).strip().splitlines()[-1]
    assert msg == f"codegen: loading {lib.name} failed ({last}); evaluating in-process"
    lib.unlink()


def test_a_silent_failing_compiler_and_one_that_cannot_start_are_reported(
    fake_cc, monkeypatch, tmp_path, caplog
):
    monkeypatch.setenv("FAKE_CC_QUIET", "1")
    x = ca.SX.sym("x", 2)
    f = ca.Function("aeromanip_quiet_cc", [x], [ca.sumsqr(x)])
    with caplog.at_level("WARNING"):
        assert compiled(f) is f
    assert "compiling aeromanip_quiet_cc failed (?); evaluating in-process" in caplog.text
    broken = tmp_path / "broken-cc"  # an interpreter that does not exist: no process
    broken.write_text("#!/nonexistent/interpreter\n")
    broken.chmod(0o755)
    monkeypatch.setenv("CC", str(broken))
    g = ca.Function("aeromanip_broken_cc", [x], [ca.sumsqr(x)])
    with caplog.at_level("WARNING"):
        assert compiled(g) is g
    assert "compiling aeromanip_broken_cc failed (" in caplog.text
    assert not list((tmp_path / "cache").glob("build-*"))


def test_codegen_switched_off_returns_the_function_itself(fake_cc):
    x = ca.SX.sym("x", 2)
    f = ca.Function("aeromanip_off_cc", [x], [ca.sumsqr(x)])
    assert compiled(f, enabled=False) is f
    assert not fake_cc.exists()  # no compiler was started


def test_several_functions_are_compiled_unless_switched_off(fake_cc, monkeypatch):
    """``compiled_all`` builds by default (here the stand-in compiler starts and fails,
    so the Functions come back as they were)."""
    monkeypatch.setenv("AEROMANIP_CODEGEN", "1")
    x = ca.SX.sym("x", 2)
    fs = [ca.Function(f"aeromanip_all_{i}", [x], [ca.sumsqr(x) + i]) for i in range(2)]
    for enabled in (False, True):
        got = codegen.compiled_all(fs, enabled=False) if not enabled else codegen.compiled_all(fs)
        assert len(got) == 2 and got[0] is fs[0] and got[1] is fs[1]
        assert fake_cc.exists() is enabled


@pytest.mark.parametrize("qpsol", ["daqp", "hpipm"])
@pytest.mark.parametrize("enabled", [False, True])
def test_the_codegen_option_decides_whether_a_models_functions_are_compiled(
    fake_cc, monkeypatch, qpsol, enabled
):
    """``solver_options.codegen`` reaches the build of either QP model's Functions (the
    dense one's and the sparse one's), with ``AEROMANIP_CODEGEN`` allowing it: the
    compiler (a stand-in that records its start and fails) runs only when asked."""
    from aeromanip.nmpc.strategies import Weighted

    monkeypatch.setenv("AEROMANIP_CODEGEN", "1")
    opts = {"codegen": enabled, "qpsol": qpsol, "seed": "none"}
    Weighted(make_problem(levels=(0, 0), horizon=2), "sqp", opts)
    assert fake_cc.exists() is enabled


def test_a_buffered_function_evaluates_in_place_and_refuses_a_wrong_argument_count():
    """``Buffered``: the Function's value in its preallocated output (by hand here),
    overwritten by the next call; a call with fewer or more arguments than the Function
    has inputs is an error, not an evaluation on the last call's leftovers."""
    x, y = ca.SX.sym("x", 2), ca.SX.sym("y")
    f = ca.Function("aeromanip_buffered", [x, y], [x * y, ca.sumsqr(x)])
    buf = codegen.Buffered(f)
    out = buf(np.array([1.0, 2.0]), np.array([3.0]))
    np.testing.assert_array_equal(out[0], [3.0, 6.0])
    assert out[1][0] == 5.0
    again = buf(np.array([0.5, 0.0]), np.array([2.0]))
    assert again[0] is out[0] and out[0].tolist() == [1.0, 0.0]
    for args in ((np.array([1.0, 1.0]),), (np.array([1.0, 1.0]), np.ones(1), np.ones(1))):
        with pytest.raises(ValueError):
            buf(*args)
