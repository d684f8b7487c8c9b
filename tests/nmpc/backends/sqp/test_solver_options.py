"""Documented contracts of the SQP backend that no closed-loop test pins down.

Truths: the docstrings and comments of ``sqp.DEFAULTS`` (each option's type and range,
``hessian``), ``sqp._go_exact`` (when "auto" goes exact), the stopping test, the line
search and the damping as their docstrings state them, and the NLP's own KKT conditions
(CasADi's derivatives) at the SQP's answer.
"""

from __future__ import annotations

import math
import time
from types import SimpleNamespace

import casadi as ca
import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends import SolveRequest
from aeromanip.nmpc.backends.sqp.dense_qp import QpResult
from aeromanip.nmpc.backends.sqp.solver import (
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
from aeromanip.nmpc.backends.sqp.sparse_qp import SparseQpModel
from aeromanip.nmpc.constraints import Bounds, Clearance, UserConstraint
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.strategies import Weighted
from aeromanip.references import Constant
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import ControlRate, EndEffectorTracking
from nmpc_helpers import X0, rest

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
    "qpsol": ["auto", "daqp", "qpoases", "riccati", "hpipm"],
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
    "qpsol": (["DAQP", "osqp"], "one of ['auto', 'daqp', 'qpoases', 'riccati', 'hpipm']"),
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
    sparse = object.__new__(SparseQpModel)  # only its type matters here
    assert not _go_exact(sparse, False, 1.0, 1)
    assert _go_exact(sparse, False, 1.0, 2)  # a full step from the second iteration
    assert not _go_exact(sparse, True, 0.5, 2)  # back to Gauss-Newton after a short one
    assert not _go_exact(sparse, False, 0.5, EXACT_FROM_ITERATION - 1)
    assert _go_exact(sparse, False, 0.5, EXACT_FROM_ITERATION)  # where GN may cycle


# --- the hessian option reaches every QP of a solve ----------------------------------------------


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
    res = backend.solve(SolveRequest(tr.pack(*rest(pb), np.zeros(7)), p, tr.lbg, tr.ubg))
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


def test_the_second_order_correction_solves_the_last_qp_with_rows_taken_at_the_full_step():
    """``CondensedQpModel.correction``: the last QP (its Hessian and gradient) with each row's
    value taken at ``v + d`` less its linear part, ``c(v + d) - A d``, checked against
    CasADi's qrqp on that QP built here; near a solution whose curved row (the end
    effector's horizontal reach) binds, the corrected step leaves it far less than the
    plain one (second order)."""
    _, model, p, v, lin, lam_c, lam_v = _near_a_binding_reach("daqp")
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


def test_the_sparse_models_correction_solves_the_last_qp_with_rows_taken_at_the_full_step():
    """``SparseQpModel.correction`` (HPIPM), as the condensed one: the last QP (its
    Hessian blocks, the NLP's gradient) with the rows ``g(v + d) - A d``, where ``g`` and
    ``A`` come from CasADi on the whole NLP (not the model's stage Functions), checked
    against qrqp on that QP assembled here (a row of the commands among them); the
    corrected step leaves the curved row (the end effector's reach) far less than the
    plain one."""
    speed = UserConstraint("speed", lambda st: ca.sumsqr(st.u[:3]), 0.0, 4.0, uses_command=True)
    tr, model, p, v, lin, lam_c, lam_v = _near_a_binding_reach("hpipm", speed)
    assert isinstance(model, SparseQpModel)
    d = model.step(v, lin, lam_c, lam_v, p, False).d
    soc = model.correction(v, d, lin, p)
    reach = (tr.lbg == 0.0) & (tr.ubg == 0.2**2)
    assert soc.ok and np.abs(soc.lam_a[reach]).max() > 0  # the corrected reach binds
    base = lin.data["v"]  # the iterate clipped into the variable bounds (stage 0 pinned)
    rows = ca.Function("rows", [tr.w, tr.p], [tr.g, ca.jacobian(tr.g, tr.w)])
    A = np.asarray(rows(base, p)[1])
    step = v + d - base
    c = np.asarray(rows(base + step, p)[0]).ravel() - A @ step
    Hs, HT = model._last_qp[1]
    H = np.zeros((tr.w.numel(),) * 2)
    for k, block in enumerate([*Hs, HT]):
        i = k * model.ns
        H[i : i + block.shape[0], i : i + block.shape[0]] = block
    lbw, ubw = tr.variable_bounds(p)
    qp = ca.conic("soc", "qrqp", {"h": ca.DM(H).sparsity(), "a": ca.DM(A).sparsity()},
                  {"print_iter": False, "print_header": False, "print_info": False})  # fmt: skip
    ref = qp(h=H, g=lin.grad, a=A, lba=tr.lbg - c, uba=tr.ubg - c, lbx=lbw - base,
             ubx=ubw - base)  # fmt: skip
    np.testing.assert_allclose(soc.d, np.asarray(ref["x"]).ravel() + base - v, atol=1e-6)
    plain = model.merit(v + d, p)[1]
    assert plain > 1e-4 and model.merit(v + soc.d, p)[1] < 0.2 * plain


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
    """The full step rejected with its rows' violation raised, a model's second-order
    correction is tried as a full step (and returned with it); a correction whose QP
    failed is not used."""
    good = QpResult(np.array([1.9]), np.zeros(1), np.zeros(1), True, "")
    table = {1.0: (40.0, 1.0), 0.95: (1.0, 0.0), 0.5: (2.0, 0.0)}  # 1.9 = 0.95 d
    assert search(MeritLine(table, soc=good)) == (1.0, good)
    failed = QpResult(np.array([1.9]), np.zeros(1), np.zeros(1), False, "x")
    assert search(MeritLine(table, soc=failed)) == (0.5, None)
    # judged as a full step: threshold 5 + 1e-4 x 1 x (-6)
    near = {1.0: (40.0, 1.0), 0.95: (5.0 - 8e-4, 0.0), 0.5: (2.0, 0.0)}
    assert search(MeritLine(near, soc=good)) == (1.0, good)
    above = {1.0: (40.0, 1.0), 0.95: (5.0 - 6e-4 + 1e-9, 0.0), 0.5: (2.0, 0.0)}
    assert search(MeritLine(above, soc=good)) == (0.5, None)


def test_the_line_search_corrects_only_a_full_step_that_raised_the_violation():
    """IPOPT's rule: a full step rejected for its cost alone (the rows' violation not
    above the current one) is not corrected, only shortened; one whose violation rose
    (by any amount) is. The corrections tried are counted."""
    good = QpResult(np.array([1.9]), np.zeros(1), np.zeros(1), True, "")

    def tried(viol0, viol_full):
        model = MeritLine({1.0: (50.0, viol_full), 0.95: (0.0, 0.0), 0.5: (0.0, 0.0)})
        calls = []
        model.correction = lambda v, d, lin, p: calls.append(d) or good
        alpha, soc = search(model, viol0=viol0)
        return len(calls), alpha, soc

    assert tried(0.0, 0.0) == (0, 0.5, None)  # the cost alone rejected it
    assert tried(0.5, 0.5) == (0, 0.5, None)  # violation as before: not raised
    assert tried(0.5, 0.4) == (0, 0.5, None)  # lowered
    assert tried(0.5, 0.5 + 1e-12) == (1, 1.0, good)  # raised, however little
    assert tried(0.0, 1e-12) == (1, 1.0, good)


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
    from aeromanip.nmpc.backends.sqp import solver as sqp_module

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
    backend.model.start = lambda r: shifts.append(r.shift) or start(r)
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    w0 = tr.pack(*rest(pb), np.zeros(7))
    first = backend.solve(SolveRequest(w0, p, tr.lbg, tr.ubg))
    backend.solve(SolveRequest(first.w, p, tr.lbg, tr.ubg, first.lam_g, first.lam_x))
    assert shifts == [True, True]


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
    backend.model.step = lambda *a, **kw: qps.append(1) or step(*a, **kw)
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    t0 = time.perf_counter()
    res = backend.solve(SolveRequest(tr.pack(*rest(pb), np.zeros(7)), p, tr.lbg, tr.ubg))
    wall = time.perf_counter() - t0
    assert res.iterations == len(qps)
    assert len(qps) == 1 if rti else len(qps) >= 3
    assert 0.0 < res.solve_time_s <= wall
    assert res.status == ("RTI step" if rti else "Solve_Succeeded")


def _near_a_binding_reach(qpsol: str, *constraints: UserConstraint) -> tuple:
    """The end effector tracked toward a target beyond its reach limit (a curved row
    that binds), solved by the SQP on ``qpsol``'s QP, and an iterate 0.02 (normal noise)
    from that solution, linearised: ``tr, model, p, v, lin, lam_c, lam_v``."""
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 3, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.6, 0.4, 0.3])), weight=10.0)
    pb.add_task(ControlRate(), weight=0.1, level=None)
    for c in (UserConstraint("ee_near", _reach_squared, 0.0, 0.2**2), *constraints):
        pb.add_constraint(c)
    strat = Weighted(pb, "sqp", {"codegen": False, "qpsol": qpsol, "seed": "none"})
    tr, backend = strat.transcription, strat.solvers[0].backend
    model = backend.model
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    sol = backend.solve(SolveRequest(tr.pack(*rest(pb), np.zeros(7)), p, tr.lbg, tr.ubg))
    assert sol.success
    v, lam_c, lam_v = model.start(
        SolveRequest(sol.w, p, tr.lbg, tr.ubg, sol.lam_g, sol.lam_x, False)
    )
    v = v + 0.02 * np.random.default_rng(1).normal(size=v.size)  # near the solution
    return tr, model, p, v, model.linearize(v, p), lam_c, lam_v


def _reach_squared(st):
    """The end effector's horizontal distance from the origin, squared [m^2]."""
    ee = st.kin.ee_position(st.x)
    return ee[0] ** 2 + ee[1] ** 2
