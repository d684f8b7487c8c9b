"""SQP optimality measures, Hessian convexification and the closed-form eigenvalues, each
checked against a NumPy re-implementation of the documented formula or ``numpy.linalg``.

Truths: ``violation``/``complementarity`` written out by hand (CasADi sign convention),
the convexification rule of ``convexify.py`` re-done in NumPy (``rho = base 10^k``, the smallest
that makes ``H + rho C'C`` positive definite; otherwise ``|lambda|`` floored at
``EIGEN_FLOOR max(|lambda|max, 1e-3)``), and ``numpy.linalg.eigvalsh`` for the spectra.
"""

import math

import casadi as ca
import numpy as np
import pytest

from aeromanip.nmpc.backends.sqp.convexify import CONVEXIFY_DECADES, EIGEN_FLOOR, convexified
from aeromanip.nmpc.backends.sqp.optimality import complementarity, violation
from aeromanip.robot.spectral import EPS_ISO, condition_number, extreme_eigenvalues

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


def numpy_convexified(H, C, fixed):
    """The rule of ``convexify.convexified``, re-done with ``eigvalsh`` as the PD test."""

    def pd(M):
        return np.linalg.eigvalsh(M).min() > 0

    if pd(H):
        return H
    if C.shape[0] or fixed.size:
        scale = max(np.abs(np.diag(H)).max(), 1e-8)
        norms = np.concatenate([(C * C).sum(axis=1), np.ones(fixed.size)])
        base = scale / max(norms.mean(), 1e-12)
        CtC = C.T @ C
        for i in fixed:
            CtC[i, i] += 1.0
        for k in range(CONVEXIFY_DECADES):
            if pd(H + base * 10.0**k * CtC):
                return H + base * 10.0**k * CtC
    lam, V = np.linalg.eigh(H)
    lam = np.maximum(np.abs(lam), EIGEN_FLOOR * max(np.abs(lam).max(), 1e-3))
    return V @ np.diag(lam) @ V.T


CASES = {
    # H is indefinite but positive definite on the null space of C: a penalty fixes it
    "rows, rho = 10 base": (np.diag([1.0, -50.0]), np.array([[0.0, 1.0]]), []),
    "coupled, rho = 100 base": (np.array([[1.0, 10.0], [10.0, 1.0]]), np.array([[0.0, 1.0]]), []),
    "rows with small norms": (np.diag([1e-3, -2e-3]), np.array([[0.0, 0.1]]), []),
    "tiny diagonal": (np.diag([1e-9, -1e-9]), np.array([[0.0, 1.0]]), []),
    "a fixed variable": (np.diag([2.0, -3.0, 1.0]), np.array([[1.0, 0.0, 1.0]]), [1]),
    # its diagonal gets the row's C'C and the fixed variable's 1, both
    "a fixed variable a row touches": (
        np.diag([2.0, -3.0, 1.5]),
        np.array([[0.0, 2.0, 1.0]]),
        [1],
    ),
    "no rows: reflected, floored": (np.diag([10.0, -1e-9]), np.zeros((0, 2)), []),
    "small spectrum: 1e-3 floor": (np.diag([0.01, -1e-12]), np.zeros((0, 2)), []),
    "rows cannot fix it": (np.diag([1.0, -1.0]), np.array([[1.0, 0.0]]), []),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_convexified_matches_a_numpy_reimplementation(name):
    H, C, fixed = CASES[name]
    fixed = np.array(fixed, dtype=int)
    expected = numpy_convexified(H, C, fixed)
    np.testing.assert_allclose(convexified(H.copy(), C, fixed), expected, rtol=1e-12, atol=0)
    assert np.linalg.eigvalsh(expected).min() > 0


def eig(A, kink=0.0):
    S = ca.SX.sym("A", *A.shape)
    lo, hi = extreme_eigenvalues(S, kink)
    return [float(v) for v in ca.Function("e", [S], [lo, hi])(A)]


@pytest.mark.parametrize("diag", [[0.7, 0.3, 0.3], [0.1, 0.2, 0.2]])
def test_repeated_eigenvalues_where_the_cubic_argument_rounds_past_one(diag):
    """Here ``det(B)/2`` rounds to just above 1 (below -1): it must be clamped into acos."""
    A = np.diag(diag)
    np.testing.assert_allclose(eig(A), [min(diag), max(diag)], rtol=1e-7)


def test_isotropic_point_adds_eps_iso_under_the_square_root():
    """At ``A = c I`` the roots are ``sqrt(EPS_ISO^2)``: 2x2 ``lambda_max = c + EPS_ISO``,
    3x3 ``c + 2 EPS_ISO cos(pi/6)`` (documented smoothing)."""
    c = 1e-6
    assert eig(c * np.eye(2))[1] == pytest.approx(c + EPS_ISO, rel=1e-9, abs=0)
    assert eig(c * np.eye(3))[1] == pytest.approx(c + math.sqrt(3.0) * EPS_ISO, rel=1e-9, abs=0)


def test_condition_number_default_delta_is_tiny():
    """Default ``delta`` 1e-9: ``rho`` of ``diag(4, 1)`` is 4 to 1e-8."""
    S = ca.SX.sym("A", 2, 2)
    rho = float(ca.Function("r", [S], [condition_number(S)])(np.diag([4.0, 1.0])))
    assert rho == pytest.approx(np.linalg.cond(np.diag([4.0, 1.0])), rel=1e-8)


def test_no_rows_no_violation_no_complementarity():
    """A problem without rows: both measures are 0 (not the max of an empty array)."""
    empty = np.zeros(0)
    assert violation(empty, empty, empty) == 0.0
    assert complementarity(empty, empty, empty, empty) == 0.0
    one = np.array([2.0])
    assert violation(one, np.array([0.0]), np.array([1.5])) == 0.5
    assert complementarity(one, np.array([0.0]), np.array([3.0]), np.array([0.5])) == 0.5
