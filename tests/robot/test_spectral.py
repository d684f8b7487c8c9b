"""The closed-form extreme eigenvalues and condition number (``robot.spectral``) against
``numpy.linalg`` and the documented smoothing."""

import math

import casadi as ca
import numpy as np
import pytest

from aeromanip.robot.spectral import EPS_ISO, condition_number, extreme_eigenvalues


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
