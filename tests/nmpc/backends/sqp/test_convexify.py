"""Hessian convexification.

Dense: against a NumPy re-implementation of the rule of ``convexify.py`` (``rho = base
10^k``, the smallest that makes ``H + rho C'C`` positive definite, each tried in turn;
otherwise, where the SQP shifts (a bounded solve), the ``delta`` of ``SHIFTS`` (times the
largest diagonal entry) one above the smallest that makes ``H + delta I`` so; otherwise
``|lambda|`` floored at ``EIGEN_FLOOR max(|lambda|max, 1e-3)``), with
``numpy.linalg.eigvalsh`` as the positive-definiteness test. Per-stage blocks: against
the condensed Hessian built here by eliminating the states explicitly (independent of
the Riccati recursion the module uses), and the equality-constrained step solved
whole."""

import numpy as np
import pytest

from aeromanip.nmpc.backends.sqp.convexify import (
    CONVEX_TOL,
    CONVEXIFY_DECADES,
    EIGEN_FLOOR,
    SHIFT_STEP,
    SHIFTS,
    active_normals,
    convexified,
    convexified_blocks,
    reduced_convexified,
    riccati_pivots,
)
from aeromanip.nmpc.backends.sqp.ocp_ipm import CompiledPivots


def numpy_convexified(H, C, fixed, shift):
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
    deltas = max(np.abs(np.diag(H)).max(), 1e-8) * SHIFTS if shift else []
    for i, delta in enumerate(deltas):
        if pd(H + delta * np.eye(len(H))):
            return H + deltas[min(i + 1, len(deltas) - 1)] * np.eye(len(H))
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
    "no rows: the second shift, or reflected": (np.diag([10.0, -1e-9]), np.zeros((0, 2)), []),
    "no rows: a shift of 10^-1": (np.diag([1.0, -0.03]), np.zeros((0, 2)), []),
    "rows cannot fix it: shifted or reflected": (np.diag([1.0, -1.0]), np.array([[1.0, 0.0]]), []),
    # no diagonal to scale a shift by (the 1e-8 floor): reflected, floored
    "zero diagonal: reflected": (np.array([[0.0, 1.0], [1.0, 0.0]]), np.zeros((0, 2)), []),
    "small spectrum: 1e-3 floor": (
        np.array([[0.0, 0.01], [0.01, 0.0]]),
        np.zeros((0, 2)),
        [],
    ),
}


@pytest.mark.parametrize("shift", [True, False])
@pytest.mark.parametrize("name", sorted(CASES))
def test_convexified_matches_a_numpy_reimplementation(name, shift):
    H, C, fixed = CASES[name]
    fixed = np.array(fixed, dtype=int)
    expected = numpy_convexified(H, C, fixed, shift)
    got = convexified(H.copy(), C, fixed, shift)
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=0)
    assert np.linalg.eigvalsh(expected).min() > 0


@pytest.mark.parametrize("seed", range(40))
def test_the_bisection_finds_the_least_penalty_or_shift_of_a_scan_in_turn(seed):
    """Random indefinite Hessians whose least penalty or shift lies anywhere on its grid
    (each found by bisection) against the scan that tries each in turn."""
    rng = np.random.default_rng(seed)
    n = 6
    Q = np.linalg.qr(rng.normal(size=(n, n)))[0]
    lam = rng.uniform(0.1, 1.0, n)
    lam[: rng.integers(1, 3)] = -(10.0 ** rng.uniform(-7, 0.5))  # one or two below zero
    H = (Q * lam) @ Q.T
    C = rng.normal(size=(rng.integers(0, 3), n))
    fixed = np.flatnonzero(rng.random(n) < 0.2)
    expected = numpy_convexified(H, C, fixed, True)
    got = convexified(H.copy(), C, fixed, True)
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=0)
    delta = got[0, 0] - H[0, 0]
    if np.allclose(got - H, delta * np.eye(n), rtol=0, atol=1e-14):  # shifted: with margin
        assert np.linalg.eigvalsh(got).min() >= (1.0 - 10.0**-SHIFT_STEP) * delta * (1 - 1e-9)


# --- per-stage blocks: convex on the dynamics' null space ------------------------------------

NX, NU, N = 4, 3, 6


def dynamics(seed=0):
    rng = np.random.default_rng(seed)
    return np.eye(NX) + 0.1 * rng.normal(size=(NX, NX)), rng.normal(size=(NX, NU))


def condensing(A, B):
    """``Y``: the stage variables ``[x_k; u_k]`` (and ``x_N``) as a linear map of the
    commands ``u_0..u_{N-1}`` with ``x_0 = 0``, by explicit elimination."""
    X = [np.zeros((NX, N * NU))]
    for k in range(N):
        step = A @ X[-1]
        step[:, k * NU : (k + 1) * NU] += B
        X.append(step)
    stages = []
    for k in range(N):
        U = np.zeros((NU, N * NU))
        U[:, k * NU : (k + 1) * NU] = np.eye(NU)
        stages.append(np.vstack([X[k], U]))
    return stages, X[N]


def condensed(Hs, HT, A, B):
    """The Hessian in the commands of ``sum_k y_k' Hs[k] y_k + x_N' HT x_N``."""
    stages, last = condensing(A, B)
    return sum(Y.T @ H @ Y for Y, H in zip(stages, Hs, strict=True)) + last.T @ HT @ last


def random_blocks(rng, shift=0.0):
    M = rng.normal(size=(N, NX + NU, NX + NU))
    Hs = np.swapaxes(M, 1, 2) @ M - shift * np.eye(NX + NU)
    T = rng.normal(size=(NX, NX))
    return Hs, T @ T.T


@pytest.mark.parametrize("seed", range(6))
def test_reduced_convexified_makes_the_condensed_hessian_positive_definite(seed):
    """Indefinite blocks whose condensed Hessian is indefinite: after, it is positive
    definite; only the command blocks ``R_k`` change, and a second pass changes
    nothing."""
    rng = np.random.default_rng(seed)
    A, B = dynamics(seed)
    Hs, HT = random_blocks(rng, shift=30.0)
    assert np.linalg.eigvalsh(condensed(Hs, HT, A, B)).min() < 0
    out, out_T = reduced_convexified(Hs, HT, (A, B))
    assert np.linalg.eigvalsh(condensed(out, out_T, A, B)).min() > 0
    np.testing.assert_array_equal(out[:, :NX, :], Hs[:, :NX, :])  # states' rows kept
    np.testing.assert_array_equal(out[:, :, :NX], Hs[:, :, :NX])
    assert out_T is HT
    again = reduced_convexified(out, out_T, (A, B))
    assert again[0] is out


def test_blocks_convex_on_the_null_space_come_back_unchanged():
    """Every state block indefinite, the condensed Hessian positive definite (the
    dynamics carry the commands' curvature): the blocks are returned as they are."""
    rng = np.random.default_rng(3)
    A, B = dynamics(3)
    Hs, HT = random_blocks(rng)
    Hs[:, NX:, NX:] += 20.0 * np.eye(NU)  # the commands' own curvature
    for k in range(N):  # each block just indefinite, along a state direction
        Hs[k, :NX, :NX] -= (np.linalg.eigvalsh(Hs[k]).min() + 0.05) * np.eye(NX)
    assert (np.linalg.eigvalsh(Hs).min(axis=1) < 0).all()
    assert np.linalg.eigvalsh(condensed(Hs, HT, A, B)).min() > 0

    def active():  # the active rows' normals: not asked for where nothing changes
        raise AssertionError("active_normals computed for definite pivots")

    out, out_T = reduced_convexified(Hs, HT, (A, B), active)
    assert out is Hs and out_T is HT


def test_an_active_rows_penalty_keeps_the_step_on_that_active_set():
    """Convex on the null space of an active row of stage 2 but not beyond it: the
    penalty on that row's normal makes the condensed Hessian positive definite and the
    step of the equality-constrained QP (solved whole, KKT system) is the exact one."""
    rng = np.random.default_rng(11)
    A, B = dynamics(11)
    Hs, HT = random_blocks(rng)
    c = rng.normal(size=NX + NU)
    stages, _ = condensing(A, B)
    H0 = condensed(Hs, HT, A, B)
    row = c @ stages[2]  # the row in the commands
    w = np.linalg.solve(H0, row)  # curvature taken away along the row's direction
    Hs[2] -= 1.5 * np.outer(c, c) * (1.0 / (row @ w))  # a rank-one cut, seen by the row
    H = condensed(Hs, HT, A, B)
    Z = np.linalg.svd(row[None])[2][1:].T  # the row's null space
    assert np.linalg.eigvalsh(H).min() < 0 < np.linalg.eigvalsh(Z.T @ H @ Z).min()
    lam = np.zeros((N, 1))
    lam[2, 0] = 0.7
    C = np.zeros((N, 1, NX + NU))
    C[2, 0] = c
    active = active_normals(
        (C, np.zeros((0, NX))), (lam, np.zeros(0)), (np.zeros((N, NX + NU)), np.zeros(NX))
    )
    out, out_T = reduced_convexified(Hs, HT, (A, B), lambda: active)
    Hc = condensed(out, out_T, A, B)
    assert np.linalg.eigvalsh(Hc).min() > 0
    rho = (out[2] - Hs[2])[np.abs(c).argmax()][np.abs(c).argmax()] / c[np.abs(c).argmax()] ** 2
    np.testing.assert_allclose(out[2], Hs[2] + rho * np.outer(c, c), rtol=1e-12, atol=1e-12)
    g = rng.normal(size=N * NU)

    def step(Hq):
        K = np.block([[Hq, row[:, None]], [row[None], np.zeros((1, 1))]])
        return np.linalg.solve(K, np.concatenate([-g, [0.0]]))[: N * NU]

    np.testing.assert_allclose(step(Hc), step(H), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_where_no_penalty_helps_the_commands_take_the_shift_above_the_least_that_does(seed):
    """Indefinite along its active row's null space too (no penalty on the row can
    help): ``delta I`` on every command block, ``delta`` the one of ``SHIFTS`` (times the
    largest diagonal entry) after the first whose condensed Hessian is positive definite
    (the smallest eigenvalue then at least ``1 - 10**-SHIFT_STEP`` of the shift), the
    states' rows and the terminal block as they were."""
    rng = np.random.default_rng(seed)
    A, B = dynamics(seed)
    Hs, HT = random_blocks(rng, shift=30.0)
    c = rng.normal(size=NX + NU)
    lam, C = np.zeros((N, 1)), np.zeros((N, 1, NX + NU))
    lam[2, 0], C[2, 0] = 0.7, c
    active = active_normals(
        (C, np.zeros((0, NX))), (lam, np.zeros(0)), (np.zeros((N, NX + NU)), np.zeros(NX))
    )
    out, out_T = reduced_convexified(Hs, HT, (A, B), lambda: active)
    assert out_T is HT
    shift = out - Hs
    delta = shift[0, NX, NX]
    np.testing.assert_array_equal(shift, delta * np.broadcast_to(np.diag(
        np.r_[np.zeros(NX), np.ones(NU)]), shift.shape))  # fmt: skip
    scale = np.abs(np.diagonal(Hs, axis1=1, axis2=2)).max()
    k = int(np.flatnonzero(np.isclose(scale * SHIFTS, delta, rtol=1e-12))[0])

    def definite(d):
        Hd = Hs.copy()
        Hd[:, NX:, NX:] += d * np.eye(NU)
        return np.linalg.eigvalsh(condensed(Hd, HT, A, B)).min() > 0

    least = scale * SHIFTS[k - 1]
    assert k >= 1 and definite(least) and (k == 1 or not definite(scale * SHIFTS[k - 2]))
    Hd = Hs.copy()
    Hd[:, NX:, NX:] += delta * np.eye(NU)
    # the condensed Hessian is H_c + delta I: its spectrum moves by delta
    lowest = np.linalg.eigvalsh(condensed(Hd, HT, A, B)).min()
    assert lowest >= (1.0 - 10.0**-SHIFT_STEP) * delta * (1 - 1e-9)


def test_active_normals_against_a_loop_over_rows_and_bounds():
    """``C_k' C_k`` summed row by row over the active rows (multiplier above the share of
    the largest), plus 1 on each bound-held variable's diagonal; the mean squared norm
    counts each active row and bound once."""
    rng = np.random.default_rng(2)
    ns, nc, ncT = NX + NU, 3, 2
    C, C_T = rng.normal(size=(N, nc, ns)), rng.normal(size=(ncT, NX))
    lam = np.where(rng.random((N, nc)) < 0.4, rng.normal(size=(N, nc)), 1e-12)
    lam_T = np.array([0.5, 1e-12])
    lam_v = np.where(rng.random((N, ns)) < 0.2, -2.0, 1e-13)
    lam_vT = np.zeros(NX)
    CtC, CtC_T, mean = active_normals((C, C_T), (lam, lam_T), (lam_v, lam_vT))
    want = np.zeros((N, ns, ns))
    norms = []
    for k in range(N):
        for i in range(nc):
            if abs(lam[k, i]) > 1e-6:
                want[k] += np.outer(C[k, i], C[k, i])
                norms.append(C[k, i] @ C[k, i])
        for j in range(ns):
            if abs(lam_v[k, j]) > 1e-6:
                want[k, j, j] += 1.0
                norms.append(1.0)
    np.testing.assert_allclose(CtC, want, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(CtC_T, np.outer(C_T[0], C_T[0]), rtol=1e-12, atol=1e-12)
    norms.append(C_T[0] @ C_T[0])
    assert mean == pytest.approx(np.mean(norms), rel=1e-12)


@pytest.mark.parametrize("shift", [0.0, 2.0, 30.0])
@pytest.mark.parametrize("sparse_dynamics", [False, True])
def test_the_compiled_recursion_decides_and_reflects_as_numpys(shift, sparse_dynamics):
    """``ocp_ipm.CompiledPivots`` (C: Cholesky where it decides, Jacobi otherwise, the
    dynamics' zeros skipped) against ``riccati_pivots`` (NumPy's ``eigh`` at every
    stage): the same verdict, the same reflected blocks, the input left as it was."""
    pivots = CompiledPivots.create(EIGEN_FLOOR)
    if pivots is None:
        pytest.skip("no C compiler")
    rng = np.random.default_rng(int(10 * shift) + sparse_dynamics)
    A, B = dynamics(int(shift))
    if sparse_dynamics:  # positions integrate rates, as the kinematic model's
        A = np.eye(NX)
        A[:2, 2:] = 0.5 * np.eye(2)
        B = np.zeros((NX, NU))
        B[2:, :2] = np.eye(2)
    AB = np.hstack([A, B])
    Hs, HT = random_blocks(rng, shift=shift)
    before = Hs.copy()
    checked = riccati_pivots(Hs, HT, AB, reflect=False)
    assert (pivots(Hs, HT, AB, reflect=False) is None) == (checked is None)
    want = riccati_pivots(Hs, HT, AB, reflect=True)
    got = pivots(Hs, HT, AB, reflect=True)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-11 * np.abs(want).max())
    np.testing.assert_array_equal(Hs, before)
    if shift == 0.0:
        assert checked is Hs  # positive definite blocks: nothing to change


@pytest.mark.parametrize(
    ("largest", "lowest", "reflected"),
    [
        (2000.0, -200.0 * CONVEX_TOL, False),  # within 1e-9 of the largest entry (2e-6)
        (2000.0, -3000.0 * CONVEX_TOL, True),
        (0.5, -1.5 * CONVEX_TOL, True),  # small entries: the tolerance is 1e-9, not less
        (0.5, -0.5 * CONVEX_TOL, False),
    ],
)
def test_the_convexity_tolerance_is_relative_to_the_largest_entry_and_at_least_absolute(
    largest, lowest, reflected
):
    """``convexified_blocks``' test: a block is indefinite below ``-CONVEX_TOL`` times the stage
    blocks' largest entry, or ``-CONVEX_TOL`` where that is below 1; the blocks are given
    their eigenvalues' absolute values (checked by NumPy) or returned as they are."""
    q = np.linalg.qr(np.random.default_rng(7).normal(size=(3, 3)))[0]
    lam = np.array([largest, 0.25 * largest, lowest])
    stage = ((q * lam) @ q.T)[None]
    assert np.abs(stage).max() <= largest  # the largest entry is at most the top eigenvalue
    terminal = np.eye(3)
    Hs, HT = convexified_blocks(stage, terminal)
    if reflected:
        np.testing.assert_allclose(Hs[0], (q * np.abs(lam)) @ q.T, atol=1e-9 * largest)
        assert np.linalg.eigvalsh(Hs[0]).min() == pytest.approx(-lowest, rel=1e-3)
    else:
        assert Hs is stage and HT is terminal
