"""Closed-form, smooth extreme eigenvalues of small symmetric matrices (CasADi symbolic).

Used for the condition number ``rho = lambda_max / lambda_min`` of ``J_eq J_eq^T``
(paper eq. 16). Eigenvalue solvers are not differentiable symbolically, so for sizes
1, 2 and 3 we use the exact closed forms:

* 2x2: ``lambda = tr/2 +- sqrt(((a - c)/2)^2 + b^2)``;
* 3x3: the trigonometric form of the cubic's roots (O. K. Smith, CACM 1961).

Smoothing (documented behaviour):

* the square roots get ``+ EPS_ISO**2`` inside, so the expressions stay differentiable at
  the isotropic point (all eigenvalues equal, ``rho = 1``: the optimum of task ``h5``);
  the error this adds to an eigenvalue is below ``EPS_ISO`` = 1e-12;
* 3x3: ``lambda_max`` comes from the trigonometric form; ``lambda_min`` from the two
  other eigenvalues' sum ``s = tr - lambda_max`` and product ``P = det / lambda_max`` by
  the stable root ``2P / (s + sqrt(s^2 - 4P))``, which keeps it *relatively* accurate as
  the matrix becomes singular (the trigonometric form loses it to cancellation);
* ``rho`` has kinks where the two largest or two smallest eigenvalues coincide (it is
  not differentiable at a repeated extreme eigenvalue), and minimising ``rho`` drives the
  matrix exactly onto them, where Newton-type solvers cycle. ``kink`` rounds them: the
  ``acos`` argument is scaled by ``1 - kink`` and ``kink s^2`` is added under the root.
  The relative error this puts on an extreme eigenvalue is about ``kink / 2`` away from
  coalescence and at most about ``sqrt(kink)`` at it. The default 1e-12 is for exact
  values; the ``ConditionNumber`` task uses 1e-4 (a ~1% rounding, measured in the tests);
* near a singular configuration ``lambda_min -> 0`` and ``rho -> inf``; ``condition_number``
  returns ``(lambda_max + delta) / (lambda_min + delta)`` with ``delta`` (default 1e-9, in
  the units of the matrix) so that it is finite and smooth there, and still ``>= 1``.
"""

from __future__ import annotations

import casadi as ca

from aeromanip.errors import ConfigError

EPS_ISO = 1e-12
KINK = 1e-12


def extreme_eigenvalues(
    A: ca.SX | ca.MX, kink: float = KINK
) -> tuple[ca.SX | ca.MX, ca.SX | ca.MX]:
    """``(lambda_min, lambda_max)`` of a symmetric 1x1, 2x2 or 3x3 symbolic matrix."""
    n = A.shape[0]
    if A.shape != (n, n):
        raise ConfigError(f"extreme_eigenvalues: matrix must be square, got {A.shape}")
    if n == 1:
        return A[0, 0], A[0, 0]
    if n == 2:
        half_tr = 0.5 * (A[0, 0] + A[1, 1])
        r = ca.sqrt((0.5 * (A[0, 0] - A[1, 1])) ** 2 + A[0, 1] ** 2 + EPS_ISO**2)
        lam_max = half_tr + r
        # det / lambda_max keeps lambda_min relatively accurate near singular matrices
        return ca.det(A) / lam_max, lam_max
    if n == 3:
        q = (A[0, 0] + A[1, 1] + A[2, 2]) / 3.0
        p1 = A[0, 1] ** 2 + A[0, 2] ** 2 + A[1, 2] ** 2
        p2 = (A[0, 0] - q) ** 2 + (A[1, 1] - q) ** 2 + (A[2, 2] - q) ** 2 + 2.0 * p1
        p = ca.sqrt(p2 / 6.0 + EPS_ISO**2)
        B = (A - q * ca.DM.eye(3)) / p
        r = ca.fmin(ca.fmax(ca.det(B) / 2.0, -1.0), 1.0) * (1.0 - kink)
        lam_max = q + 2.0 * p * ca.cos(ca.acos(r) / 3.0)
        # the two others are the roots of t^2 - s t + P: s = their sum, P = their product;
        # the stable root formula keeps lambda_min relatively accurate (even as A -> singular)
        s = 3.0 * q - lam_max
        prod = ca.det(A) / lam_max
        gap = ca.sqrt(ca.fmax(s * s - 4.0 * prod, 0.0) + kink * s * s)
        return 2.0 * prod / (s + gap), lam_max
    raise ConfigError(
        f"condition number: closed form exists for up to 3 tracked coordinates, got {n}"
    )


def condition_number(A: ca.SX | ca.MX, delta: float = 1e-9, kink: float = KINK) -> ca.SX | ca.MX:
    """Regularised condition number ``(lambda_max + delta) / (lambda_min + delta)`` of SPD ``A``."""
    lam_min, lam_max = extreme_eigenvalues(A, kink)
    return (lam_max + delta) / (ca.fmax(lam_min, 0.0) + delta)
