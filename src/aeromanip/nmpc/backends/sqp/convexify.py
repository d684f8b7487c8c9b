"""Hessian convexification for the SQP's QPs: a penalty on the active rows' normals, else
a shift of the diagonal (dense Hessians, and the Riccati recursion's pivots of per-stage
blocks of a problem with linear dynamics), or each block's eigenvalues reflected (for a
QP solver that needs every block positive semi-definite).

The least penalty or shift on a grid that makes a matrix positive definite is found by
bisection (``least_passing``): a larger one makes it so too, so the answer is the same as
trying them in order, in about ``log2`` of the Cholesky factorisations."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

CONVEXIFY_DECADES = 5  # penalties rho tried on the active normals: base * 10**(0..4)
EIGEN_FLOOR = 1e-6  # reflected eigenvalues kept above this share of the largest (or 1e-3)
# the shifts ``delta`` tried on the (commands') diagonal, times its largest entry:
# 10**(SHIFT_FIRST + SHIFT_STEP * i), i < SHIFT_COUNT (1e-8 to 1e4 by half decades)
SHIFT_FIRST, SHIFT_STEP, SHIFT_COUNT = -8.0, 0.5, 25
#: those shifts (Python's ``**`` is C's ``pow``, as in the compiled loop)
SHIFTS = np.array([10.0 ** (SHIFT_FIRST + SHIFT_STEP * i) for i in range(SHIFT_COUNT)])
#: the penalties' factors on their base
PENALTY_FACTORS = np.array([10.0**t for t in range(CONVEXIFY_DECADES)])
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


def least_passing(count: int, passes: Callable[[int], bool]) -> int | None:
    """The least ``i < count`` where ``passes(i)``, for a test that holds from some ``i``
    on, or ``None``: the last ``i`` tried first, then bisection (``compiled_loop``'s
    C does the same tests in the same order)."""
    if count <= 0 or not passes(count - 1):
        return None
    lo, hi = -1, count - 1  # passes(hi); not passes(lo), or lo = -1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if passes(mid):
            hi = mid
        else:
            lo = mid
    return hi


def above_least(i: int) -> int:
    """The shift taken where ``SHIFTS[i]`` is the least that makes a matrix definite: the
    next one. The least leaves the smallest eigenvalue anywhere above 0 (a near-singular
    QP, whose step rounding steers: a bounded solve's iterate differed by 4e-9 between
    two builds of the same loop); one step up it is at least ``1 - 10**-SHIFT_STEP``
    (0.68) of the shift, and the shift at most ``10**(2 SHIFT_STEP)`` (10) times the
    least that would do."""
    return min(i + 1, SHIFT_COUNT - 1)


def shifted(H: np.ndarray, delta: float) -> np.ndarray:
    """``H + delta I`` (a copy)."""
    out = H.copy()
    out.flat[:: H.shape[0] + 1] += delta
    return out


def convexified(H: np.ndarray, C: np.ndarray, fixed: np.ndarray, shift: bool = False) -> np.ndarray:
    """``H`` if positive definite; else ``H + rho C'C`` (plus ``rho`` on the ``fixed``
    variables' diagonal) for the smallest ``rho`` in a few decades that makes it so, which
    keeps the step on that active set; else (the problem curves down along it), if
    ``shift``, ``H + delta I`` as IPOPT's inertia correction, with ``delta`` one step
    above the smallest on a half-decade grid (``SHIFTS``, times the largest diagonal
    entry) that makes it so (``above_least``); else ``H`` with its eigenvalues reflected
    (``|lambda|``, floored). Each grid is searched by ``least_passing``.

    The SQP shifts in a bounded solve (``accept_at_max_iter``): a shift costs a few
    Cholesky factorisations (18 us each at 70 variables), a reflection an
    eigendecomposition (330 us), and a bounded solve's QPs must each be cheap. A
    converged solve reflects: the shift adds curvature to every direction, flat ones too,
    and along a flat valley its steps crawl (the flight's hardest level took 60 QPs
    instead of 24, its exported worst step 10.5 ms instead of 5.8)."""
    if is_positive_definite(H):
        return H
    scale = max(float(np.abs(np.diag(H)).max()), 1e-8)
    if C.shape[0] or fixed.size:
        norms = np.concatenate([np.einsum("ij,ij->i", C, C), np.ones(fixed.size)])
        base = scale / max(float(norms.mean()), 1e-12)
        CtC = C.T @ C
        CtC[fixed, fixed] += 1.0
        rhos = base * PENALTY_FACTORS
        i = least_passing(rhos.size, lambda i: is_positive_definite(H + rhos[i] * CtC))
        if i is not None:
            return H + rhos[i] * CtC
    deltas = scale * SHIFTS if shift else SHIFTS[:0]
    i = least_passing(deltas.size, lambda i: is_positive_definite(shifted(H, deltas[i])))
    if i is not None:
        return shifted(H, deltas[above_least(i)])
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
    for a dense Hessian, ``active()`` (``active_normals``; called only then) is added
    with the smallest ``rho`` in a few decades that makes every pivot definite, which
    keeps the step on that active set; failing that (the problem curves down along that
    active set), ``delta I`` is added to every ``R_k``, ``delta`` one step above the
    smallest on a half-decade grid (``SHIFTS``, times the blocks' largest diagonal entry)
    that makes every pivot definite (``above_least``), as IPOPT's inertia correction adds
    ``delta_w I``: the step follows the negative curvature with little made-up
    curvature. Where none does, each indefinite pivot's eigenvalues are reflected
    (``|lambda|``, floored) by a change of ``R_k`` alone (Verschueren et al. 2017,
    "Sparsity preserving convexification").
    Reflected, a strict hierarchy's lower level crawled along the higher level's pinned
    rows where they curve down (the flight 25x faster at N = 20,
    ``benchmarks/bench_bounds_bind_n20.py``: 50 QPs, steps growing 1.2x a QP); shifted,
    it took 27. ``pivots``: the recursion
    (``riccati_pivots``' signature; default it, in NumPy; ``ocp_ipm.CompiledPivots`` is
    the same in C)."""
    pivots = pivots or riccati_pivots
    AB = np.hstack(dynamics)

    def definite(Hs: np.ndarray, HT: np.ndarray) -> bool:
        return pivots(Hs, HT, AB, reflect=False) is not None

    if pivots(stage_blocks, terminal_block, AB, reflect=False) is not None:
        return stage_blocks, terminal_block
    CtC, CtC_T, mean_norm = active() if active is not None else (None, None, 0.0)
    scale = max(float(np.abs(np.diagonal(stage_blocks, axis1=1, axis2=2)).max()), 1e-8)
    if mean_norm > 0.0:
        rhos = scale / mean_norm * PENALTY_FACTORS

        def penalized(i: int) -> tuple[np.ndarray, np.ndarray]:
            return stage_blocks + rhos[i] * CtC, terminal_block + rhos[i] * CtC_T

        i = least_passing(rhos.size, lambda i: definite(*penalized(i)))
        if i is not None:
            return penalized(i)
    u = np.arange(AB.shape[0], stage_blocks.shape[1])  # the commands' diagonal

    def commands_shifted(i: int) -> np.ndarray:
        Hs = stage_blocks.copy()
        Hs[:, u, u] += scale * SHIFTS[i]
        return Hs

    i = least_passing(SHIFTS.size, lambda i: definite(commands_shifted(i), terminal_block))
    if i is not None:
        return commands_shifted(above_least(i)), terminal_block
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
