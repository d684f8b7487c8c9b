"""The sqp backend's IPOPT seed (issue 14): its options, checked before anything is built,
the answer it keeps, and when it is made."""

import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends.base import NlpResult
from aeromanip.nmpc.backends.sqp import SqpBackend, _cheaper
from aeromanip.nmpc.constraints import Bounds
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.strategies import Weighted
from aeromanip.references import Constant
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import ControlRate, EndEffectorTracking


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


def result(f, success=True, iterations=2, time_s=0.01):
    return NlpResult(np.zeros(1), np.zeros(0), np.zeros(1), f, success, "", iterations, time_s)


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
        first = backend.solve(w0, p, tr.lbg, tr.ubg)
        tracking.reference = Constant([0.4, 0.0, 0.6])  # the jump
        p2 = tr.parameters(x0, np.zeros(7), pb.stage_params(0.0))
        second = backend.solve(first.w, p2, tr.lbg, tr.ubg, first.lam_g, first.lam_x, False)
        assert first.success and second.success
        assert second.f > backend.opts["seed_ratio"] * first.f
        seeds[seed] = backend.seeds
    assert seeds == {"ipopt": 2, "none": 0}  # the cold start and the jump; none at all
