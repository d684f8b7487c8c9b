"""The SQP's answer: multipliers that make it a KKT point of the NLP, the stopping
test at its tolerances, the warm start's multipliers and what a solve reports.
"""

from __future__ import annotations

import time
from types import SimpleNamespace

import casadi as ca
import numpy as np
import pytest

from aeromanip.nmpc.backends import SolveRequest
from aeromanip.nmpc.backends.sqp.solver import (
    DEFAULTS,
    SqpBackend,
)
from aeromanip.nmpc.constraints import Bounds, Clearance
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.strategies import Weighted
from aeromanip.references import Constant
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import ControlRate, EndEffectorTracking
from nmpc_helpers import X0, rest


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
