"""The SQP solve (``SqpBackend``): its loop against a scripted stand-in model, and its IPOPT
seed.

The loop: what each QP is given (damping, Hessian, multipliers), the merit's penalty, the
count of acceptable iterations, a cost that is not a number. Each expectation follows from
the rules in the module's docstrings (the damping schedule, ``_go_exact``,
``PENALTY_MARGIN`` / ``PENALTY_FLOOR``), worked out by hand here.

The IPOPT seed: its options, checked before anything is built, the answer it keeps, and
when it is made."""

from types import SimpleNamespace

import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends import SolveRequest
from aeromanip.nmpc.backends.base import NlpResult
from aeromanip.nmpc.backends.sqp import solver as sqp_module
from aeromanip.nmpc.backends.sqp.qp_model import Linearization, QpResult
from aeromanip.nmpc.backends.sqp.solver import (
    ACCURATE_QPS_BELOW,
    DAMPING_START,
    DEFAULTS,
    PENALTY_FLOOR,
    PENALTY_MARGIN,
    SEED_FLOOR,
    SqpBackend,
    _cheaper,
)
from aeromanip.nmpc.backends.sqp.sparse_qp import SparseQpModel
from aeromanip.nmpc.constraints import Bounds
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.strategies import Weighted
from aeromanip.references import Constant
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import ControlRate, EndEffectorTracking
from nmpc_helpers import make_problem


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
    """The same script, of the sparse model's type."""


def backend(model, **opts):
    """An ``SqpBackend`` with only what ``_sqp`` reads: its options, ``model`` and no
    compiled loop or real-time iteration (the Python loop runs the script)."""
    sqp = object.__new__(SqpBackend)
    sqp.opts = {**DEFAULTS, "tol": 1e-8, "acceptable_tol": 1e-6, **opts}
    sqp.model = model
    sqp.loop = sqp.rti = None
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
        # exact from the first short step on, and it stays: the same rule for both
        (ScriptedModel, [False, False, True, True, True]),
        (ScriptedSparseModel, [False, False, True, True, True]),
    ],
)
def test_auto_hessian_in_the_loop_follows_go_exact_for_the_models_type(model_type, exact):
    """``hessian = "auto"``: the QPs' ``exact`` flags over five QPs, the second and the
    fourth one's full steps refused (``_go_exact``'s rule, its ``exact`` argument being
    the last QP's), whichever the model's type."""
    model = model_type(kkt=[1.0] * 5 + [0.0], short={1, 3})
    run(backend(model, hessian="auto"))
    assert [c.exact for c in model.calls] == exact


def test_the_merits_penalty_is_the_largest_multiplier_so_far_with_margin_and_floor(monkeypatch):
    """The line search's ``mu``: ``PENALTY_MARGIN max|lam| + PENALTY_FLOOR`` of the QP's
    row multipliers, never decreasing: the floor alone while they are 0."""
    seen = []
    real = sqp_module._line_search

    def spy(model, v, d, p, lin, mu, *rest):
        seen.append(mu)
        return real(model, v, d, p, lin, mu, *rest)

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


# --- the IPOPT seed ------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"seed": "acados"}, "solver_options.seed: 'acados' is not one of ['ipopt', 'none']"),
        ({"seed_ratio": 0.5}, "solver_options.seed_ratio: 0.5 is not a finite number >= 1"),
        ({"seed_ratio": float("nan")}, "solver_options.seed_ratio: nan is not a finite"),
    ],
)
def test_bad_seed_options_are_one_clear_line(options, message):
    with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("]", r"\]")):
        SqpBackend.checked_options(options)


def test_seed_defaults():
    opts = SqpBackend.checked_options({})
    assert opts["seed"] == "ipopt" and opts["seed_ratio"] == 10.0


def result(f, success=True, iterations=2, time_s=0.01, w=0.0):
    """An answer of cost ``f`` at ``w`` (multipliers 7 and 8, to be recognised)."""
    return NlpResult(np.full(1, w), np.full(1, 7.0), np.full(1, 8.0), f, success, "",
                     iterations, time_s)  # fmt: skip


@pytest.mark.parametrize(
    ("fa", "ok_a", "fb", "ok_b", "kept"),
    [
        (2.0, True, 1.0, True, "b"),  # both solved: the cheaper
        (1.0, True, 2.0, True, "a"),
        (1.0, True, 1.0, True, "a"),  # a tie keeps the first
        (2.0, False, 5.0, True, "b"),  # only one solved: that one, whatever it costs
        (5.0, True, 1.0, False, "a"),
        (1.0, False, 0.5, False, "a"),  # neither: the first
    ],
)
def test_the_cheaper_successful_answer_is_kept_with_the_effort_of_both(fa, ok_a, fb, ok_b, kept):
    a, b = result(fa, ok_a, 3, 0.01), result(fb, ok_b, 4, 0.02)
    best = _cheaper(a, b)
    assert best is (a if kept == "a" else b)
    assert best.iterations == 7 and best.solve_time_s == pytest.approx(0.03)


def test_an_answer_far_above_the_promise_is_solved_again_from_an_ipopt_seed():
    """The reference jumps 0.4 m after the first solve: the next answer costs far more than
    the last one promised, so IPOPT seeds a second solve and the cheaper answer is kept;
    with ``seed = "none"`` no IPOPT solve is made."""
    x8 = load_robot("x8-3dof")
    x0 = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.6, -1.2])
    seeds = {}
    for seed in ("ipopt", "none"):
        pb = Problem(x8, 6, 0.5, Bounds.from_robot(x8))
        tracking = EndEffectorTracking(Constant([0.0, 0.0, 0.6]))
        pb.add_task(tracking, weight=10.0)
        pb.add_task(ControlRate(), weight=0.05)
        strat = Weighted(pb, "sqp", {"codegen": False, "seed": seed})
        tr, backend = strat.transcription, strat.solvers[0].backend
        w0 = tr.pack(np.tile(x0, (7, 1)), np.zeros((6, 7)), np.zeros(7))
        p = tr.parameters(x0, np.zeros(7), pb.stage_params(0.0))
        first = backend.solve(SolveRequest(w0, p, tr.lbg, tr.ubg))
        tracking.reference = Constant([0.4, 0.0, 0.6])  # the jump
        p2 = tr.parameters(x0, np.zeros(7), pb.stage_params(0.0))
        second = backend.solve(
            SolveRequest(first.w, p2, tr.lbg, tr.ubg, first.lam_g, first.lam_x, False)
        )
        assert first.success and second.success
        assert second.f > backend.opts["seed_ratio"] * first.f
        seeds[seed] = backend.seeds
    assert seeds == {"ipopt": 2, "none": 0}  # the cold start and the jump; none at all


# --- when a solve is seeded, against scripted SQP and IPOPT answers ---------------------


@pytest.fixture
def seeded_backend():
    """A real ``sqp`` backend (small problem, seed on) whose SQP loop and IPOPT solves are
    scripted: ``script.sqp`` / ``script.ipopt`` are popped in order, ``script.sqp_calls``
    records each SQP start (``w0``, multipliers, shift)."""
    strat = Weighted(make_problem(levels=(0, 0), horizon=2), "sqp", {"codegen": False})
    sqp = strat.solvers[0].backend
    script = SimpleNamespace(sqp=[], ipopt=[], sqp_calls=[])

    def fake_sqp(r):
        script.sqp_calls.append((r.w0, r.lam_g0, r.lam_x0, r.shift))
        return script.sqp.pop(0)

    def fake_ipopt(r):
        assert r.cold  # the seed is a cold start
        return script.ipopt.pop(0)

    sqp._sqp = fake_sqp
    sqp._ipopt = SimpleNamespace(solve=fake_ipopt)
    return sqp, script


def solve(sqp, warm=True):
    lam = np.zeros(1) if warm else None
    return sqp.solve(SolveRequest(np.zeros(1), np.zeros(0), np.zeros(1), np.zeros(1), lam, lam))


def test_a_first_warm_solve_has_no_promise_to_be_measured_against(seeded_backend):
    """Multipliers given to a fresh backend: no cold-start seed, and no earlier answer
    whose cost the new one could be far above."""
    sqp, script = seeded_backend
    script.sqp = [result(5.0)]
    assert solve(sqp).f == 5.0 and sqp.seeds == 0


def test_a_failed_answer_makes_no_promise(seeded_backend):
    """After a failed solve (cost 0) the next answer, however far above 0, is not
    re-seeded; after a successful one of the same cost it is."""
    sqp, script = seeded_backend
    script.sqp = [result(0.0, success=False), result(1.0), result(0.0), result(1.0), result(0.5)]
    script.ipopt = [result(2.0)]  # the seed, then the SQP from it (0.5)
    solve(sqp), solve(sqp)
    assert sqp.seeds == 0
    solve(sqp), solve(sqp)
    assert sqp.seeds == 1


@pytest.mark.parametrize(
    ("promise", "f", "seeded"),
    [
        (1.0, 10.0 * 1.0 + SEED_FLOOR, False),  # exactly at seed_ratio x promise + floor
        (1.0, 10.0 * 1.0 + 2 * SEED_FLOOR, True),
        (0.0, 0.5 * SEED_FLOOR, False),  # within the floor of a zero promise
        (0.0, 2.0 * SEED_FLOOR, True),
    ],
)
def test_an_answer_is_re_seeded_only_above_seed_ratio_times_the_promise_plus_the_floor(
    seeded_backend, promise, f, seeded
):
    sqp, script = seeded_backend
    assert sqp.opts["seed_ratio"] == 10.0
    script.sqp = [result(promise), result(f), result(0.5 * f)]  # the last one from the seed
    script.ipopt = [result(0.5 * f)]
    solve(sqp), solve(sqp)
    assert sqp.seeds == int(seeded)


@pytest.mark.parametrize("ipopt_ok", [True, False])
def test_a_seeded_solve_starts_the_sqp_from_ipopts_answer_only_if_ipopt_solved(
    seeded_backend, ipopt_ok
):
    """A cold solve: IPOPT first; the SQP from IPOPT's answer and multipliers (as this
    step's: not shifted) if IPOPT solved, else cold from ``w0``. The time is both solves',
    the iterations the SQP's QPs only."""
    sqp, script = seeded_backend
    script.ipopt = [result(2.0, success=ipopt_ok, iterations=9, time_s=0.25, w=4.0)]
    script.sqp = [result(1.0, iterations=2, time_s=0.5)]
    res = solve(sqp, warm=False)
    ((w0, lam_g0, lam_x0, shift),) = script.sqp_calls
    if ipopt_ok:
        assert w0[0] == 4.0 and lam_g0[0] == 7.0 and lam_x0[0] == 8.0 and not shift
    else:
        assert w0[0] == 0.0 and lam_g0 is None and lam_x0 is None
    assert res.iterations == 2 and res.solve_time_s == pytest.approx(0.75)
    assert sqp.seeds == 1
