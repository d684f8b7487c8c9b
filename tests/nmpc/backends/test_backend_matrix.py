"""Every backend on every built-in problem, against IPOPT converged tightly on the same NLP.

Each built-in scenario variant's problem is solved once from its initial state (a cold
start from rest: identical inputs) by the backend under test and by IPOPT
(``tol = 1e-12``: a strict hierarchy's higher level, its regulariser lightened, has small
costs, ~1e-4 at 1 % of its weight, and ``1e-10`` left them ~1e-6 apart, the tolerance the
comparison allows). The problems are nonconvex, so two solvers may stop in different
local optima; what must hold is:

* the backend's answer is a local optimum: IPOPT restarted there stays (same costs; for
  the weighted strategy: IPOPT starts a hierarchy's lower levels from the level above's
  answer, not from a guess);
* it is no worse than IPOPT's: its level costs, compared in priority order (one level for
  the weighted strategy), are not higher;
* where both reach the same optimum, they apply the same command.
"""

import numpy as np
import pytest

from aeromanip.experiment.scenario import builtin_scenarios, load_scenarios
from aeromanip.nmpc.controller import Controller

REFERENCE = {"ipopt.tol": 1e-12}
# restarted at an answer, IPOPT's barrier must start small or it walks away from it
RESTART = {**REFERENCE, "ipopt.mu_init": 1e-10, "ipopt.warm_start_bound_push": 1e-10}
OPTIONS = {
    "fatrop": {"fatrop.tol": 1e-11},
    "sqp": {"tol": 1e-11, "qpsol": "daqp"},  # condensed, dense QP
    "sqp-hpipm": {"tol": 1e-11, "qpsol": "hpipm"},  # multiple shooting, sparse QP
    "sqp-riccati": {"tol": 1e-11, "qpsol": "riccati"},  # the same, aeromanip's QP solver
}
REL = 1e-6  # costs within this (relative) are the same optimum
CASES = [(name, variant) for name in builtin_scenarios() for variant in load_scenarios(name)]


def solve(sc, backend, options, guess=None):
    """One step from the scenario's initial state; ``guess`` (X, U) replaces the cold start."""
    ctrl = Controller(sc.problem, sc.strategy, backend, options, hierarchy=sc.hierarchy or None)
    if guess is not None:  # start every level at the given plan
        ctrl.initial_guesses = lambda x0: (
            [ctrl.strategy.transcription.pack(*guess, ctrl.u_prev)] * (len(ctrl.strategy.solvers))
        )
    cmd = ctrl.step(sc.x0, 0.0)
    assert cmd.status == "ok", (backend, cmd.message)
    return cmd


def level_costs(cmd):
    """What each level minimised at its optimum (its tasks and the regularisers)."""
    return np.array([lv.objective for lv in cmd.levels])


def same(a, b):
    return bool(np.all(np.abs(a - b) <= REL * np.maximum(np.abs(b), 1e-8)))


KNOWN = {  # cases that fail today, each with its reason: strict, so a fix is noticed
    ("clearance", "", "fatrop"): "fatrop fails from rest with the clearance binding",
    ("contact-deck", "hierarchical", "fatrop"): "fatrop's lower level (the CoG, the "
    "contact level's rows pinned) stops with SOLVER_RET_UNKNOWN from rest: a partial step",
    **{
        (name, variant, "fatrop"): "with the tracking level's regulariser at 10 %, "
        "fatrop from rest lands in another local optimum, 0.9 % above IPOPT's at level 0"
        for name, variant in [
            ("waypoints", "hierarchical"),
            ("waypoints-rates", "2hz"),
            ("waypoints-physics", "paper-hierarchical"),
        ]
    },
}


@pytest.mark.parametrize("backend", ["sqp", "sqp-hpipm", "sqp-riccati", "fatrop"])
@pytest.mark.parametrize(("name", "variant"), CASES, ids=[f"{n}/{v}" for n, v in CASES])
def test_backend_reaches_an_optimum_no_worse_than_ipopts(name, variant, backend, request):
    if (name, variant, backend) in KNOWN:
        request.applymarker(pytest.mark.xfail(strict=True, reason=KNOWN[name, variant, backend]))
    sc = load_scenarios(name, only=variant or None)[variant]
    got = solve(sc, backend.split("-")[0], OPTIONS[backend])
    ref = solve(sc, "ipopt", REFERENCE)
    mine, theirs = level_costs(got), level_costs(ref)
    if sc.strategy == "weighted":
        stay = level_costs(solve(sc, "ipopt", RESTART, guess=(got.plan_x, got.plan_u)))
        assert same(stay, mine), ("not a local optimum", stay, mine)
    for a, b in zip(mine, theirs, strict=True):  # lexicographic: the first difference decides
        if not same(a, b):
            assert a < b, f"a worse optimum than IPOPT's: levels {mine} vs {theirs}"
            return
    scale = 1.0 + np.abs(ref.u).max()
    np.testing.assert_allclose(got.u, ref.u, atol=1e-5 * scale)
