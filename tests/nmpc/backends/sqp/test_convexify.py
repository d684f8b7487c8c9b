"""Hessian convexification against a NumPy re-implementation of the rule of ``convexify.py``
(``rho = base 10^k``, the smallest that makes ``H + rho C'C`` positive definite; otherwise
``|lambda|`` floored at ``EIGEN_FLOOR max(|lambda|max, 1e-3)``), with ``numpy.linalg.eigvalsh``
as the positive-definiteness test."""

import numpy as np
import pytest

from aeromanip.nmpc.backends.sqp.convexify import CONVEXIFY_DECADES, EIGEN_FLOOR, convexified


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
