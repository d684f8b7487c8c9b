"""Hessian convexification for the SQP's QPs: a penalty on the active rows' normals
(dense Hessians) or reflected eigenvalues (per-stage blocks)."""

from __future__ import annotations

import numpy as np

CONVEXIFY_DECADES = 5  # penalties rho tried on the active normals: base * 10**(0..4)
EIGEN_FLOOR = 1e-6  # reflected eigenvalues kept above this share of the largest (or 1e-3)
CONVEX_TOL = 1e-9  # an eigenvalue below -tol x the largest entry: an indefinite block


def is_positive_definite(H: np.ndarray) -> bool:
    try:
        np.linalg.cholesky(H)
    except np.linalg.LinAlgError:
        return False
    return True


def convexified(H: np.ndarray, C: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """``H`` if positive definite; else ``H + rho C'C`` (plus ``rho`` on the ``fixed``
    variables' diagonal) for the smallest ``rho`` in a few decades that makes it so; else
    ``H`` with its eigenvalues reflected (``|lambda|``, floored)."""
    if is_positive_definite(H):
        return H
    if C.shape[0] or fixed.size:
        scale = max(float(np.abs(np.diag(H)).max()), 1e-8)
        norms = np.concatenate([np.einsum("ij,ij->i", C, C), np.ones(fixed.size)])
        base = scale / max(float(norms.mean()), 1e-12)
        CtC = C.T @ C
        CtC[fixed, fixed] += 1.0
        for rho in base * 10.0 ** np.arange(CONVEXIFY_DECADES):
            Hc = H + rho * CtC
            if is_positive_definite(Hc):
                return Hc
    lam, V = np.linalg.eigh(H)
    lam = np.maximum(np.abs(lam), EIGEN_FLOOR * max(np.abs(lam).max(), 1e-3))
    return (V * lam) @ V.T


def convexified_blocks(
    stage_blocks: np.ndarray, terminal_block: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The stage (``(N, n, n)``) and terminal Hessian blocks as they are if all are
    positive semi-definite (to ``CONVEX_TOL`` of the stage blocks' largest entry), else
    each with its eigenvalues' absolute values (one eigendecomposition per block)."""
    lam_s, vec_s = np.linalg.eigh(stage_blocks)
    lam_t, vec_t = np.linalg.eigh(terminal_block)
    scale = max(1.0, float(np.abs(stage_blocks).max(initial=0.0)))
    if min(lam_s.min(initial=0.0), lam_t.min(initial=0.0)) >= -CONVEX_TOL * scale:
        return stage_blocks, terminal_block

    def reflected(lam: np.ndarray, vec: np.ndarray) -> np.ndarray:
        return (vec * np.abs(lam)[..., None, :]) @ np.swapaxes(vec, -1, -2)

    return reflected(lam_s, vec_s), reflected(lam_t, vec_t)
