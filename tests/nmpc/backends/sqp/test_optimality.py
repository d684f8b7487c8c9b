"""SQP optimality measures against the documented formula written out by hand (CasADi sign
convention)."""

import math

import numpy as np
import pytest

from aeromanip.nmpc.backends.sqp.optimality import complementarity, violation

LB, UB = np.array([0.0, -1.0]), np.array([1.0, 1.0])


@pytest.mark.parametrize(
    ("g", "expected"),
    [([-0.5, 0.0], 0.5), ([0.5, 1.25], 0.25), ([0.5, 0.0], 0.0), ([1.0, -1.0], 0.0)],
)
def test_violation_is_the_largest_bound_excess(g, expected):
    assert violation(np.array(g), LB, UB) == expected


def test_complementarity_uses_the_bound_of_the_multiplier_sign():
    g = np.array([0.5, 0.5])
    # lam > 0 pairs with the upper bound, lam < 0 with the lower one
    assert complementarity(g, LB, UB, np.array([0.5, 0.0])) == pytest.approx(0.25)
    assert complementarity(g, LB, UB, np.array([0.0, -0.4])) == pytest.approx(0.6)
    assert complementarity(g, LB, UB, np.array([2.0, 0.0])) == pytest.approx(1.0)
    assert complementarity(np.array([math.nan, 0.0]), LB, UB, np.array([1.0, 0.0])) == math.inf


def test_no_rows_no_violation_no_complementarity():
    """A problem without rows: both measures are 0 (not the max of an empty array)."""
    empty = np.zeros(0)
    assert violation(empty, empty, empty) == 0.0
    assert complementarity(empty, empty, empty, empty) == 0.0
    one = np.array([2.0])
    assert violation(one, np.array([0.0]), np.array([1.5])) == 0.5
    assert complementarity(one, np.array([0.0]), np.array([3.0]), np.array([0.5])) == 0.5
