"""Documented contracts of the NMPC layer that no closed-loop test pins down.

Truths: ``base.casadi_message`` (one line, without suggestions or listings),
``codegen.cache_dir`` (``$AEROMANIP_CACHE`` or ``~/.cache/aeromanip``, as docs/guide.md
says), ``codegen.limit_blas_threads`` (read back with OpenBLAS's own getter), the QP
solvers themselves (a failed QP reports the status DAQP / qpOASES give for the same QP),
and the controller's and transcription's docstrings (warm starts, budgets, refusals,
path rows). The SQP's own contracts: tests/nmpc/backends/sqp/ (test_solver_options.py,
test_line_search.py, test_sqp_answer.py); its sparse model:
tests/nmpc/backends/sqp/test_sparse_qp.py; the ``nlpsol`` backends:
tests/nmpc/backends/test_nlpsol.py.
"""

from __future__ import annotations

import ctypes
import hashlib
import logging
import math
from pathlib import Path
from types import SimpleNamespace

import casadi as ca
import numpy as np
import pytest

from aeromanip.errors import ConfigError, InfeasibleProblemError, StateError
from aeromanip.nmpc.backends import codegen
from aeromanip.nmpc.backends.base import NlpResult, casadi_message
from aeromanip.nmpc.backends.cache import CacheEntry
from aeromanip.nmpc.backends.sqp.dense_qp import SOLVERS as QP_SOLVERS
from aeromanip.nmpc.backends.sqp.dense_qp import DenseQp
from aeromanip.nmpc.backends.sqp.solver import (
    DEFAULTS,
    SqpBackend,
)
from aeromanip.nmpc.constraints import Bounds, Clearance, UserConstraint
from aeromanip.nmpc.controller import Controller
from aeromanip.nmpc.model import RateModel
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.strategies import Hierarchical, LevelSolver, Weighted, _solve_level
from aeromanip.references import Constant
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import CogAlignment, ControlRate, EndEffectorTracking
from aeromanip.tasks.posture import Posture
from nmpc_helpers import X0, rest

# --- small helpers with a documented contract -------------------------------------------------


def test_casadi_message_keeps_the_messages_and_drops_locations_suggestions_and_listings():
    text = (
        ".../casadi/core/function_internal.cpp:145: Error calling Ipopt::init for 'solver':\n"
        ".../casadi/core/options.cpp:255: Unknown option: print_tim\n"
        "Did you mean one of the following?\n"
        '> "print_time"          [OT_BOOL]\n'
    )
    assert casadi_message(RuntimeError(text)) == "Unknown option: print_tim"
    two = "first problem:\n.../x/y.cpp:1: second problem\n> listing"
    assert casadi_message(RuntimeError(two)) == "first problem; second problem"
    assert casadi_message(RuntimeError("  \n> only a listing")) == "> only a listing"
    # CasADi's call-stack lines go; a message's own trailing letters stay
    wrapped = (
        "Error in Function::call for 'f' [SXFunction] at .../function.cpp:1458:\n"
        ".../casadi/core/x.cpp:9: dimension mismatch for input X:"
    )
    assert casadi_message(RuntimeError(wrapped)) == "dimension mismatch for input X"
    long = "> " + "y" * 300  # nothing kept: the text itself, cut at 200 characters
    assert casadi_message(RuntimeError(long)) == long[:200]


def test_a_cache_entry_records_a_checksum_that_sha256sum_can_check(tmp_path):
    """The layout of the module docstring (``<lib>.sha256`` holding the hex digest, as
    ``sha256sum`` prints it), read back with hashlib; a changed library is not valid."""
    built = tmp_path / "build" / "f.so"
    built.parent.mkdir()
    payload = bytes(range(256)) * 5000  # > one hashing chunk
    built.write_bytes(payload)
    entry = CacheEntry(tmp_path / "f-abc.so")
    assert not entry.valid()
    entry.install(built)
    recorded = (tmp_path / "f-abc.so.sha256").read_text()
    assert recorded == hashlib.sha256(payload).hexdigest() + "\n"
    assert entry.valid() and not built.exists()
    entry.lib.write_bytes(payload[:-1])  # truncated
    assert not entry.valid()
    entry.discard()
    assert not entry.lib.exists() and not (tmp_path / "f-abc.so.sha256").exists()


def test_cache_dir_is_the_environment_variable_or_the_users_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("AEROMANIP_CACHE", str(tmp_path / "c"))
    assert codegen.cache_dir() == tmp_path / "c"
    monkeypatch.delenv("AEROMANIP_CACHE")
    monkeypatch.setenv("HOME", str(tmp_path))
    assert codegen.cache_dir() == Path(tmp_path) / ".cache" / "aeromanip"


def test_a_warning_is_logged_once(caplog):
    msg = "codegen: test_nmpc_contract warning"
    codegen._warned.discard(msg)  # as if new in this process
    with caplog.at_level(logging.WARNING):
        codegen._warn_once(msg)
        codegen._warn_once(msg)
    assert [r.getMessage() for r in caplog.records].count(msg) == 1


# --- the QP layer: a failed solve reports the QP solver's own status -----------------------------


@pytest.mark.parametrize("solver", ["daqp", "qpoases"])
def test_an_infeasible_screened_qp_reports_the_solvers_status_and_no_multipliers(solver):
    """20 rows, one of them near its bound (so the first round is a screened 8-row QP):
    ``x1 + x2 >= 5`` with ``|x| <= 1`` has no solution."""
    n, m = 2, 20
    A = np.random.default_rng(0).normal(size=(m, n))
    lba, uba = np.full(m, -100.0), np.full(m, 100.0)
    A[0], lba[0], uba[0] = (1.0, 1.0), 5.0, np.inf
    args = (np.eye(n), np.zeros(n), A, lba, uba, -np.ones(n), np.ones(n))
    res = DenseQp(n, m, solver).solve(*args)
    assert res.ok is False
    assert not res.lam_a.any()
    opts = {"error_on_fail": False, "print_time": False, **QP_SOLVERS[solver]}
    sparsity = {"h": ca.Sparsity.dense(n, n), "a": ca.Sparsity.dense(m, n)}
    direct = ca.conic("direct", solver, sparsity, opts)
    names = ("h", "g", "a", "lba", "uba", "lbx", "ubx")
    direct(**dict(zip(names, args, strict=True)))
    raw = direct.stats()["return_status"]
    if solver == "daqp":  # its exit flag by the name DAQP gives it
        assert raw == -1 and res.status == "infeasible (DAQP exit flag -1)"
    else:
        assert res.status == str(raw) != ""


# --- BLAS threads: set in the library NumPy loaded (its own getter reads them back) --------------


def _numpy_openblas():
    libs = Path(np.__file__).parent.parent / "numpy.libs"
    found = sorted(libs.glob("*openblas*.so*")) if libs.is_dir() else []
    if not found or not Path("/proc/self/maps").exists():
        pytest.skip("needs Linux and NumPy's bundled OpenBLAS")
    lib = ctypes.CDLL(str(found[0]))
    for name in ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads",
                 "openblas_get_num_threads64_", "openblas_get_num_threads"):  # fmt: skip
        if hasattr(lib, name):
            return str(found[0]), getattr(lib, name)
    pytest.skip("OpenBLAS without a thread-count getter")


def test_limit_blas_threads_sets_numpys_openblas():
    path, get = _numpy_openblas()
    before = get()
    try:
        for n in (2, 1):
            assert path in codegen.limit_blas_threads(n)
            assert get() == n
    finally:
        codegen.limit_blas_threads(before)


def test_limit_blas_threads_defaults_to_one_and_touches_only_openblas(monkeypatch):
    """One thread by default; only mapped files named like OpenBLAS are opened (a library
    that links OpenBLAS, e.g. NumPy's core, is not counted); one that will not load is
    skipped and the next one still set."""
    path, get = _numpy_openblas()
    before = get()
    try:
        codegen.limit_blas_threads(2)
        done = codegen.limit_blas_threads()
        assert get() == 1 and path in done
        assert all("openblas" in Path(p).name.lower() for p in done)
        maps = [f"7f00-7f01 r-xp 0 08:01 1 {p}\n" for p in ("/nowhere/libopenblas_a.so", path)]
        monkeypatch.setattr(codegen, "open", lambda *a, **k: _Lines(maps), raising=False)
        codegen.limit_blas_threads(2)
        assert get() == 2
    finally:
        monkeypatch.undo()
        codegen.limit_blas_threads(before)


class _Lines(list):
    """A stand-in for an open text file: its lines, as a context manager."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


# --- warm start with rate responses: the guess starts from the measured rates --------------------

TAU = np.array([0.3, 0.25, 0.2, 0.08, 0.0, 0.0, 0.05])  # s; joints 1-2 follow at once


def test_guesses_start_from_the_measured_rates_which_then_decay_as_a_first_order_lag():
    """Controller.step's ``rates`` are the actual rates at the plan's start: the first
    guess (rest at x0) and the next one (the last plan shifted) start from them, and under
    the guess's commands a lagged rate follows ``r' = (u - r) / tau``."""
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 3, 0.1, Bounds.from_robot(x8), response_tau=TAU)
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0)
    pb.add_task(ControlRate(), weight=0.1, level=None)
    ctrl = Controller(pb, "weighted", "ipopt")
    guesses = []
    solve = ctrl.strategy.solve

    def recording(p, gs):
        guesses.append(np.array(gs[0]))
        return solve(p, gs)

    ctrl.strategy.solve = recording
    tr, lag = ctrl.strategy.transcription, np.flatnonzero(TAU > 0)
    x0 = np.array([0.0, 0.0, 1.0, 0.0, 0.3, 0.4, -0.8])
    rng = np.random.default_rng(5)
    for k in range(2):
        rates = rng.uniform(-0.3, 0.3, 7)
        cmd = ctrl.step(x0, k * pb.dt, rates=rates)
        assert cmd.status == "ok"
        Z = guesses[k][tr.index_z]
        _, U = tr.unpack(guesses[k])
        np.testing.assert_allclose(Z[0, 14:], rates[lag], rtol=0, atol=1e-15)
        # exact solution of the lag over one period with the command held
        a = np.exp(-pb.dt / TAU[lag])
        np.testing.assert_allclose(Z[1, 14:], U[0][lag] + a * (rates[lag] - U[0][lag]), atol=1e-12)
        x0 = x0 + pb.dt * cmd.u


def test_auto_qp_solver_is_dense_up_to_condense_max_horizon_then_sparse():
    opts = {**DEFAULTS, "qpsol": "auto", "condense_max_horizon": 12}
    picked = [SqpBackend.pick_qp(opts, n) for n in (1, 12, 13, 100)]
    assert picked == ["daqp"] * 2 + ["riccati"] * 2
    for named in ("daqp", "qpoases", "riccati", "hpipm"):
        assert SqpBackend.pick_qp({**opts, "qpsol": named}, 1) == named
        assert SqpBackend.pick_qp({**opts, "qpsol": named}, 100) == named


def test_reset_with_a_wrong_previous_command_names_it(small_problem):
    ctrl = Controller(small_problem, "weighted", "ipopt")
    with pytest.raises(StateError, match=r"^u_prev: expected 7 values \(x, y, z, yaw, q1"):
        ctrl.reset(u_prev=[0.0, 1.0])
    with pytest.raises(StateError, match=r"^u_prev: expected 7 numbers"):
        ctrl.reset(u_prev="fast")
    ctrl.reset(u_prev=np.arange(7.0))
    np.testing.assert_array_equal(ctrl.u_prev, np.arange(7.0))


@pytest.mark.parametrize(
    ("state", "t", "rates", "message"),
    [
        ([0.0] * 6, 0.0, None, r"state: expected 7 values \(x, y, z, yaw, q1, q2, q3\), got 6"),
        (X0, 0.0, [0.0, 1.0], r"rates: expected 7 values \(x, y, z, yaw, q1, q2, q3\), got 2"),
        (X0, 0.0, [0.0] * 5 + [math.inf, 0.0], r"rates: q2 is not finite \(inf\)"),
        (X0, math.nan, None, r"t: must be a finite number of seconds, got nan"),
        (X0, math.inf, None, r"t: must be a finite number of seconds, got inf"),
        (X0, "0.5", None, r"t: must be a finite number of seconds, got '0.5'"),
        (X0, True, None, r"t: must be a finite number of seconds, got True"),
    ],
)
def test_a_step_refuses_bad_input_with_one_line_naming_it(small_problem, state, t, rates, message):
    """Before any solve: the state and the measured rates as 7 finite numbers (each error
    names the vector and the entry), the time a finite number of seconds."""
    ctrl = Controller(small_problem, "weighted", "ipopt")
    with pytest.raises(StateError, match=f"^{message}$"):
        ctrl.step(state, t, rates)


# --- the command reports the solver's effort; a solve over budget is a failure -----------------


def _recorded(ctrl, solve_time_s=None):
    """Record the strategy's answers (with ``solve_time_s`` in place of the measured one)."""
    results = []
    solve = ctrl.strategy.solve

    def recording(p, gs):
        results.append(solve(p, gs))
        if solve_time_s is not None:
            results[-1].solve_time_s = solve_time_s
        return results[-1]

    ctrl.strategy.solve = recording
    return results


def test_the_command_reports_the_iterations_and_time_of_its_solve(small_problem):
    ctrl = Controller(small_problem)  # by default: the weighted sum, solved by IPOPT
    assert type(ctrl.strategy) is Weighted and ctrl.strategy.solvers[0].backend.name == "ipopt"
    results = _recorded(ctrl)
    cmd = ctrl.step(X0, 0.0)
    assert cmd.status == "ok" and cmd.message == ""
    assert cmd.iterations == results[0].iterations and cmd.iterations > 0
    assert type(cmd.iterations) is int
    assert cmd.solve_time_s == results[0].solve_time_s > 0


def test_a_solve_over_the_time_budget_is_a_failure_that_says_both_times_in_ms(small_problem):
    ctrl = Controller(small_problem, "weighted", "ipopt", time_budget_s=0.25)
    results = _recorded(ctrl, solve_time_s=0.3)  # as if the solve had taken 300 ms
    cmd = ctrl.step(X0, 0.0)
    assert results[0].success and cmd.status == "stopped"  # no earlier plan to fall back on
    assert cmd.message == "over budget: 300.0 ms > 250.0 ms"
    assert cmd.iterations == results[0].iterations
    np.testing.assert_array_equal(cmd.u, np.zeros(7))
    ctrl.reset()
    _recorded(ctrl, solve_time_s=0.25)  # at the budget: in time
    assert ctrl.step(X0, 0.0).status == "ok"


# --- bounds and hierarchies: documented refusals and partial results ----------------------------


def test_command_rate_bounds_must_be_positive_numbers():
    b = Bounds.from_robot(load_robot("x8-3dof"))
    assert b.with_accel(np.full(7, 2.0)).accel is not None
    for bad in (np.r_[np.nan, np.ones(6)], np.r_[0.0, np.ones(6)], np.ones(6)):
        with pytest.raises(ConfigError, match=r"^bounds\.acceleration: expected 7 values > 0"):
            b.with_accel(bad)


def test_a_failed_middle_level_keeps_the_higher_levels_solution():
    """Three levels, the second one fails: the first level's solution is applied
    (``partial``), with the first two levels reported and no third."""
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 3, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0, level=0)
    pb.add_task(CogAlignment(), weight=1.0, level=1)
    pb.add_task(Posture(["yaw"]), weight=1.0, level=2)
    pb.add_task(ControlRate(), weight=0.1, level=None)
    h = Hierarchical(pb, "stagewise")
    tr = h.transcription
    n = tr.w.numel()

    def failing(*args, **kw):
        return NlpResult(np.full(n, np.nan), np.zeros(tr.g.numel()), np.zeros(n), np.nan,
                         False, "Infeasible_Problem_Detected", 3, 0.0)  # fmt: skip

    h.solvers[1].backend.solve = failing
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    res = h.solve(p, [tr.pack(*rest(pb), np.zeros(7))])
    assert res.success and res.status == "partial: Infeasible_Problem_Detected"
    # through the controller: level 0's command flies, reported as partial
    ctrl = Controller(pb, "hierarchical", hierarchy={"mode": "stagewise"})
    ctrl.strategy.solvers[1].backend.solve = failing
    cmd = ctrl.step(X0, 0.0)
    assert (cmd.status, cmd.message) == ("partial", "partial: Infeasible_Problem_Detected")
    np.testing.assert_allclose(cmd.u, tr.unpack(res.level_w[0])[1][0], atol=1e-6)
    assert [(r.level, r.success) for r in res.levels] == [(0, True), (1, False)]
    assert len(res.level_w) == 1
    np.testing.assert_array_equal(res.w, res.level_w[0])
    assert abs(res.levels[0].loss) < 1e-12  # the applied solution is level 0's own


def test_a_nan_in_either_side_of_a_box_is_refused():
    b = Bounds.from_robot(load_robot("x8-3dof"))
    for side in ("x_lower", "x_upper", "u_lower", "u_upper"):
        values = getattr(b, side).copy()
        values[5] = np.nan
        kind = side[0]
        with pytest.raises(ConfigError, match=rf"^bounds\.{kind}\.q2: must not be NaN"):
            Bounds(**{**vars(b), side: values})
        with pytest.raises(ConfigError, match=rf"^bounds\.{kind}: expected 7 entries"):
            Bounds(**{**vars(b), side: values[:6]})  # either side's length alone


def test_integer_time_constants_give_the_same_first_order_response():
    """``a = exp(-dt / tau)``: whole seconds given as integers are seconds."""
    ints, floats = np.array([1, 2, 0, 0, 0, 0, 3]), np.array([1.0, 2.0, 0, 0, 0, 0, 3.0])
    A_i, B_i = RateModel(7, 0.1, ints).matrices(0.1)
    A_f, B_f = RateModel(7, 0.1, floats).matrices(0.1)
    np.testing.assert_array_equal(A_i, A_f)
    np.testing.assert_array_equal(B_i, B_f)
    lag_rows = 14 + np.arange(3)
    np.testing.assert_allclose(np.diag(A_f)[lag_rows], np.exp(-0.1 / floats[[0, 1, 6]]))


# --- a failed warm solve is retried cold; the step reports both attempts -------------------------


class Scripted:
    """A backend that answers from a script and records what it was given."""

    bounded_iterations = False  # a solve out of iterations is retried (``Backend``'s)

    def __init__(self, *answers):
        self.answers, self.calls = list(answers), []

    def solve(self, r):
        self.calls.append((np.array(r.w0), r.lam_g0, r.lam_x0, (r.p, r.lbg, r.ubg)))
        return self.answers.pop(0)


def _result(ok, status, w, t, it):
    return NlpResult(np.array(w, float), np.ones(2), np.ones(3), 1.0, ok, status, it, t)


@pytest.mark.parametrize(
    ("status", "restart"),
    [("Infeasible_Problem_Detected", "w0"), ("Maximum_Iterations_Exceeded", "last")],
)
def test_a_failed_warm_solve_is_retried_cold_and_both_attempts_are_counted(status, restart):
    w0, last = np.zeros(3), np.array([0.1, 0.2, 0.3])
    backend = Scripted(_result(False, status, last, 0.25, 7), _result(True, "ok", last, 0.5, 3))
    warm = _result(True, "ok", last, 0.1, 1)
    st = LevelSolver([], SimpleNamespace(lbg=np.zeros(2)), backend, warm=warm)
    p, ubg = np.array([7.0]), np.array([1.0, 2.0])
    res = _solve_level(st, p, w0, ubg)
    assert (res.success, res.iterations, res.solve_time_s) == (True, 10, 0.75)
    (w_warm, lam_g1, lam_x1, nlp1), (w_cold, lam_g2, lam_x2, nlp2) = backend.calls
    for given in (nlp1, nlp2):  # both attempts solve the same NLP
        assert given[0] is p and given[1] is st.tr.lbg and given[2] is ubg
    np.testing.assert_array_equal(w_warm, w0)
    assert lam_g1 is warm.lam_g and lam_x1 is warm.lam_x  # warm: the last multipliers
    assert lam_g2 is None and lam_x2 is None  # the retry: cold
    np.testing.assert_array_equal(w_cold, w0 if restart == "w0" else last)
    assert st.warm is res


# --- path constraints: rows and bounds at stages 1..N, without command rows at N ---------------


def test_path_rows_at_each_stage_carry_their_own_constraints_bounds():
    """``PathConstraint``: ``lower <= expression <= upper`` at stages 1..N; one that
    uses the command is not applied at stage N (there is no command there)."""
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 3, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0)
    pb.add_constraint(UserConstraint("height", lambda st: st.x[2], 0.5, 3.0))
    pb.add_constraint(UserConstraint("yaw_rate", lambda st: st.u[3], -0.3, 0.2, uses_command=True))
    tr = Weighted(pb, "ipopt").transcription
    kind, stage = np.asarray(tr.g_kind), np.asarray(tr.g_stage)
    lbg, ubg = np.asarray(tr.lbg, float).ravel(), np.asarray(tr.ubg, float).ravel()
    X, U = rest(pb)
    U[:, 3] = [0.1, -0.2, 0.05]
    X = X0 + np.vstack([np.zeros(7), np.cumsum(pb.dt * U, axis=0)])
    g = np.asarray(ca.Function("g", [tr.w, tr.p], [tr.g])(
        tr.pack(X, U, np.zeros(7)), tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    )).ravel()  # fmt: skip
    assert not np.any((stage == 0) & np.isin(kind, ["path", "terminal"]))
    for k in (1, 2):
        rows = np.flatnonzero((kind == "path") & (stage == k))
        np.testing.assert_array_equal(lbg[rows], [0.5, -0.3])
        np.testing.assert_array_equal(ubg[rows], [3.0, 0.2])
        np.testing.assert_allclose(g[rows], [X[k, 2], U[k, 3]], atol=1e-15)
    rows = np.flatnonzero((kind == "terminal") & (stage == 3))
    np.testing.assert_array_equal((lbg[rows], ubg[rows]), ([0.5], [3.0]))
    np.testing.assert_allclose(g[rows], [X[3, 2]], atol=1e-15)


def test_clearance_keeps_the_named_points_in_their_order_and_refuses_a_non_finite_d_min():
    """``Clearance(points=...)``: one row per named point, in the order given, each the
    depth the default constraint gives that point (its points: joint2, joint3, ee), all
    bounded below by ``d_min``."""
    from aeromanip.robot.kinematics import Kinematics
    from aeromanip.tasks.base import Stage

    kin = Kinematics(load_robot("x8-3dof"))
    stage = Stage(kin, ca.DM(X0), ca.DM.zeros(7), ca.DM.zeros(7), ca.DM.zeros(0), 0.1)

    def rows(c):
        r = c.expression(stage)
        return np.asarray(ca.evalf(r.expr)).ravel(), r.lower, r.upper

    every, _, _ = rows(Clearance(0.1))
    named, lower, upper = rows(Clearance(0.05, points=("ee", "joint2")))
    assert every.size == 3 and np.ptp(every) > 0.01
    np.testing.assert_array_equal(named, every[[2, 0]])
    np.testing.assert_array_equal(lower, [0.05, 0.05])
    assert np.isinf(upper).all()
    for bad in (float("nan"), float("inf")):
        with pytest.raises(ConfigError, match=rf"^clearance\.d_min: must be finite, got {bad}$"):
            Clearance(bad)


def test_a_user_constraint_whose_bounds_cross_is_refused_by_its_name_and_entry():
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 2, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0)
    pb.add_constraint(UserConstraint("level", lambda st: st.x[2], 1.0, 1.0))  # equal: fine
    Weighted(pb, "ipopt")
    pb.add_constraint(UserConstraint("ee_box", lambda st: st.x[:3], [0.0, 2.0, 0.5], 1.5))
    with pytest.raises(InfeasibleProblemError, match=r"^constraint 'ee_box'\[1\]: lower is above"):
        Weighted(pb, "ipopt")


def test_condensed_qp_moves_each_state_bound_row_to_its_twin_one_stage_on():
    """The dense QP's rows end with the bounded state entries (``state_idx`` into the
    NLP's variables); after ``shift()`` each one is predicted by the same entry one stage
    on (``stride`` variables later), or by itself at the last stage (10 stages: every
    joint's bound rows at every stage)."""
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 10, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0)
    opts = {"codegen": False, "qpsol": "daqp"}
    if "seed" in DEFAULTS:
        opts["seed"] = "none"
    strat = Weighted(pb, "sqp", opts)
    tr, model = strat.transcription, strat.solvers[0].backend.model
    sidx, nk = model.state_idx, model.nk
    assert sidx.size > 0 and model.qp.shift_rows.size == nk + sidx.size
    where = {int(i): nk + r for r, i in enumerate(sidx)}
    for r, i in enumerate(sidx):
        assert model.qp.shift_rows[nk + r] == where.get(int(i) + tr.stride, nk + r)
    assert any(int(i) + tr.stride in where for i in sidx)


def test_bounds_as_dict_lists_each_finite_bound_under_its_log_column():
    """Keys as in log.csv (``z``, ``q1``, ``u_x``); a one-sided bound is listed (with its
    infinite side), an unbounded entry is not."""
    x8 = load_robot("x8-3dof")
    b = Bounds.from_robot(x8, platform_box={"z": (0.8, np.inf)}, velocity_limits=False)
    d = b.as_dict()
    assert d["z"] == [0.8, np.inf]
    assert d["q2"] == [-1.6, 1.6] and "x" not in d and "yaw" not in d
    assert not any(k.startswith("u_") for k in d)  # no command bounds asked: none at all
    assert np.all(b.u_lower == -np.inf) and np.all(b.u_upper == np.inf)
    v = Bounds.from_robot(x8).as_dict()
    assert v["u_x"] == [-1.0, 1.0] and v["u_q3"] == [-1.0, 1.0] and "U_x" not in v
    assert v["u_z"] == [-0.7, 0.7] and v["u_yaw"] == [-0.8, 0.8]  # x8-3dof.toml's own
