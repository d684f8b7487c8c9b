"""``accept_at_max_iter``: a solve that runs out of its ``max_iter`` QPs (second-order
corrections counted) ends with its iterate where that iterate's rows hold (a bounded
step for real time), and fails where they do not, with no cold retry.

Truth: the NLP's own rows and bounds, evaluated by CasADi on the answer (not the loop's
violation measure); the QPs the model solves, counted at the model; the same solve
without the option, which must reach the same iterate where it made no correction and
only judge it differently; the strict hierarchy's level reports.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from aeromanip.bench.controller_speed import bench_scenario
from aeromanip.nmpc.backends.sqp import solver as solver_module
from aeromanip.nmpc.backends.sqp.solver import DEFAULTS, SqpBackend
from aeromanip.nmpc.controller import Controller

BUDGET = 2  # QPs per solve
BOUNDED = {"seed": "none", "max_iter": BUDGET, "accept_at_max_iter": True}


@pytest.fixture(scope="module")
def recorded():
    """Every level's solve requests over 10 s of the ``fast`` case (velocity bounds
    bind), strict hierarchy, converged: (level's transcription, requests)."""
    sc = bench_scenario("fast", 10.0)
    hierarchy = dict(sc.hierarchy, mode="strict")
    ctrl = Controller(sc.problem, "hierarchical", "sqp", {"seed": "none"}, hierarchy=hierarchy)
    levels = []
    for ls in ctrl.strategy.solvers:
        requests, solve = [], ls.backend.solve
        ls.backend.solve = lambda r, solve=solve, requests=requests: requests.append(r) or solve(r)
        levels.append((ls.tr, requests))
    x = sc.x0.copy()
    for k in range(sc.steps):
        x = x + sc.problem.dt * ctrl.step(x, k * sc.problem.dt).u
    return levels


def _violation(tr, w: np.ndarray, request) -> float:
    """The largest violation of the NLP's rows and variable bounds at ``w`` (CasADi)."""
    g = np.array(ca.Function("g", [tr.w, tr.p], [tr.g])(w, request.p)).ravel()
    lbx, ubx = tr.variable_bounds(request.p)
    return max(np.max(request.lbg - g, initial=0.0), np.max(g - request.ubg, initial=0.0),
               np.max(lbx - w, initial=0.0), np.max(w - ubx, initial=0.0))  # fmt: skip


def _counting_qps(backend: SqpBackend) -> list[str]:
    """The QPs ``backend``'s model solves from now on: ``"step"`` or ``"correction"``."""
    solved: list[str] = []
    model = backend.model

    def counting(kind: str):
        real = getattr(model, kind)

        def counted(*args, **kwargs):
            solved.append(kind)
            return real(*args, **kwargs)

        return counted

    model.step, model.correction = counting("step"), counting("correction")
    return solved


@pytest.mark.parametrize("level", [0, 1])
def test_an_iterate_out_of_iterations_is_the_answer_exactly_where_its_rows_hold(recorded, level):
    """Every QP counts, second-order corrections too: at most ``BUDGET`` a solve. A solve
    whose unbounded twin (its Hessians convexified alike) made no correction reaches the
    same iterate, only judged otherwise."""
    tr, requests = recorded[level]
    bounded = SqpBackend(tr, BOUNDED)
    plain = SqpBackend(tr, {**BOUNDED, "accept_at_max_iter": False})
    plain.model.opts["accept_at_max_iter"] = True  # its QPs convexified as bounded ones
    qps, plain_qps = _counting_qps(bounded), _counting_qps(plain)
    tol = DEFAULTS["constr_viol_tol"]
    judged = {True: 0, False: 0}
    compared = corrections = 0
    for request in requests:
        qps.clear(), plain_qps.clear()
        got, ref = bounded.solve(request), plain.solve(request)
        assert got.iterations == len(qps) <= BUDGET
        corrections += qps.count("correction")
        if "correction" not in plain_qps:
            np.testing.assert_array_equal(got.w, ref.w)
            assert got.iterations == ref.iterations
            compared += 1
        if got.status not in ("Maximum_Iterations_Exceeded", "Feasible_At_Maximum_Iterations"):
            assert got.success
            continue
        holds = _violation(tr, got.w, request) <= tol
        assert got.success == holds
        assert got.status == (
            "Feasible_At_Maximum_Iterations" if holds else "Maximum_Iterations_Exceeded"
        )
        judged[holds] += 1
    if level == 0:  # the tracking level's rows are linear in its commands: they hold
        assert judged[True] > 0 and judged[False] == 0 and compared > 0
    else:  # the hierarchy's pinned rows curve: the corrections spend the budget
        assert judged[False] > 0 and corrections > 0


def test_a_bounded_hierarchy_spends_at_most_its_budget_per_level():
    """No level is retried cold after running out (a level whose solves are not bounded
    is: ``Backend.bounded_iterations``); a second level whose rows do not hold leaves
    the step partial, the first level's answer flying."""
    sc = bench_scenario("fast", 20.0)
    hierarchy = dict(sc.hierarchy, mode="strict")
    budget, spent = 6, {}  # QPs: the second level runs out now and then, warm
    opts = {**BOUNDED, "max_iter": budget}
    for bounded in (True, False):
        ctrl = Controller(sc.problem, "hierarchical", "sqp", opts, hierarchy=hierarchy)
        for ls in ctrl.strategy.solvers:
            assert ls.backend.bounded_iterations
            ls.backend.bounded_iterations = bounded
        x, levels, statuses = sc.x0.copy(), [], []
        for k in range(sc.steps):
            cmd = ctrl.step(x, k * sc.problem.dt)
            levels += [lv.iterations for lv in cmd.levels]
            statuses.append((cmd.status, [lv.success for lv in cmd.levels]))
            x = x + sc.problem.dt * cmd.u
        spent[bounded] = max(levels)
        if bounded:
            assert all(s != "fallback" for s, _ in statuses)
            for status, solved in statuses:
                assert status == ("ok" if all(solved) else "partial")
            assert any(s == "partial" for s, _ in statuses)
    assert spent[True] == budget < spent[False]


def test_only_a_bounded_solve_ignores_a_rise_of_rounding_before_a_correction(recorded, monkeypatch):
    """A bounded solve counts its corrections, so rounding must not decide them: its line
    searches pass ``SOC_MIN_RISE``; a converged solve's pass 0 (corrections at any rise)."""
    seen = []
    real = solver_module._line_search

    def spy(model, v, d, p, lin, mu, max_soc, min_rise):
        seen.append(min_rise)
        return real(model, v, d, p, lin, mu, max_soc, min_rise)

    monkeypatch.setattr(solver_module, "_line_search", spy)
    tr, requests = recorded[1]
    for bounded, want in ((True, solver_module.SOC_MIN_RISE), (False, 0.0)):
        seen.clear()
        SqpBackend(tr, {**BOUNDED, "accept_at_max_iter": bounded}).solve(requests[0])
        assert seen and set(seen) == {want}
