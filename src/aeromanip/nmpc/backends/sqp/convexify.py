"""Hessian convexification for the SQP's QPs: a penalty on the active rows' normals
(dense Hessians), or the Riccati recursion's pivots made positive definite (per-stage
blocks of a problem with linear dynamics), or each block's eigenvalues reflected (for a
QP solver that needs every block positive semi-definite)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

CONVEXIFY_DECADES = 5  # penalties rho tried on the active normals: base * 10**(0..4)
EIGEN_FLOOR = 1e-6  # reflected eigenvalues kept above this share of the largest (or 1e-3)
#: the shifts ``delta`` tried on the commands' diagonal (times the largest diagonal entry)
SHIFTS = 10.0 ** np.arange(-8.0, 4.5, 0.5)
CONVEX_TOL = 1e-9  # an eigenvalue below -tol x the largest entry: an indefinite block
#: a row or bound is active at an interior point's answer where its multiplier is above
#: this share of the largest (at least 1): inactive ones fall to ~mu / slack
ACTIVE_SHARE = 1e-6


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


def riccati_pivots(
    stage_blocks: np.ndarray, terminal_block: np.ndarray, AB: np.ndarray, reflect: bool
) -> np.ndarray | None:
    """The recursion of ``reduced_convexified``: the stage blocks (a copy where one
    changed), or ``None`` at the first pivot that is not positive definite if not
    ``reflect``."""
    N, nx = stage_blocks.shape[0], AB.shape[0]
    out, P = stage_blocks, terminal_block
    for k in range(N - 1, -1, -1):
        L = stage_blocks[k] + AB.T @ P @ AB
        lam, V = np.linalg.eigh(L[nx:, nx:])
        floor = EIGEN_FLOOR * max(float(np.abs(lam).max(initial=0.0)), 1e-3)
        if lam.min(initial=np.inf) < floor:
            if not reflect:
                return None
            fixed = np.maximum(np.abs(lam), floor)
            if out is stage_blocks:
                out = stage_blocks.copy()
            out[k, nx:, nx:] += (V * (fixed - lam)) @ V.T
            lam = fixed
        Lxu = L[:nx, nx:] @ V
        P = L[:nx, :nx] - (Lxu / lam) @ Lxu.T
        P = 0.5 * (P + P.T)
    return out


def reduced_convexified(
    stage_blocks: np.ndarray,
    terminal_block: np.ndarray,
    dynamics: tuple[np.ndarray, np.ndarray],
    active: Callable[[], tuple[np.ndarray, np.ndarray, float]] | None = None,
    pivots: Callable[..., np.ndarray | None] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-stage Hessian blocks made convex on the dynamics' null space, sparsity kept.

    ``stage_blocks``: ``(N, nx + nu, nx + nu)`` in ``[x_k; u_k]``; ``dynamics``: ``A,
    B`` of ``x_{k+1} = A x_k + B u_k + b_k`` (``x_0`` pinned). The condensed Hessian is
    positive definite exactly when every pivot of the Riccati recursion is (the Hessian
    in ``u_k`` once the later stages are minimised out, ``R_k + B' P_{k+1} B``): then
    the blocks come back as they are, indefinite or not. Else, as ``convexified`` does
    for a dense Hessian, ``active()`` (``active_normals``; called only then) is added with
    the smallest ``rho`` in a few decades that makes every pivot definite, which keeps the step on
    that active set; failing that (the problem curves down along that active set),
    ``delta I`` is added to every ``R_k`` with the smallest ``delta`` on a half-decade
    grid (``SHIFTS``, times the blocks' largest diagonal entry) that makes every pivot
    definite, as IPOPT's inertia correction adds ``delta_w I``: the step follows the
    negative curvature with the least made-up curvature. Where none does, each
    indefinite pivot's eigenvalues are reflected (``|lambda|``, floored) by a change of
    ``R_k`` alone (Verschueren et al. 2017, "Sparsity preserving convexification").
    Reflected, a strict hierarchy's lower level crawled along the higher level's pinned
    rows where they curve down (the flight 25x faster at N = 20,
    ``benchmarks/bench_bounds_bind_n20.py``: 50 QPs, steps growing 1.2x a QP); shifted,
    it took 27. ``pivots``: the recursion
    (``riccati_pivots``' signature; default it, in NumPy; ``ocp_ipm.CompiledPivots`` is
    the same in C)."""
    pivots = pivots or riccati_pivots
    AB = np.hstack(dynamics)
    if pivots(stage_blocks, terminal_block, AB, reflect=False) is not None:
        return stage_blocks, terminal_block
    CtC, CtC_T, mean_norm = active() if active is not None else (None, None, 0.0)
    scale = max(float(np.abs(np.diagonal(stage_blocks, axis1=1, axis2=2)).max()), 1e-8)
    if mean_norm > 0.0:
        for rho in scale / mean_norm * 10.0 ** np.arange(CONVEXIFY_DECADES):
            Hs, HT = stage_blocks + rho * CtC, terminal_block + rho * CtC_T
            if pivots(Hs, HT, AB, reflect=False) is not None:
                return Hs, HT
    u = np.arange(AB.shape[0], stage_blocks.shape[1])  # the commands' diagonal
    for delta in scale * SHIFTS:
        Hs = stage_blocks.copy()
        Hs[:, u, u] += delta
        if pivots(Hs, terminal_block, AB, reflect=False) is not None:
            return Hs, terminal_block
    reflected = pivots(stage_blocks, terminal_block, AB, reflect=True)
    assert reflected is not None  # reflecting, the recursion always ends
    return reflected, terminal_block


def active_normals(
    rows: tuple[np.ndarray, np.ndarray],
    multipliers: tuple[np.ndarray, np.ndarray],
    bound_multipliers: tuple[np.ndarray, np.ndarray],
) -> tuple[np.ndarray, np.ndarray, float]:
    """Per stage ``C_k' C_k`` of the active rows' normals plus the unit diagonal of the
    variables at a bound (``(N, ns, ns)``), the terminal one, and their mean squared
    norm (0: nothing active). ``rows``: the stage rows' Jacobians ``(N, nc, ns)`` and
    the terminal ``(ncT, nx)``; ``multipliers``: theirs (``(N, nc)``, ``(ncT,)``);
    ``bound_multipliers``: the variables' (``(N, ns)``, ``(nx,)``). Active: a multiplier
    above ``ACTIVE_SHARE`` of the largest."""
    (C, C_T), (lam, lam_T), (lam_v, lam_vT) = rows, multipliers, bound_multipliers
    top = max(1.0, *(float(np.abs(a).max(initial=0.0)) for a in (lam, lam_T, lam_v, lam_vT)))
    on, on_T = np.abs(lam) > ACTIVE_SHARE * top, np.abs(lam_T) > ACTIVE_SHARE * top
    fix, fix_T = np.abs(lam_v) > ACTIVE_SHARE * top, np.abs(lam_vT) > ACTIVE_SHARE * top
    CtC = np.swapaxes(C * on[:, :, None], 1, 2) @ C
    CtC_T = (C_T * on_T[:, None]).T @ C_T
    ns, nx = C.shape[2], C_T.shape[1]
    CtC[:, np.arange(ns), np.arange(ns)] += fix
    CtC_T[np.arange(nx), np.arange(nx)] += fix_T
    count = float(on.sum() + on_T.sum() + fix.sum() + fix_T.sum())
    total = float(np.trace(CtC, axis1=1, axis2=2).sum() + np.trace(CtC_T))
    return CtC, CtC_T, total / count if count else 0.0
