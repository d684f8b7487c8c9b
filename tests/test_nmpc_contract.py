"""Documented contracts of the NMPC layer that no closed-loop test pins down.

Truths: the docstrings and comments of ``sqp.DEFAULTS`` (each option's type and range,
``hessian``), ``sqp._go_exact`` (when "auto" goes exact), ``base.casadi_message`` (one
line, without suggestions or listings), ``codegen.cache_dir`` (``$AEROMANIP_CACHE`` or
``~/.cache/aeromanip``, as docs/guide.md says), ``codegen.limit_blas_threads`` (read back
with OpenBLAS's own getter) and the QP solvers themselves (a failed QP reports the status
DAQP / qpOASES give for the same QP).
"""

from __future__ import annotations

import ctypes
import hashlib
import logging
import math
import signal
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import casadi as ca
import numpy as np
import pytest

from aeromanip.errors import ConfigError, InfeasibleProblemError, StateError
from aeromanip.nmpc.backends import codegen
from aeromanip.nmpc.backends.base import NlpResult, casadi_message
from aeromanip.nmpc.backends.cache import CacheEntry
from aeromanip.nmpc.backends.multiple_shooting import MultipleShootingModel
from aeromanip.nmpc.backends.qp import SOLVERS as QP_SOLVERS
from aeromanip.nmpc.backends.qp import DenseQp, QpResult
from aeromanip.nmpc.backends.sqp import (
    DEFAULTS,
    EXACT_FROM_ITERATION,
    HESSIANS,
    OPTION_CHECKS,
    SqpBackend,
    _damping,
    _go_exact,
    _line_search,
    _number,
    _one_of,
)
from aeromanip.nmpc.constraints import Bounds, Clearance, UserConstraint
from aeromanip.nmpc.controller import Controller
from aeromanip.nmpc.model import RateModel
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.strategies import Hierarchical, LevelSolver, Weighted, _solve_level
from aeromanip.references import Constant
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import CogAlignment, CogVelocity, ControlRate, EndEffectorTracking
from aeromanip.tasks.posture import Posture

# --- the SQP's options: each one's valid edge and first invalid value -------------------------

GOOD = {
    "max_iter": [1, 50],
    "tol": [0, 0.0, 1e-6],  # 0: only the acceptable level ends a solve
    "acceptable_tol": [1e-12, 1],
    "constr_viol_tol": [1e-12, 2.5],
    "acceptable_iter": [1, 3],
    "rti": [True, False],
    "codegen": [True, False],
    "hessian": list(HESSIANS),
    "regularization": [0, 0.0, 1e-3],
    "qpsol": ["auto", "daqp", "qpoases", "hpipm"],
    "condense_max_horizon": [1, 40],
    "qpsol_options": [{}],
    "screen": [0, 0.0, 5.0],
    "blas_threads": [None, 1, 2],
}
BAD = {
    "max_iter": ([0, -1, 1.0, True, "5"], "an integer >= 1"),
    "tol": ([-1e-12, math.inf, math.nan, True, "1e-6", None], "a finite number >= 0"),
    "acceptable_tol": ([0, 0.0, -1.0, math.inf, False], "a finite number > 0"),
    "constr_viol_tol": ([0.0, math.nan], "a finite number > 0"),
    "acceptable_iter": ([0, 2.0], "an integer >= 1"),
    "rti": ([1, "true", None], "true or false"),
    "codegen": ([0, "false"], "true or false"),
    "hessian": (["Exact", "newton", None], "one of ['auto', 'exact', 'gauss-newton']"),
    "regularization": ([-1e-9, math.inf], "a finite number >= 0"),
    "qpsol": (["DAQP", "osqp"], "one of ['auto', 'daqp', 'qpoases', 'hpipm']"),
    "condense_max_horizon": ([0, 12.0], "an integer >= 1"),
    "qpsol_options": ([[], "x"], "a table"),
    "screen": ([-0.1, math.inf], "a finite number >= 0"),
    "blas_threads": ([0, 1.0, True], "an integer >= 1"),
}


def test_every_option_is_checked():
    assert set(OPTION_CHECKS) == set(DEFAULTS)
    assert set(GOOD) == set(BAD) <= set(DEFAULTS)


@pytest.mark.parametrize("key", sorted(GOOD))
def test_an_options_valid_values_are_kept(key):
    for value in GOOD[key]:
        opts = SqpBackend.checked_options({key: value})
        assert opts[key] is value
        assert {k: v for k, v in opts.items() if k != key} == {
            k: v for k, v in DEFAULTS.items() if k != key
        }


@pytest.mark.parametrize("key", sorted(BAD))
def test_an_options_invalid_values_name_the_key_the_value_and_what_is_allowed(key):
    values, allowed = BAD[key]
    for value in values:
        with pytest.raises(ConfigError) as e:
            SqpBackend.checked_options({key: value})
        assert str(e.value) == f"solver_options.{key}: {value!r} is not {allowed}"


def test_defaults_pass_their_own_checks():
    assert SqpBackend.checked_options(None) == DEFAULTS
    assert SqpBackend.checked_options({}) == DEFAULTS


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


# --- hessian = "auto" (sqp.DEFAULTS and _go_exact's docstring) ----------------------------------


def test_auto_hessian_goes_exact_at_the_first_short_step_or_the_seventh_iteration():
    condensed = object()  # any model but the multiple-shooting one
    assert not _go_exact(condensed, False, 1.0, 0)
    assert not _go_exact(condensed, False, 1.0, EXACT_FROM_ITERATION - 1)
    assert _go_exact(condensed, False, 1.0, EXACT_FROM_ITERATION)
    assert EXACT_FROM_ITERATION == 6  # "the 7th iteration" of DEFAULTS' comment, 0-based
    assert _go_exact(condensed, False, 0.5, 0)
    assert _go_exact(condensed, True, 1.0, 0)  # once exact, exact for the solve


def test_auto_hessian_on_the_sparse_model_goes_exact_near_a_solution_or_late():
    sparse = object.__new__(MultipleShootingModel)  # only its type matters here
    assert not _go_exact(sparse, False, 1.0, 1)
    assert _go_exact(sparse, False, 1.0, 2)  # a full step from the second iteration
    assert not _go_exact(sparse, True, 0.5, 2)  # back to Gauss-Newton after a short one
    assert not _go_exact(sparse, False, 0.5, EXACT_FROM_ITERATION - 1)
    assert _go_exact(sparse, False, 0.5, EXACT_FROM_ITERATION)  # where GN may cycle


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


# --- the hessian option reaches every QP of a solve ----------------------------------------------


@pytest.fixture(scope="module")
def small_problem():
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 3, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0)
    pb.add_task(ControlRate(), weight=0.1, level=None)
    return pb


@pytest.mark.parametrize(("hessian", "first"), [("exact", True), ("gauss-newton", False)])
def test_the_hessian_option_is_the_one_every_qp_uses(small_problem, hessian, first):
    opts = {"codegen": False, "hessian": hessian}
    if "seed" in DEFAULTS:  # no IPOPT seed: every iterate comes from the SQP's own QPs
        opts["seed"] = "none"
    strat = Weighted(small_problem, "sqp", opts)
    model = strat.solvers[0].backend.model
    flags = []
    step = model.step

    def recording(*args, **kw):
        flags.append(args[5] if len(args) > 5 else kw["exact"])
        return step(*args, **kw)

    model.step = recording
    tr = strat.transcription
    x0 = np.array([0.0, 0.0, 1.0, 0.0, 0.3, 0.4, -0.8])
    p = tr.parameters(x0, np.zeros(7), small_problem.stage_params(0.0))
    w0 = tr.pack(np.repeat(x0[None], 4, 0), np.zeros((3, 7)), np.zeros(7))
    assert strat.solve(p, [w0]).success
    assert flags and set(flags) == {first}


# --- warm start with rate responses: the guess starts from the measured rates --------------------

X0 = np.array([0.0, 0.0, 1.0, 0.0, 0.3, 0.4, -0.8])
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
    assert [SqpBackend.pick_qp(opts, n) for n in (1, 12, 13, 100)] == ["daqp"] * 2 + ["hpipm"] * 2
    for named in ("daqp", "qpoases", "hpipm"):
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


# --- the sparse (HPIPM) QP model: its step check and its merit ---------------------------------


@pytest.fixture(scope="module")
def sparse_model(small_problem):
    opts = {"codegen": False, "qpsol": "hpipm"}
    if "seed" in DEFAULTS:
        opts["seed"] = "none"
    strat = Weighted(small_problem, "sqp", opts)
    tr, model = strat.transcription, strat.solvers[0].backend.model
    assert type(model).__name__ == "MultipleShootingModel"
    p = tr.parameters(X0, np.zeros(7), small_problem.stage_params(0.0))
    model.start(tr.pack(*rest(small_problem), np.zeros(7)), p, tr.lbg, tr.ubg, None, None, True)
    return small_problem, tr, model, p


def rest(pb, U=None):
    """States rolled out from ``X0`` under commands ``U`` (default: rest)."""
    U = np.zeros((pb.horizon, 7)) if U is None else U
    X = X0 + np.vstack([np.zeros(7), np.cumsum(pb.dt * U, axis=0)])
    return X, U


def test_a_qp_step_that_leaves_a_variable_bound_on_either_side_is_not_a_solution(sparse_model):
    """Steps along the dynamics (the gap rows hold exactly) that command the platform's x
    beyond its speed limit: only a variable bound is crossed, on one side or the other."""
    pb, tr, model, p = sparse_model
    v = tr.pack(*rest(pb), np.zeros(7))
    lin = model.linearize(v, p)
    assert model._solved(lin, np.zeros_like(v)) == (True, "")
    for side in (+1.0, -1.0):
        U = np.zeros((pb.horizon, 7))
        U[0, 0] = side * (pb.bounds.u_upper[0] + 0.5)
        step = tr.pack(*rest(pb, U), np.zeros(7)) - v
        ok, status = model._solved(lin, step)
        assert not ok and status
        U[0, 0] = side * 0.5 * pb.bounds.u_upper[0]  # inside: a solution of the rows
        assert model._solved(lin, tr.pack(*rest(pb, U), np.zeros(7)) - v) == (True, "")


def test_the_merit_pins_stage_zero_to_the_measured_state(sparse_model):
    pb, tr, model, p = sparse_model
    v = tr.pack(*rest(pb), np.zeros(7))
    f0, viol0 = model.merit(v, p)
    assert viol0 < 1e-12
    for side in (+1.0, -1.0):
        moved = v.copy()
        moved[tr.index_x[0]] += side * 0.1
        assert model.merit(moved, p) == (f0, viol0)


def test_the_linearisation_pins_stage_zero_to_the_measured_state_from_either_side(sparse_model):
    """A guess whose stage-0 state is above or below the measured one is linearised at the
    measured state (the variable bounds of stage 0 are the state itself)."""
    pb, tr, model, p = sparse_model
    v = tr.pack(*rest(pb), np.zeros(7))
    at = model.linearize(v, p)
    for side in (+1.0, -1.0):
        moved = v.copy()
        moved[tr.index_x[0]] += side * 0.1
        lin = model.linearize(moved, p)
        np.testing.assert_array_equal(lin.data["v"], v)
        assert lin.f == at.f and np.array_equal(lin.grad, at.grad)


def test_the_sparse_model_takes_the_multipliers_only_when_both_come(sparse_model):
    """``start``: the rows' and the variables' multipliers are the given ones (moved a stage
    on with ``shift``) only when both are given; one alone starts both at zero."""
    pb, tr, model, p = sparse_model
    w = tr.pack(*rest(pb), np.zeros(7))
    rng = np.random.default_rng(3)
    lam_g, lam_x = rng.normal(size=tr.g.numel()), rng.normal(size=w.size)
    for given in ((lam_g, None), (None, lam_x)):
        _, lam_c, lam_v = model.start(w, p, tr.lbg, tr.ubg, *given, True)
        assert not lam_c.any() and not lam_v.any()
        assert lam_c.shape == (tr.g.numel(),) and lam_v.shape == w.shape
    _, lam_c, lam_v = model.start(w, p, tr.lbg, tr.ubg, lam_g, lam_x, False)
    assert np.array_equal(lam_c, lam_g) and np.array_equal(lam_v, lam_x)
    _, lam_c, lam_v = model.start(w, p, tr.lbg, tr.ubg, lam_g, lam_x, True)
    assert np.array_equal(lam_c, lam_g[tr.shift_g]) and np.array_equal(lam_v, lam_x[tr.shift_w])


@pytest.mark.parametrize("rti", [False, True])
def test_the_sparse_models_hpipm_has_its_limits_and_prints_nothing(
    monkeypatch, capfd, small_problem, rti
):
    """The HPIPM solver a sparse model builds gets the limits of its kind (a converged
    SQP's or an RTI's, ``HPIPM_LIMITS``), the user's HPIPM options added key by key (one
    given keeps the others); a solve prints nothing (no timings)."""
    from aeromanip.nmpc.backends.multiple_shooting import HPIPM_LIMITS

    made, real = [], ca.conic

    def conic(name, solver, sparsity, opts):
        if name.startswith("aeromanip_hpipm_"):  # not the options' trial QP
            made.append((solver, opts))
        return real(name, solver, sparsity, opts)

    monkeypatch.setattr(ca, "conic", conic)
    opts = {"codegen": False, "qpsol": "hpipm", "seed": "none", "rti": rti,
            "qpsol_options": {"hpipm": {"warm_start": True}}}  # fmt: skip
    strat = Weighted(small_problem, "sqp", opts)
    monkeypatch.undo()
    ((solver, given),) = made
    tol, iterations = HPIPM_LIMITS["rti" if rti else "sqp"]
    assert solver == "hpipm" and given["print_time"] is False
    hpipm = given["hpipm"]
    assert hpipm["warm_start"] is True and hpipm["mode"] == "robust"
    assert hpipm["iter_max"] == iterations
    assert all(hpipm[f"res_{r}_max"] == tol for r in "gbdm")
    tr = strat.transcription
    p = tr.parameters(X0, np.zeros(7), small_problem.stage_params(0.0))
    capfd.readouterr()
    assert strat.solve(p, [tr.pack(*rest(small_problem), np.zeros(7))]).success
    assert capfd.readouterr().out == ""
    assert HPIPM_LIMITS["rti"] != HPIPM_LIMITS["sqp"]


def test_hpipm_options_are_tried_on_hpipm_and_auto_checks_both_solvers():
    """``qpsol = "hpipm"``: its own options pass, an unknown one or a value of the wrong type
    is one line naming it; ``"auto"`` may use either QP solver (dense up to
    ``condense_max_horizon``, sparse beyond), so its options must suit both, whatever that
    horizon."""
    SqpBackend.check_options({"qpsol": "hpipm", "qpsol_options": {"hpipm": {"iter_max": 30}}})
    with pytest.raises(ConfigError, match=r"^solver_options\.qpsol_options: hpipm rejects "
                       r"them: Unknown option: no_such$"):  # fmt: skip
        SqpBackend.check_options({"qpsol": "hpipm", "qpsol_options": {"no_such": 1}})
    with pytest.raises(ConfigError, match=r"^solver_options\.qpsol_options: hpipm rejects "
                       r"them: .*OT_INT cannot be cast to OT_DICT"):  # fmt: skip
        SqpBackend.check_options({"qpsol": "hpipm", "qpsol_options": {"hpipm": 3}})
    for horizon, own, other in ((1, "hpipm", "daqp"), (100, "daqp", "hpipm")):
        opts = {"qpsol": "auto", "condense_max_horizon": horizon,
                "qpsol_options": {own: {}}}  # fmt: skip
        with pytest.raises(ConfigError, match=rf"^solver_options\.qpsol_options: {other} "
                           rf"rejects them: Unknown option: {own}$"):  # fmt: skip
            SqpBackend.check_options(opts)


def test_an_unknown_sqp_option_is_named_with_every_known_one():
    with pytest.raises(ConfigError) as err:
        SqpBackend.check_options({"tolerance": 1e-6})
    known = ", ".join(DEFAULTS)
    assert str(err.value) == f"solver_options.tolerance: unknown sqp option (known: {known})"


# --- the SQP's answer is a KKT point of the NLP (its own multipliers, CasADi's derivatives) ------


def floored_problem():
    """The small problem with the platform's height bounded below at 0.98 m and the end
    effector wanted low: a state bound binds (its multiplier enters the model rows')."""
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 3, 0.5, Bounds.from_robot(x8, platform_box={"z": (0.98, 1.5)}))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.2])), weight=10.0)
    pb.add_task(ControlRate(), weight=0.1, level=None)
    return pb


def clearance_problem():
    """The small problem with the end effector wanted 0.1 m under the base, its clearance
    0.25 m and the platform held near 1 m: a path row binds (its multiplier enters the
    model rows')."""
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 3, 0.5, Bounds.from_robot(x8, platform_box={"z": (0.99, 1.01)}))
    pb.add_task(EndEffectorTracking(Constant([0.0, 0.0, 0.9])), weight=10.0)
    pb.add_task(ControlRate(), weight=0.1, level=None)
    pb.add_constraint(Clearance(0.25, points=("ee",)))
    return pb


@pytest.mark.parametrize("qpsol", ["daqp", "hpipm"])
@pytest.mark.parametrize("case", ["free", "state-bound-active", "row-active"])
def test_sqp_returns_multipliers_that_make_its_answer_stationary(small_problem, qpsol, case):
    """``grad f + J_g^T lam_g + lam_x = 0`` (CasADi's sign convention), with ``lam_x``
    nonzero only at an active variable bound: the NLP's multipliers, the model rows' too
    (``daqp``: the condensed model, which recovers those the QP condensed away), with a
    state bound or a path row active."""
    floored = case == "state-bound-active"
    made = {"free": lambda: small_problem, "row-active": clearance_problem}
    pb = floored_problem() if floored else made[case]()
    opts = {"codegen": False, "qpsol": qpsol, "tol": 1e-9}
    if "seed" in DEFAULTS:
        opts["seed"] = "none"
    strat = Weighted(pb, "sqp", opts)
    tr, backend = strat.transcription, strat.solvers[0].backend
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    res = backend.solve(tr.pack(*rest(pb), np.zeros(7)), p, tr.lbg, tr.ubg)
    if floored:  # a state bound binds: its multiplier is in play
        assert np.abs(res.lam_x[tr.index_x[1:].ravel()]).max() > 1e-6
    if case == "row-active":  # a clearance row (bounded below only) binds
        path = np.isfinite(tr.lbg) & np.isinf(tr.ubg)
        assert path.sum() == pb.horizon and np.abs(res.lam_g[path]).max() > 1e-6
    assert res.success
    kkt = ca.Function("kkt", [tr.w, tr.p], [ca.gradient(tr.f, tr.w), ca.jacobian(tr.g, tr.w)])
    grad, J = (np.asarray(a) for a in kkt(res.w, p))
    assert res.lam_x.shape == res.w.shape and res.lam_g.shape == (J.shape[0],)
    stationarity = grad.ravel() + J.T @ res.lam_g + res.lam_x
    lbw, ubw = tr.variable_bounds(p)
    free = lbw < ubw  # a fixed variable (the measured stage 0) may be eliminated, its
    assert free.sum() > 0.8 * free.size  # multiplier then unreported: any value holds
    assert np.abs(stationarity[free]).max() < 1e-6 * (1.0 + np.abs(grad).max())
    slack = np.minimum(res.w - lbw, ubw - res.w)
    assert np.all(np.abs(res.lam_x[free & (slack > 1e-6)]) < 1e-8)


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

    def __init__(self, *answers):
        self.answers, self.calls = list(answers), []

    def solve(self, w0, p, lbg, ubg, lam_g0=None, lam_x0=None, shift=True):
        self.calls.append((np.array(w0), lam_g0, lam_x0, (p, lbg, ubg)))
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


def test_the_second_order_correction_solves_the_last_qp_with_rows_taken_at_the_full_step():
    """``CondensedModel.correction``: the last QP (its Hessian and gradient) with each row's
    value taken at ``v + d`` less its linear part, ``c(v + d) - A d``, checked against
    CasADi's qrqp on that QP built here; near a solution whose curved row (the end
    effector's horizontal reach) binds, the corrected step leaves it far less than the
    plain one (second order)."""
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 3, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.6, 0.4, 0.3])), weight=10.0)
    pb.add_task(ControlRate(), weight=0.1, level=None)

    def reach(st):  # the end effector's horizontal distance from the origin, squared
        ee = st.kin.ee_position(st.x)
        return ee[0] ** 2 + ee[1] ** 2

    pb.add_constraint(UserConstraint("ee_near", reach, 0.0, 0.2**2))
    strat = Weighted(pb, "sqp", {"codegen": False, "qpsol": "daqp", "seed": "none"})
    tr, backend = strat.transcription, strat.solvers[0].backend
    model = backend.model
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    sol = backend.solve(tr.pack(*rest(pb), np.zeros(7)), p, tr.lbg, tr.ubg)
    assert sol.success
    v, lam_c, lam_v = model.start(sol.w, p, tr.lbg, tr.ubg, sol.lam_g, sol.lam_x, False)
    v = v + 0.02 * np.random.default_rng(1).normal(size=v.size)  # near the solution
    lin = model.linearize(v, p)
    d = model.step(v, lin, lam_c, lam_v, p, False).d
    soc = model.correction(v, d, lin, p)
    assert soc.ok and np.count_nonzero(soc.lam_a) > 0  # the corrected rows bind
    A = lin.data[1]
    c = model.merit_f(v + d, p)[1] - A @ d
    H = model._last_H
    qp = ca.conic("soc", "qrqp", {"h": ca.DM(H).sparsity(), "a": ca.DM(A).sparsity()},
                  {"print_iter": False, "print_header": False, "print_info": False})  # fmt: skip
    ref = qp(h=H, g=lin.grad, a=A, lba=lin.lbc - c, uba=lin.ubc - c,
             lbx=model.lbU - v, ubx=model.ubU - v)  # fmt: skip
    np.testing.assert_allclose(soc.d, np.asarray(ref["x"]).ravel(), atol=1e-6)
    plain = model.merit(v + d, p)[1]
    assert plain > 1e-4 and model.merit(v + soc.d, p)[1] < 0.2 * plain


def sparse_clearance_point(accel: bool):
    """The sparse model of a 3-step tracking and CoG-velocity problem with the clearance
    rows (and, if ``accel``, command-rate rows), linearised at a moving plan: ``tr, model,
    p, w, lin``."""
    x8 = load_robot("x8-3dof")
    bounds = Bounds.from_robot(x8)
    pb = Problem(x8, 3, 0.5, bounds.with_accel(np.full(7, 2.0)) if accel else bounds)
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0)
    pb.add_task(CogVelocity(), weight=1.0)  # bilinear: the Hessian depends on u
    pb.add_task(ControlRate(), weight=0.1, level=None)
    pb.add_constraint(Clearance(0.1))
    strat = Weighted(pb, "sqp", {"codegen": False, "qpsol": "hpipm", "seed": "none"})
    tr, model = strat.transcription, strat.solvers[0].backend.model
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    U = np.tile([0.1, -0.05, 0.02, 0.1, 0.2, -0.1, 0.1], (pb.horizon, 1))
    w = tr.pack(*rest(pb, U), np.zeros(7))
    model.start(w, p, tr.lbg, tr.ubg, None, None, True)
    lin = model.linearize(w, p)
    return tr, model, p, w, lin


def test_the_sparse_models_exact_hessian_blocks_are_the_nlps_lagrangian_hessian():
    """``MultipleShootingModel._hessian_blocks(exact=True)``: each stage's block (its
    state and command) and the terminal one are the blocks of the NLP's Lagrangian
    Hessian ``f + lam' g`` (CasADi's derivatives; the model rows are linear, the problem
    couples no two stages), plus the regularisation; with the clearance rows (curved), the
    command-rate rows (in every stage but the terminal one) and random multipliers on
    every row."""
    tr, model, p, w, lin = sparse_clearance_point(accel=True)
    lam = np.random.default_rng(5).normal(size=tr.g.numel())
    Hs, HT = model._hessian_blocks(lin, lam, p, True)
    L = tr.f + ca.dot(ca.DM(lam), tr.g)
    H = np.asarray(ca.Function("H", [tr.w, tr.p], [ca.hessian(L, tr.w)[0]])(w, p))
    reg, s, N = model.opts["regularization"], tr.stride, tr.N
    for k in range(N):
        block = H[k * s : (k + 1) * s, k * s : (k + 1) * s] + reg * np.eye(s)
        np.testing.assert_allclose(Hs[k], block, atol=1e-9, rtol=1e-9)
    np.testing.assert_allclose(HT, H[N * s :, N * s :] + reg * np.eye(tr.nz), atol=1e-9)
    assert np.abs(Hs - 2.0 * np.einsum("kri,krj->kij", lin.data["J"], lin.data["J"])).max() > 1e-3


def test_the_sparse_models_row_products_are_the_nlps_jacobian_times_a_step():
    """``MultipleShootingModel._a_times(lin, d)``, assembled block by block (the dynamics'
    gaps, each stage's rows, the terminal rows), is ``J d`` with ``J`` CasADi's Jacobian
    of the NLP's rows at the linearisation point; with the clearance rows (curved)."""
    tr, model, p, w, lin = sparse_clearance_point(accel=False)
    J = np.asarray(ca.Function("J", [tr.w, tr.p], [ca.jacobian(tr.g, tr.w)])(w, p))
    d = np.random.default_rng(11).normal(size=w.size)
    np.testing.assert_allclose(model._a_times(lin, d), J @ d, atol=1e-9, rtol=1e-9)
    lam = np.random.default_rng(12).normal(size=J.shape[0])
    np.testing.assert_allclose(model._at_lam(lin, lam), J.T @ lam, atol=1e-9, rtol=1e-9)
    lbw, ubw = tr.variable_bounds(p)  # the iterate returned is clipped to them
    far = w + 50.0 * np.sign(np.random.default_rng(13).normal(size=w.size))
    assert np.isfinite(lbw).any() and np.isfinite(ubw).any()
    np.testing.assert_array_equal(model.result(far, p, lam, d)[0], np.clip(far, lbw, ubw))
    res = model._qp(lin, *model._hessian_blocks(lin, np.zeros(J.shape[0]), p, False))
    assert res.ok and res.status == ""  # HPIPM's answer, checked with these products


@pytest.mark.parametrize("where", ["row upper", "row lower", "bound upper", "bound lower"])
@pytest.mark.parametrize(("excess", "ok"), [(0.95, True), (1.05, False)])
def test_the_sparse_models_qp_answer_is_checked_to_its_tolerance(where, excess, ok):
    """``MultipleShootingModel._solved``: HPIPM's answer is accepted only if it keeps the
    linearised rows and the bounds to ``QP_FEASIBILITY (1 + |d|)``; here a step of 0.25
    crosses one of them by ``excess`` times that (1.25e-6). A step that is not finite is
    refused as such."""
    model = object.__new__(MultipleShootingModel)
    A = np.array([[1.0, 0.0], [0.0, 1.0]])
    model._a_times = lambda lin, d: A @ d
    far = np.full(2, 9.0)
    lin = SimpleNamespace(c=np.zeros(2), lbc=-far, ubc=far.copy(),
                          data={"v": np.zeros(2), "lbw": -far, "ubw": far.copy()})  # fmt: skip
    sign = 1.0 if where.endswith("upper") else -1.0
    if where.startswith("row"):
        (lin.ubc if sign > 0 else lin.lbc)[0] = 0.25 * sign
    else:
        (lin.data["ubw"] if sign > 0 else lin.data["lbw"])[1] = 0.25 * sign
    step = np.zeros(2)
    step[0 if where.startswith("row") else 1] = sign * (0.25 + excess * 1e-6 * 1.25)
    assert model._solved(lin, step) == (
        (True, "") if ok else (False, "infeasible or not converged")
    )
    assert model._solved(lin, np.array([np.nan, 0.0])) == (False, "not finite")


def test_the_sparse_kkt_error_is_the_largest_part_and_ignores_pinned_variables():
    """Row complementarity, free variables' bound complementarity and stationarity, each
    made the largest in turn; a pinned variable (``lbw = ubw``, e.g. the measured state)
    carries any multiplier: neither its stationarity nor its complementarity counts."""
    model = object.__new__(MultipleShootingModel)
    model._at_lam = lambda lin, lam: np.array([lam[0], 0.0])  # one row: on variable 0

    def kkt(c, lam_c, v0, lam_v0, grad0):
        # variable 1 is pinned at 0 with a stationarity residual of 5: never counted
        lin = SimpleNamespace(grad=np.array([grad0, 5.0]), c=np.array([c]),
                              lbc=np.array([0.0]), ubc=np.array([1.0]),
                              data={"v": np.array([v0, 0.0]), "lbw": np.array([-1.0, 0.0]),
                                    "ubw": np.array([1.0, 0.0])})  # fmt: skip
        lam_v = np.array([lam_v0, 0.0])
        return model.kkt_error(lin.data["v"], lin, np.array([lam_c]), lam_v)

    assert kkt(0.5, 2.0, 0.0, 0.0, -2.0) == pytest.approx(1.0)  # row: 2 x 0.5 from its top
    assert kkt(1.0, 0.0, 0.25, -3.0, 3.0) == pytest.approx(3.75)  # bound: 3 x 1.25
    assert kkt(1.0, 0.0, 0.0, 0.0, 0.125) == pytest.approx(0.125)  # stationarity


@pytest.mark.parametrize("opts", [{"hessian": "gauss-newton"}, {"rti": True}])
def test_the_sparse_model_builds_no_exact_hessian_it_will_not_use(opts):
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 2, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0)
    base = {"codegen": False, "qpsol": "hpipm", "seed": "none"}
    model = Weighted(pb, "sqp", {**base, **opts}).solvers[0].backend.model
    assert model.f_hess is None and model.t_hess is None
    assert Weighted(pb, "sqp", base).solvers[0].backend.model.f_hess is not None


@pytest.mark.parametrize("mode", ["stagewise", "strict", "residual"])
def test_hpipm_solves_a_hierarchy_as_ipopt_does(mode):
    """Each mode the sparse model takes (the higher level's rows per stage: its cost
    (``stagewise``) or its residuals (``strict``, ``residual``)): each level's optimal cost
    as IPOPT's on the same NLPs. (Without the cost rows' Gauss-Newton curvature in its
    Hessian the stagewise lower level ran to the iteration limit.)"""
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 4, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0, level=0)
    pb.add_task(CogAlignment(), weight=1.0, level=1)
    pb.add_task(ControlRate(), weight=0.1, level=None)
    opts = {"codegen": False, "qpsol": "hpipm", "seed": "none", "tol": 1e-9}
    hp = Hierarchical(pb, mode=mode, backend="sqp", options=opts)
    tr = hp.transcription
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    w0 = tr.pack(*rest(pb), np.zeros(7))
    assert type(hp.solvers[1].backend.model).__name__ == "MultipleShootingModel"
    got = hp.solve(p, [w0, None])
    ref = Hierarchical(pb, mode=mode, backend="ipopt").solve(p, [w0, None])
    assert got.success and ref.success and got.status == ref.status == "ok"
    for mine, theirs in zip(got.levels, ref.levels, strict=True):
        assert mine.cost == pytest.approx(theirs.cost, rel=1e-4, abs=1e-9)
    assert got.levels[1].iterations <= 15


def test_the_sparse_gauss_newton_blocks_carry_the_stagewise_cost_rows_curvature():
    """Gauss-Newton blocks: ``2 J'J`` plus, per higher-level cost row ``|r_j|^2`` of the
    stage, ``2 max(lam_j, 0) J_j' J_j`` with ``J_j`` CasADi's Jacobian of the
    transcription's residuals ``r_j`` in that stage's variables (random multipliers); the
    third level of three, so two cost rows a stage (one bilinear in the state and the
    command), after the clearance rows."""
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 3, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0, level=0)
    pb.add_task(CogVelocity(), weight=1.0, level=1)  # its rows' curvature depends on u
    pb.add_task(Posture(["q2"], [0.3]), weight=1.0, level=2)
    pb.add_task(ControlRate(), weight=0.1, level=None)
    pb.add_constraint(Clearance(0.1))  # path rows before the cost rows in each stage
    opts = {"codegen": False, "qpsol": "hpipm", "seed": "none"}
    st = Hierarchical(pb, mode="stagewise", backend="sqp", options=opts).solvers[2]
    tr, model = st.tr, st.backend.model
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    U = np.tile([0.1, -0.05, 0.02, 0.1, 0.2, -0.1, 0.1], (pb.horizon, 1))
    w = tr.pack(*rest(pb, U), np.zeros(7))
    model.start(w, p, tr.lbg, tr.ubg, None, None, True)
    lin = model.linearize(w, p)
    lam = np.random.default_rng(6).normal(size=tr.g.numel())
    Hs, HT = model._hessian_blocks(lin, lam, p, False)
    s, N, reg = tr.stride, tr.N, model.opts["regularization"]
    full = np.zeros((w.size, w.size))
    for row, r in tr.hier_residuals:
        J = np.asarray(ca.Function("J", [tr.w, tr.p], [ca.jacobian(r, tr.w)])(w, p))
        full += 2.0 * max(lam[row], 0.0) * J.T @ J
    assert len(tr.hier_residuals) == 2 * (N + 1) and np.abs(full).max() > 1e-3
    for k in range(N):
        gn = 2.0 * lin.data["J"][k].T @ lin.data["J"][k] + reg * np.eye(s)
        block = full[k * s : (k + 1) * s, k * s : (k + 1) * s]
        np.testing.assert_allclose(Hs[k], gn + block, atol=1e-9, rtol=1e-9)
    gnT = 2.0 * lin.data["JT"].T @ lin.data["JT"] + reg * np.eye(tr.nz)
    np.testing.assert_allclose(HT, gnT + full[N * s :, N * s :], atol=1e-9, rtol=1e-9)


def test_hpipm_refuses_the_hierarchy_mode_that_couples_every_stage():
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 3, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0, level=0)
    pb.add_task(CogAlignment(), weight=1.0, level=1)
    msg = r"^solver_options\.qpsol: hpipm needs stage-wise rows; hierarchy mode 'total' "
    with pytest.raises(ConfigError, match=msg + r"couples every stage \(use qpsol = 'daqp'"):
        Hierarchical(pb, mode="total", backend="sqp", options={"codegen": False, "qpsol": "hpipm"})


@pytest.mark.parametrize(
    ("exact_step", "ok", "kept"),
    [
        ([0.1, -0.2], True, True),  # descends (grad'd = -0.3): the exact step is taken
        ([0.1, -0.2], False, False),  # the exact QP failed
        ([1e3 + 1.0, -2e3], True, False),  # longer than MAX_STEP: an unbounded QP
        ([1e3, -1e3], True, True),  # exactly MAX_STEP long, descending: taken
        ([0.3, 0.2], True, False),  # ascends a little (grad'd = 0.7)
        ([0.2, -0.1], True, True),  # grad'd = 0 exactly: not an ascent
    ],
)
def test_the_sparse_models_exact_step_falls_back_on_gauss_newton(exact_step, ok, kept):
    """``MultipleShootingModel.step(exact=True)``: where the exact Hessian's QP fails,
    gives a step longer than ``MAX_STEP`` or one that does not descend (``grad'd > 0``),
    the Gauss-Newton QP's step is taken instead; either is moved by the iterate's clipping
    (``lin.data["v"] - v``). The two QPs are stand-ins returning the given steps."""
    model = object.__new__(MultipleShootingModel)
    gn_step = np.array([-0.05, 0.01])
    model._hessian_blocks = lambda lin, lam, p, exact: ("exact" if exact else "gn", None)
    model._qp = lambda lin, kind, _: (
        QpResult(np.array(exact_step, float), np.zeros(1), np.zeros(2), ok, "" if ok else "x")
        if kind == "exact"
        else QpResult(gn_step.copy(), np.zeros(1), np.zeros(2), True, "")
    )
    v, clipped = np.array([0.0, 0.0]), np.array([0.01, 0.0])
    lin = SimpleNamespace(grad=np.array([1.0, 2.0]), data={"v": clipped})
    res = model.step(v, lin, np.zeros(1), np.zeros(2), np.zeros(0), True)
    expected = np.array(exact_step, float) if kept else gn_step
    np.testing.assert_array_equal(res.d, expected + clipped - v)
    assert res.ok is (ok or not kept)
    gn = model.step(v, lin, np.zeros(1), np.zeros(2), np.zeros(0), False)
    np.testing.assert_array_equal(gn.d, gn_step + clipped - v)


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


def test_an_option_key_that_is_not_a_string_is_one_line():
    from aeromanip.nmpc.backends.nlpsol import IpoptBackend

    with pytest.raises(ConfigError, match=r"^solver_options: keys must be strings, got 7$"):
        IpoptBackend.check_options({"ipopt.tol": 1e-6, 7: 1.0})


def _tracking_ipopt():
    """A 3-step tracking problem and its weighted IPOPT backend."""
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 3, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0)
    return pb, Weighted(pb, "ipopt").solvers[0].backend


@pytest.mark.parametrize(
    ("raised", "status"),
    [
        ("evaluation failed\nat nmpc_ipopt: NaN in f", "at nmpc_ipopt: NaN in f"),
        (
            "Error in Function::call\nevaluation failed\nat nmpc_ipopt: NaN in f",
            "at nmpc_ipopt: NaN in f",
        ),
        ("", "solver error"),
    ],
)
def test_a_solver_that_raises_is_a_failed_solve_with_its_last_line(raised, status):
    """Also with the iterations the solver's stats count and the solve's wall time."""
    pb, backend = _tracking_ipopt()
    tr = backend.tr

    class Raising:
        def __call__(self, **args):
            time.sleep(0.002)
            raise RuntimeError(raised)

        def stats(self):
            return {"iter_count": 4}

    backend.solver = Raising()
    t0 = time.perf_counter()
    res = backend.solve(
        tr.pack(*rest(pb), np.zeros(7)),
        tr.parameters(X0, np.zeros(7), pb.stage_params(0.0)),
        tr.lbg,
        tr.ubg,
    )
    assert (res.success, res.status, res.iterations) == (False, status, 4)
    assert np.isnan(res.w).all() and np.isnan(res.f)
    assert 0.002 <= res.solve_time_s <= time.perf_counter() - t0


@pytest.mark.parametrize("interrupted", [False, True])
def test_an_ipopt_solve_cut_by_ctrl_c_raises_it_again_and_a_solve_reports_its_time(
    interrupted, monkeypatch
):
    """The solver's stats say it was interrupted: the solve raises ``KeyboardInterrupt``
    (Python's own SIGINT handler, main thread); otherwise it reports its wall time."""
    from aeromanip.nmpc.backends import nlpsol
    from aeromanip.nmpc.backends.nlpsol import INTERRUPTED_STATUS

    # Python's own handler, whatever the test runner installed (xdist workers do)
    monkeypatch.setattr(nlpsol.signal, "getsignal", lambda _: nlpsol.signal.default_int_handler)
    pb, backend = _tracking_ipopt()
    tr, solver = backend.tr, backend.solver
    status = INTERRUPTED_STATUS if interrupted else "Solve_Succeeded"

    class Stopped:
        def __call__(self, **args):
            return solver(**args)

        def stats(self):
            return {**solver.stats(), "return_status": status}

    backend.solver = Stopped()
    args = (tr.pack(*rest(pb), np.zeros(7)), tr.parameters(X0, np.zeros(7), pb.stage_params(0.0)))
    t0 = time.perf_counter()
    if interrupted:
        with pytest.raises(KeyboardInterrupt):
            backend.solve(*args, tr.lbg, tr.ubg)
    else:
        res = backend.solve(*args, tr.lbg, tr.ubg)
        assert res.success and 0 < res.solve_time_s <= time.perf_counter() - t0


def test_a_solves_iterations_are_the_solvers_count_or_0_where_it_reports_none():
    from aeromanip.nmpc.backends.nlpsol import _iterations

    assert _iterations({"iter_count": 7}) == 7
    assert _iterations({}) == 0


def test_a_solvers_status_is_its_text_or_casadis_name_for_a_number():
    """``nlpsol._status_text``: IPOPT's text as it is; fatrop's number with CasADi's
    unified name; nothing reported is ``unknown``."""
    from aeromanip.nmpc.backends.nlpsol import _status_text

    assert _status_text({"return_status": "Solve_Succeeded"}) == "Solve_Succeeded"
    assert _status_text({}) == "unknown"
    fatrop = {"return_status": 2, "unified_return_status": "SOLVER_RET_INFEASIBLE"}
    assert _status_text(fatrop) == "SOLVER_RET_INFEASIBLE (code 2)"
    assert _status_text({"return_status": 2}) == "SOLVER_RET_UNKNOWN (code 2)"


def test_a_solve_cut_by_casadi_catching_ctrl_c_raises_it_again_only_where_python_would(
    monkeypatch,
):
    """``nlpsol._reraise_interrupt``: in the main thread with Python's own SIGINT handler
    the swallowed Ctrl-C becomes a ``KeyboardInterrupt``; with another handler (the
    CLI's, which defers the signal) or in another thread it does not."""
    from aeromanip.nmpc.backends import nlpsol

    handlers = {signal.SIGINT: signal.default_int_handler}  # SIGINT's is what is asked
    monkeypatch.setattr(nlpsol.signal, "getsignal", handlers.get)
    with pytest.raises(KeyboardInterrupt):
        nlpsol._reraise_interrupt()
    raised = []

    def in_thread():
        try:
            nlpsol._reraise_interrupt()
        except KeyboardInterrupt:
            raised.append(True)

    worker = threading.Thread(target=in_thread)
    worker.start()
    worker.join()
    assert raised == []
    handlers[signal.SIGINT] = lambda *a: None
    nlpsol._reraise_interrupt()  # another handler: nothing raised


def test_the_option_checkers_name_what_a_value_must_be():
    """``_number`` and ``_one_of`` (``OPTION_CHECKS`` is made of them at import)."""
    positive, nonneg = _number(True), _number(False)
    for v in (1, 0.5, 1e-12):
        assert positive(v) == nonneg(v) == ""
    assert nonneg(0) == nonneg(0.0) == ""
    for v in (0, 0.0, -1.0):
        assert positive(v) == "a finite number > 0"
    for v in (-1e-12, -3):
        assert nonneg(v) == "a finite number >= 0"
    for v in (True, float("inf"), float("nan"), "1", None):
        assert positive(v) == "a finite number > 0" and nonneg(v) == "a finite number >= 0"
    pick = _one_of(("a", 2))
    assert pick("a") == pick(2) == "" and pick("b") == "one of ['a', 2]"


def stopping(rti=False):
    """An ``SqpBackend`` with only what ``_verdict`` reads: its options and a model whose
    KKT error is set by hand."""
    sqp = object.__new__(SqpBackend)
    sqp.opts = {**DEFAULTS, "rti": rti, "tol": 1e-8, "acceptable_tol": 1e-5,
                "constr_viol_tol": 1e-4, "acceptable_iter": 3}  # fmt: skip
    sqp.model = SimpleNamespace(kkt=0.0)
    sqp.model.kkt_error = lambda v, lin, lam_c, lam_v: sqp.model.kkt
    return sqp


def verdict(sqp, kkt, viol, it, warm=False, acceptable=0, max_iter=50):
    sqp.model.kkt = kkt
    lin = SimpleNamespace(c=np.array([viol]), lbc=np.array([-1.0]), ubc=np.array([0.0]))
    return sqp._verdict(None, lin, None, None, it, warm, acceptable, max_iter)


def test_the_sqp_stops_at_the_tolerances_and_counts_acceptable_iterations():
    """``_verdict``: solved at ``kkt <= tol`` and ``violation <= tol`` (edges included),
    the KKT error measured only from the first QP on (or a warm start) and where the rows
    hold to ``constr_viol_tol``; ``acceptable_iter`` iterations in a row at
    ``acceptable_tol`` (or one at the iteration limit) end it at the acceptable level."""
    sqp = stopping()
    assert verdict(sqp, 1e-8, 1e-8, 1) == ("Solve_Succeeded", 0)
    assert verdict(sqp, 1e-8, 0.0, 0) == ("", 0)  # a cold start's first iterate
    assert verdict(sqp, 1e-8, 0.0, 0, warm=True) == ("Solve_Succeeded", 0)
    assert verdict(sqp, 2e-8, 0.0, 1) == ("", 1)  # acceptable, once
    assert verdict(sqp, 1e-5, 0.0, 1, acceptable=1) == ("", 2)  # the edge counts
    assert verdict(sqp, 1e-5, 0.0, 1, acceptable=2) == ("Solved_To_Acceptable_Level", 3)
    assert verdict(sqp, 2e-5, 0.0, 1, acceptable=2) == ("", 0)  # the run is broken
    assert verdict(sqp, 1e-8, 1e-4, 1) == ("", 1)  # rows hold to constr_viol_tol only
    assert verdict(sqp, 1e-8, 2e-4, 1, acceptable=2) == ("", 0)  # not measured
    assert verdict(sqp, 1e-3, 0.0, 50) == ("Maximum_Iterations_Exceeded", 0)
    assert verdict(sqp, 1e-3, 0.0, 49) == ("", 0)
    assert verdict(sqp, 1e-6, 0.0, 50) == ("Solved_To_Acceptable_Level", 1)
    rti = stopping(rti=True)  # one QP: no stopping test but the iteration limit
    assert verdict(rti, 0.0, 5.0, 1, max_iter=1) == ("Maximum_Iterations_Exceeded", 0)
    assert verdict(rti, 0.0, 5.0, 0, max_iter=1) == ("", 0)


class MeritLine:
    """A stand-in QP model along one direction ``d`` from ``v = 0``: ``merit`` at the
    trial ``alpha d`` is ``table[alpha]`` (cost, violation); an optional second-order
    correction returns ``soc``."""

    def __init__(self, table, soc=None):
        self.table, self.soc, self.tried = table, soc, []
        if soc is not None:
            self.correction = lambda v, d, lin, p: soc

    def merit(self, w, p):
        alpha = round(float(w[0]) / 2.0, 12)  # d = [2.0]
        self.tried.append(alpha)
        if alpha not in self.table:
            return 1e9, 0.0
        return self.table[alpha]


def search(model, viol0=0.0, mu=10.0, grad=-3.0):
    """``_line_search`` from cost 5 and row violation ``viol0`` along ``d = [2]``: the
    merit is ``phi0 = 5 + mu viol0``, its slope ``2 grad - mu viol0``."""
    lin = SimpleNamespace(f=5.0, grad=np.array([grad]), c=np.array([viol0]),
                          lbc=np.array([-1.0]), ubc=np.array([0.0]))  # fmt: skip
    return _line_search(model, np.zeros(1), np.array([2.0]), None, lin, mu)


def test_the_line_search_takes_the_first_step_with_sufficient_decrease_of_the_merit():
    """Armijo on the l1 merit ``f + mu viol``: a trial ``alpha`` is taken when its merit
    is at most ``phi0 + 1e-4 alpha min(slope, 0)``, the slope being ``grad'd - mu viol0``;
    halving from 1 down to below 1e-3. Each case sits on one side of that line."""
    slope = 2 * -3.0 - 10.0 * 0.5
    phi0 = 5.0 + 10.0 * 0.5
    edge = phi0 + 1e-4 * 1.0 * slope  # the full step's threshold, exactly
    assert search(MeritLine({1.0: (edge, 0.0)}), viol0=0.5) == (1.0, None)
    # just short of it (by less than the slope's share would move it): rejected
    short = MeritLine({1.0: (edge + 1e-9, 0.0), 0.5: (phi0 - 1.0, 0.0)})
    assert search(short, viol0=0.5) == (0.5, None) and short.tried == [1.0, 0.5]
    # the violation at the trial counts with mu: 0.1 x 10 more than the cost's decrease
    assert search(MeritLine({1.0: (phi0 - 0.5, 0.1), 0.5: (1.0, 0.0)}), viol0=0.5)[0] == 0.5
    # at 0.5 the threshold is phi0 + 1e-4 x 0.5 x slope
    half = phi0 + 1e-4 * 0.5 * slope
    assert search(MeritLine({1.0: (phi0, 0.0), 0.5: (half, 0.0)}), viol0=0.5)[0] == 0.5
    assert search(MeritLine({1.0: (phi0, 0.0), 0.5: (half + 1e-9, 0.0),
                             0.25: (0.0, 0.0)}), viol0=0.5)[0] == 0.25  # fmt: skip
    # an ascent direction (slope > 0): no increase allowed at all
    assert search(MeritLine({1.0: (5.0 + 1e-6, 0.0), 0.5: (4.0, 0.0)}), grad=1.0)[0] == 0.5
    # nothing accepted: halved until below 1e-3, the shortest step taken as it is
    none = MeritLine({})
    assert search(none)[0] == 0.5**10 and none.tried == [0.5**k for k in range(11)]


def test_the_line_search_takes_a_corrected_full_step_only_if_the_correction_solved():
    """The full step rejected, a model's second-order correction is tried as a full step
    (and returned with it); a correction whose QP failed is not used."""
    good = QpResult(np.array([1.9]), np.zeros(1), np.zeros(1), True, "")
    table = {1.0: (50.0, 0.0), 0.95: (1.0, 0.0), 0.5: (2.0, 0.0)}  # 1.9 = 0.95 d
    assert search(MeritLine(table, soc=good)) == (1.0, good)
    failed = QpResult(np.array([1.9]), np.zeros(1), np.zeros(1), False, "x")
    assert search(MeritLine(table, soc=failed)) == (0.5, None)
    # judged as a full step: threshold 5 + 1e-4 x 1 x (-6)
    near = {1.0: (50.0, 0.0), 0.95: (5.0 - 8e-4, 0.0), 0.5: (2.0, 0.0)}
    assert search(MeritLine(near, soc=good)) == (1.0, good)
    above = {1.0: (50.0, 0.0), 0.95: (5.0 - 6e-4 + 1e-9, 0.0), 0.5: (2.0, 0.0)}
    assert search(MeritLine(above, soc=good)) == (0.5, None)


def test_the_damping_grows_tenfold_after_a_short_step_and_fades_after_full_ones():
    """Levenberg-Marquardt damping: from 0 to 1e-3 at the first shortened step, x10 at
    each next one; /10 after a full step, back to 0 once below 1e-3."""
    assert _damping(0.0, 1.0) == 0.0
    assert _damping(0.0, 0.5) == 1e-3
    assert _damping(1e-3, 0.25) == pytest.approx(1e-2)
    assert _damping(1e-2, 1.0) == pytest.approx(1e-3)  # exactly the floor: kept
    assert _damping(1e-3 * 10.0, 1.0) >= 1e-3
    assert _damping(5e-3, 1.0) == 0.0  # 5e-4 < 1e-3


def test_sqp_options_are_checked_as_given_and_blas_threads_set_only_when_asked(monkeypatch):
    with pytest.raises(ConfigError, match=r"^solver_options: must be a table, got 'x'$"):
        SqpBackend.checked_options("x")
    with pytest.raises(ConfigError, match=r"^solver_options\.tol: "):
        SqpBackend.check_options({"tol": -1.0})
    from aeromanip.nmpc.backends import sqp as sqp_module

    calls = []
    monkeypatch.setattr(sqp_module, "limit_blas_threads", calls.append)
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 2, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0)
    for threads in (None, 2):
        Weighted(pb, "sqp", {"codegen": False, "seed": "none", "blas_threads": threads})
    assert calls == [2]


def test_a_warm_sqp_solve_moves_its_multipliers_a_stage_on_by_default():
    """``solve(..., lam_g0, lam_x0)`` with the last step's multipliers: the QP model
    starts with them shifted a stage on (``shift`` defaults to True), as the NLP moved."""
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 3, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0)
    backend = Weighted(pb, "sqp", {"codegen": False, "seed": "none"}).solvers[0].backend
    tr, shifts = backend.tr, []
    start = backend.model.start
    backend.model.start = lambda *a: shifts.append(a[-1]) or start(*a)
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    w0 = tr.pack(*rest(pb), np.zeros(7))
    first = backend.solve(w0, p, tr.lbg, tr.ubg)
    backend.solve(first.w, p, tr.lbg, tr.ubg, first.lam_g, first.lam_x)
    assert shifts == [True, True]


def test_a_warm_ipopt_solve_starts_from_the_multipliers_moved_a_stage_on_by_default():
    """The same for IPOPT: ``lam_g0``/``lam_x0`` reach it as ``lam[shift_g]``/``[shift_w]``."""
    pb, backend = _tracking_ipopt()
    tr, given = backend.tr, []

    class Recording:  # the solver, recording what it is given
        def __init__(self, solver):
            self.solver, self.stats = solver, solver.stats

        def __call__(self, **args):
            given.append(args)
            return self.solver(**args)

    backend.solver = Recording(backend.solver)
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    first = backend.solve(tr.pack(*rest(pb), np.zeros(7)), p, tr.lbg, tr.ubg)
    backend.solve(first.w, p, tr.lbg, tr.ubg, first.lam_g, first.lam_x)
    np.testing.assert_array_equal(given[1]["lam_g0"], first.lam_g[tr.shift_g])
    np.testing.assert_array_equal(given[1]["lam_x0"], first.lam_x[tr.shift_w])
    backend.solve(first.w, p, tr.lbg, tr.ubg, first.lam_g, first.lam_x, shift=False)
    np.testing.assert_array_equal(given[2]["lam_g0"], first.lam_g)  # this step's: as given
    np.testing.assert_array_equal(given[2]["lam_x0"], first.lam_x)


@pytest.mark.parametrize("rti", [False, True])
def test_an_sqp_solve_reports_its_qps_and_its_time(rti):
    """``iterations`` is the number of QPs solved (one in RTI, whose status says so) and
    ``solve_time_s`` lies within the wall time of the call."""
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 3, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0)
    pb.add_task(ControlRate(), weight=0.1, level=None)
    opts = {"codegen": False, "seed": "none", "rti": rti}
    backend = Weighted(pb, "sqp", opts).solvers[0].backend
    tr, qps = backend.tr, []
    step = backend.model.step
    backend.model.step = lambda *a: qps.append(1) or step(*a)
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    t0 = time.perf_counter()
    res = backend.solve(tr.pack(*rest(pb), np.zeros(7)), p, tr.lbg, tr.ubg)
    wall = time.perf_counter() - t0
    assert res.iterations == len(qps)
    assert len(qps) == 1 if rti else len(qps) >= 3
    assert 0.0 < res.solve_time_s <= wall
    assert res.status == ("RTI step" if rti else "Solve_Succeeded")
