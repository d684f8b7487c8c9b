"""The sqp backend's IPOPT seed: its options, checked before anything is built,
the answer it keeps, and when it is made."""

from types import SimpleNamespace

import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends import SolveRequest
from aeromanip.nmpc.backends.base import NlpResult
from aeromanip.nmpc.backends.sqp.solver import SEED_FLOOR, SqpBackend, _cheaper
from aeromanip.nmpc.constraints import Bounds
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.strategies import Weighted
from aeromanip.references import Constant
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import ControlRate, EndEffectorTracking
from nmpc_helpers import make_problem


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
    assert opts["seed"] == "ipopt" and opts["seed_ratio"] == 3.0


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
        (1.0, 3.0 * 1.0 + SEED_FLOOR, False),  # exactly at seed_ratio x promise + floor
        (1.0, 3.0 * 1.0 + 2 * SEED_FLOOR, True),
        (0.0, 0.5 * SEED_FLOOR, False),  # within the floor of a zero promise
        (0.0, 2.0 * SEED_FLOOR, True),
    ],
)
def test_an_answer_is_re_seeded_only_above_seed_ratio_times_the_promise_plus_the_floor(
    seeded_backend, promise, f, seeded
):
    sqp, script = seeded_backend
    assert sqp.opts["seed_ratio"] == 3.0
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
