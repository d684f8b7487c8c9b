"""Compiled CasADi Functions: built once, cached on disk, the same answers as in-process."""

import casadi as ca
import numpy as np
import pytest

from aeromanip.nmpc.backends.codegen import compiled
from aeromanip.nmpc.controller import Controller
from test_sqp import FAST, X0, make_problem

pytestmark = pytest.mark.codegen


def test_compiled_functions_are_cached_and_agree(tmp_path, monkeypatch):
    monkeypatch.setenv("AEROMANIP_CACHE", str(tmp_path))
    x = ca.SX.sym("x", 3)
    f = ca.Function("aeromanip_test_f", [x], [ca.sin(x) * ca.sumsqr(x), ca.jacobian(x**3, x)])
    g = compiled(f)
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


@pytest.mark.parametrize("cc", ["false", "no-such-compiler-xyz"])
def test_without_a_working_compiler_functions_run_in_process(tmp_path, monkeypatch, cc):
    monkeypatch.setenv("AEROMANIP_CACHE", str(tmp_path))
    monkeypatch.setenv("CC", cc)
    x = ca.SX.sym("x", 2)
    f = ca.Function("aeromanip_test_cc", [x], [ca.sumsqr(x)])
    assert compiled(f) is f
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
