"""The SQP backend's options as documented: each option's type and range (the
docstrings and comments of ``sqp.DEFAULTS``), ``hessian`` ("auto" going exact as
``sqp._go_exact`` says, and the option reaching every QP), the checkers' words.
The line search is in ``test_line_search.py``, the answer in ``test_sqp_answer.py``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends.sqp.solver import (
    DEFAULTS,
    EXACT_FROM_ITERATION,
    HESSIANS,
    OPTION_CHECKS,
    SqpBackend,
    _go_exact,
    _number,
    _one_of,
)
from aeromanip.nmpc.constraints import Bounds
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.strategies import Weighted
from aeromanip.references import Constant
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import EndEffectorTracking

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


def test_auto_hessian_goes_exact_at_the_first_short_step_or_the_seventh_iteration():
    assert not _go_exact(False, 1.0, 0)
    assert not _go_exact(False, 1.0, EXACT_FROM_ITERATION - 1)
    assert _go_exact(False, 1.0, EXACT_FROM_ITERATION)
    assert EXACT_FROM_ITERATION == 6  # "the 7th iteration" of DEFAULTS' comment, 0-based
    assert _go_exact(False, 0.5, 0)
    assert _go_exact(True, 1.0, 0)  # once exact, exact for the solve


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
