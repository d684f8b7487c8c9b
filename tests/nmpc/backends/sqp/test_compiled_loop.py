"""The SQP loop in compiled C (``compiled_loop``) against the Python loop and LAPACK.

Truth: the Python loop (``SqpBackend._python_sqp``, itself tested against IPOPT) on
the same problems, step by step in closed loop; NumPy's LAPACK ``eigh`` for the C
eigensolver that convexifies indefinite Hessians. The step around the loop runs in Python
here (``compiled_step = false``); the whole step compiled is
``tests/nmpc/test_compiled_controller.py``'s.
"""

import ctypes
import logging
import os
import shutil
from dataclasses import replace

import numpy as np
import pytest

from aeromanip.bench.controller_speed import _stepper, bench_scenario
from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends.cache import CacheEntry
from aeromanip.nmpc.backends.sqp import compiled_loop
from aeromanip.nmpc.backends.sqp.solver import SqpBackend
from aeromanip.nmpc.controller import Controller

pytestmark = pytest.mark.codegen

EQUAL = 1e-8  # [rad/s, m/s] the commands of the two loops
STEPS = 16  # closed-loop steps per case (8 s of the flight)


@pytest.fixture(autouse=True)
def _codegen_on(monkeypatch):
    monkeypatch.setenv("AEROMANIP_CODEGEN", "1")


def closed_loop(kind, strategy, backend, compiled, options=None):
    """The commands and statuses of ``STEPS`` steps of the ideal loop."""
    sc = bench_scenario(kind, STEPS * 0.5)
    ctrl, step = _stepper(
        sc,
        strategy,
        backend,
        {**(options or {}), "compiled_loop": compiled, "compiled_step": False},
    )
    loops = [getattr(ls.backend, "loop", None) for ls in ctrl.strategy.solvers]
    assert all((lp is not None) == compiled for lp in loops)
    x, us, oks, its = sc.x0.copy(), [], [], []
    for k in range(sc.steps):
        u, it, ok = step(x, k * sc.problem.dt)
        us.append(u)
        oks.append(ok)
        its.append(it)
        x = x + sc.problem.dt * u
    return np.array(us), oks, its


@pytest.mark.parametrize(
    "kind, strategy, backend",
    [
        ("flight", "weighted", "sqp"),
        ("flight", "weighted", "sqp-rti"),
        ("fast", "weighted", "sqp"),  # velocity bounds bind: exact Hessians, corrections
        # a strict hierarchy runs the same loop per level; the stagewise one also puts
        # its cost rows' curvature in the Hessian
        ("fast", "stagewise", "sqp"),
    ],
)
def test_the_compiled_loop_gives_the_python_loops_commands(kind, strategy, backend):
    py_u, py_ok, py_it = closed_loop(kind, strategy, backend, compiled=False)
    c_u, c_ok, c_it = closed_loop(kind, strategy, backend, compiled=True)
    assert all(py_ok) and c_ok == py_ok
    assert c_it == py_it  # the same iterations, step by step
    np.testing.assert_allclose(c_u, py_u, rtol=0, atol=EQUAL)


def test_a_bounded_loop_judges_its_last_iterate_as_the_python_loop():
    """Four QPs a solve, the iterate at the fourth the answer where its rows hold
    (``accept_at_max_iter``): the strict hierarchy's second level, along the first's
    curved rows, runs out with them held or not, step by step alike."""
    bounded = {"seed": "none", "max_iter": 4, "accept_at_max_iter": True}
    py_u, py_ok, py_it = closed_loop("fast", "hierarchical", "sqp", False, bounded)
    c_u, c_ok, c_it = closed_loop("fast", "hierarchical", "sqp", True, bounded)
    assert c_ok == py_ok and not all(py_ok)  # some steps partial
    assert c_it == py_it
    np.testing.assert_allclose(c_u, py_u, rtol=0, atol=EQUAL)


def test_the_loops_options_are_in_the_order_the_c_loop_reads_them():
    import re

    from aeromanip.nmpc.backends.sqp.solver import LOOP_OPTIONS

    header = (compiled_loop.HERE / "sqp_loop.h").read_text()
    enum = re.search(r"enum \{\s*(OPT_MAX_ITER.*?)\};", header, re.DOTALL)[1]
    names = [n.lower()[4:] for n in re.findall(r"\b(OPT_[A-Z_]+)\b", enum)]
    assert names == [*LOOP_OPTIONS, "count"]


def test_the_eigensolver_agrees_with_lapack():
    lib = compiled_loop.loop_library()
    assert lib is not None
    eig = lib.sqp_eigen_symmetric
    eig.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p,
                    ctypes.c_void_p]  # fmt: skip
    rng = np.random.default_rng(7)
    for n in (1, 2, 7, 70):
        M = rng.standard_normal((n, n))
        S = np.asfortranarray(M + M.T)
        S[0, 0] -= 50.0  # indefinite, with a spread of magnitudes
        lam, V, e = np.zeros(n), np.zeros((n, n), order="F"), np.zeros(n)
        eig(S.ctypes.data, n, lam.ctypes.data, V.ctypes.data, e.ctypes.data)
        scale = np.abs(S).max()
        np.testing.assert_allclose(np.sort(lam), np.linalg.eigh(S)[0], atol=1e-12 * scale)
        np.testing.assert_allclose((V * lam) @ V.T, S, atol=1e-12 * scale)
        np.testing.assert_allclose(V.T @ V, np.eye(n), atol=1e-12)


def test_a_damaged_loop_library_is_rebuilt(monkeypatch, tmp_path):
    monkeypatch.setenv("AEROMANIP_CACHE", str(tmp_path))
    assert compiled_loop.loop_library() is not None
    path = compiled_loop.loop_entry(shutil.which("gcc")).lib
    cut = path.with_suffix(".cut")
    cut.write_bytes(path.read_bytes()[:100])
    os.replace(cut, path)  # truncated (a new file: the loaded one stays mapped)
    assert not CacheEntry(path).valid()
    again = compiled_loop.loop_library()
    assert again is not None and CacheEntry(path).valid()


def test_without_a_compiler_the_python_loop_runs(monkeypatch, caplog):
    monkeypatch.setenv("CC", "/nonexistent/cc")
    assert compiled_loop.loop_library() is None


def test_where_the_loop_does_not_apply_the_python_loop_runs():
    sc = bench_scenario("flight", 1.0)
    for options in ({"qpsol": "qpoases"}, {"qpsol_options": {"print_time": False}},
                    {"compiled_loop": False}):  # fmt: skip
        ctrl, _ = _stepper(sc, "weighted", "sqp", options)
        assert ctrl.strategy.solvers[0].backend.loop is None, options


def test_a_bad_compiled_loop_option_is_one_line():
    with pytest.raises(
        ConfigError, match=r"^solver_options.compiled_loop: 'yes' is not true or false$"
    ):
        SqpBackend.checked_options({"compiled_loop": "yes"})


def test_a_build_failure_is_one_warning(monkeypatch, tmp_path, caplog):
    monkeypatch.setenv("AEROMANIP_CACHE", str(tmp_path))
    loop = compiled_loop
    for name in (*loop.SOURCES, *loop.HEADERS, *loop.DAQP_SOURCES, *loop.DAQP_HEADERS):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text("this is not C\n")
    with caplog.at_level(logging.WARNING):
        assert compiled_loop.loop_library(tmp_path) is None
    assert "building the compiled SQP loop failed" in caplog.text


def test_a_failing_solve_ends_as_in_the_python_loop():
    """DAQP held to 2 iterations: the SQP runs out of iterations; both loops report it
    alike and the controller falls back alike."""
    outcomes = {}
    for compiled in (False, True):
        sc = bench_scenario("fast", 2.0)
        qp = {"daqp": {"iter_limit": 2}}
        opts = {
            "compiled_loop": compiled,
            "compiled_step": False,
            "seed": "none",
            "qpsol_options": qp,
        }
        ctrl = Controller(sc.problem, "weighted", "sqp", opts)
        assert (ctrl.strategy.solvers[0].backend.loop is not None) == compiled
        x, rows = sc.x0.copy(), []
        for k in range(sc.steps):
            cmd = ctrl.step(x, k * sc.problem.dt)
            rows.append((cmd.status, cmd.message, cmd.u))
            x = x + sc.problem.dt * cmd.u
        outcomes[compiled] = rows
    assert {r[0] for r in outcomes[True]} == {"stopped"}
    for py, c in zip(outcomes[False], outcomes[True], strict=True):
        assert c[:2] == py[:2] == ("stopped", "Maximum_Iterations_Exceeded")
        np.testing.assert_array_equal(c[2], py[2])


def _restarts_at_a_solution(compiled):
    """Iterations of a warm and of a cold solve, both started at the first step's
    solution (the warm one with its multipliers, the cold one without any)."""
    sc = bench_scenario("flight", 1.0)
    opts = {"compiled_loop": compiled, "compiled_step": False, "seed": "none"}
    ctrl = Controller(sc.problem, "weighted", "sqp", opts)
    backend = ctrl.strategy.solvers[0].backend
    assert (backend.loop is not None) == compiled
    requests, solve = [], backend.solve
    backend.solve = lambda r: requests.append(r) or solve(r)
    ctrl.step(sc.x0, 0.0)
    at = replace(requests[0], shift=False)
    sol = solve(at)
    assert sol.success
    warm = solve(replace(at, w0=sol.w, lam_g0=sol.lam_g, lam_x0=sol.lam_x))
    cold = solve(replace(at, w0=sol.w, lam_g0=None, lam_x0=None))
    return warm.iterations, cold.iterations, cold.success


def test_a_cold_start_takes_a_step_even_at_the_solution_as_in_the_python_loop():
    """Without multipliers the tolerances are not judged before a first QP, even from
    the solution itself; with them, that solution is accepted at once (both loops)."""
    py = _restarts_at_a_solution(compiled=False)
    assert py[0] == 0 and py[1] >= 1 and py[2]
    assert _restarts_at_a_solution(compiled=True) == py
