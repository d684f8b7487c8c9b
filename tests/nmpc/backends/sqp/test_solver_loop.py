"""The SQP loop (``SqpBackend._sqp``) against a scripted stand-in model: what each QP is
given (damping, Hessian, multipliers), the merit's penalty, the count of acceptable
iterations, a cost that is not a number. Each expectation follows from the rules in the
module's docstrings (the damping schedule, ``_go_exact``, ``PENALTY_MARGIN`` /
``PENALTY_FLOOR``), worked out by hand here. (The IPOPT seed's decisions:
``tests/nmpc/backends/sqp/test_ipopt_seed.py``.)"""

from types import SimpleNamespace

import numpy as np
import pytest

from aeromanip.nmpc.backends import SolveRequest
from aeromanip.nmpc.backends.sqp import solver as sqp_module
from aeromanip.nmpc.backends.sqp.qp_model import Linearization, QpResult
from aeromanip.nmpc.backends.sqp.solver import (
    ACCURATE_QPS_BELOW,
    DAMPING_START,
    DEFAULTS,
    PENALTY_FLOOR,
    PENALTY_MARGIN,
    SqpBackend,
)
from aeromanip.nmpc.backends.sqp.sparse_qp import SparseQpModel


class ScriptedModel:
    """A QP model of one variable whose iterates are scripted: the KKT error of iterate
    ``k`` is ``kkt[k]``, QP ``k`` returns the step ``d = 1``, row multiplier ``lams[k]``
    and bound multiplier ``k + 1``, and the merit refuses its full step when ``k`` is in
    ``short`` (half of it is then taken) and every step longer than ``cut[k]``; the cost
    is 1 (``nan`` at the iterates in ``nan_at``), the rows hold. Each QP's inputs are
    recorded in ``calls``."""

    def __init__(self, kkt, lams=None, short=(), nan_at=(), cut=None):
        self.kkt, self.lams, self.short, self.nan_at = kkt, lams, set(short), set(nan_at)
        self.cut = cut or {}  # QP index -> the longest step its line search accepts
        self.calls = []

    def start(self, request):
        lam_c = np.zeros(1) if request.cold else np.asarray(request.lam_g0, dtype=float)
        return np.zeros(1), lam_c, np.zeros(1)

    def linearize(self, v, p):
        f = np.nan if len(self.calls) in self.nan_at else 1.0
        return Linearization(f, np.array([-1.0]), np.zeros(1), -np.ones(1), np.ones(1))

    def kkt_error(self, v, lin, lam_c, lam_v):
        return self.kkt[len(self.calls)]

    def step(self, v, lin, lam_c, lam_v, p, exact, damping=0.0, accurate=False):
        k = len(self.calls)
        self.calls.append(SimpleNamespace(v=v.copy(), damping=damping, exact=exact,
                                          accurate=accurate, lam_c=lam_c.copy(),
                                          lam_v=lam_v.copy()))  # fmt: skip
        lam = np.array([self.lams[k] if self.lams else 0.0])
        return QpResult(np.ones(1), lam, np.array([k + 1.0]), True, "")

    def merit(self, w, p):
        call = self.calls[-1]
        alpha = float(w[0] - call.v[0])
        if alpha == 1.0 and len(self.calls) - 1 in self.short:
            return 1e9, 0.0
        if alpha > self.cut.get(len(self.calls) - 1, 1.0):
            return 1e9, 0.0
        return 1.0 - alpha, 0.0

    def result(self, v, p, lam_c, lam_v):
        return v, lam_c, lam_v


class ScriptedSparseModel(ScriptedModel, SparseQpModel):
    """The same script, of the sparse model's type (``_go_exact`` has a rule of its own
    for it)."""


def backend(model, **opts):
    """An ``SqpBackend`` with only what ``_sqp`` reads: its options, ``model`` and no
    compiled loop (the Python loop runs the script)."""
    sqp = object.__new__(SqpBackend)
    sqp.opts = {**DEFAULTS, "tol": 1e-8, "acceptable_tol": 1e-6, **opts}
    sqp.model = model
    sqp.loop = None
    return sqp


def run(sqp, warm=False):
    lam = np.zeros(1) if warm else None
    return sqp._sqp(
        SolveRequest(np.zeros(1), np.zeros(0), np.zeros(1), np.zeros(1), lam, lam, False)
    )


def test_each_qp_gets_the_damping_the_last_step_left_and_the_last_qps_multipliers():
    """Four QPs, the second one's full step refused: damping 0 for the first QP, then
    ``_damping``'s schedule (1e-3 after the short step, back to 0 after a full one); each
    QP gets the previous QP's multipliers (the first: the start's)."""
    model = ScriptedModel(kkt=[1.0] * 4 + [0.0], lams=[0.1, 0.2, 0.3, 0.4], short={1})
    res = run(backend(model))
    assert res.success and res.status == "Solve_Succeeded" and res.iterations == 4
    assert [c.damping for c in model.calls] == [0.0, 0.0, DAMPING_START, 0.0]
    assert [c.lam_v[0] for c in model.calls] == [0.0, 1.0, 2.0, 3.0]
    assert [c.lam_c[0] for c in model.calls] == [0.0, 0.1, 0.2, 0.3]
    np.testing.assert_allclose(res.w, [3.5])  # three full steps and a half one


def test_a_line_search_cut_below_a_hundredth_makes_the_solves_later_qps_accurate():
    """Five QPs: steps of 1, 1/2, 1/128, 1 (the second one shortened, the third cut below
    ``ACCURATE_QPS_BELOW``): the QPs after the third are asked to be accurate, to the end
    of the solve, and the next solve starts inexact again."""
    model = ScriptedModel(kkt=[1.0] * 5 + [0.0], cut={1: 0.5, 2: 2.0**-7})
    assert 2.0**-6 > ACCURATE_QPS_BELOW > 2.0**-7  # the third cut just below the edge
    sqp = backend(model)
    run(sqp)
    assert [c.accurate for c in model.calls] == [False, False, False, True, True]
    model.calls.clear()
    model.cut = {1: 2.0**-6}  # just above the edge: no accuracy asked
    model.kkt = [1.0] * 3 + [0.0]
    run(sqp)
    assert [c.accurate for c in model.calls] == [False, False, False]


@pytest.mark.parametrize(
    ("model_type", "exact"),
    [
        # dense: exact from the first short step on, and it stays
        (ScriptedModel, [False, False, True, True, True]),
        # sparse: exact after a full step from the second iteration on
        (ScriptedSparseModel, [False, False, False, True, False]),
    ],
)
def test_auto_hessian_in_the_loop_follows_go_exact_for_the_models_type(model_type, exact):
    """``hessian = "auto"``: the QPs' ``exact`` flags over five QPs, the second and the
    fourth one's full steps refused (``_go_exact``'s rules per model type, its ``exact``
    argument being the last QP's)."""
    model = model_type(kkt=[1.0] * 5 + [0.0], short={1, 3})
    run(backend(model, hessian="auto"))
    assert [c.exact for c in model.calls] == exact


def test_the_merits_penalty_is_the_largest_multiplier_so_far_with_margin_and_floor(monkeypatch):
    """The line search's ``mu``: ``PENALTY_MARGIN max|lam| + PENALTY_FLOOR`` of the QP's
    row multipliers, never decreasing: the floor alone while they are 0."""
    seen = []
    real = sqp_module._line_search

    def spy(model, v, d, p, lin, mu):
        seen.append(mu)
        return real(model, v, d, p, lin, mu)

    monkeypatch.setattr(sqp_module, "_line_search", spy)
    model = ScriptedModel(kkt=[1.0] * 4 + [0.0], lams=[0.0, 0.5, -0.2, -0.7])
    run(backend(model))
    top = PENALTY_MARGIN * 0.5 + PENALTY_FLOOR
    assert seen == [PENALTY_FLOOR, top, top, PENALTY_MARGIN * 0.7 + PENALTY_FLOOR]


def test_acceptable_iter_iterates_in_a_row_at_the_acceptable_level_end_the_solve():
    """``acceptable_iter = 3``, every iterate between ``tol`` and ``acceptable_tol``, a
    warm start (the KKT error measured from the first iterate): iterates 0, 1, 2 are the
    three, so the solve ends after 2 QPs."""
    model = ScriptedModel(kkt=[1e-7] * 10)
    res = run(backend(model, acceptable_iter=3), warm=True)
    assert res.status == "Solved_To_Acceptable_Level" and res.success
    assert res.iterations == 2


def test_a_cost_that_is_not_a_number_ends_the_solve_as_a_failure():
    model = ScriptedModel(kkt=[1.0] * 5, nan_at={2})
    res = run(backend(model))
    assert res.status == "Invalid_Number_Detected" and not res.success
    assert res.iterations == 2 and np.isnan(res.f)
