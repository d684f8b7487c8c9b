"""``nmpc.backends.sqp.dense_qp.DenseQp`` against an independent brute-force QP solver, in NumPy.

Truth: for ``min 1/2 d'Hd + g'd  s.t.  lba <= A d <= uba,  lbx <= d <= ubx`` with ``H``
positive definite, the optimum is the unique KKT point. With linear constraints a KKT
multiplier exists whose nonzero entries belong to linearly independent constraints
(Carathéodory for cones), so the optimum is the solution of the equality-constrained KKT
system of some working set of at most ``n`` constraints (equality rows always in it), each at
its lower or upper side. ``brute_force`` enumerates all of them, solves every KKT system
(batched) and keeps the points that are feasible with multipliers of the right sign (KKT
sufficient for a convex QP); it also checks that this point is the lowest-cost feasible
candidate (the other characterisation of the optimum), so the truth is checked twice.

Tolerances: both sides are exact active-set solutions, they differ only by rounding times
the conditioning of the KKT system (``H = M M' + c I`` with O(1) data: far below 1e-9), while
a wrong working set moves ``d`` and the multipliers by O(1e-2) or more. ``d`` is compared to
1e-6 relative (DAQP's primal tolerance is 1e-9; DenseQp accepts rows crossed by
1e-6 (1 + |d|) when it screens), the multipliers to 1e-5.

Multipliers follow CasADi's sign convention: ``H d + g + A' lam_a + lam_x = 0``, ``lam > 0``
at an upper bound, ``< 0`` at a lower one.
"""

import functools
import itertools

import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends.sqp.dense_qp import DenseQp

SOLVERS = ("daqp", "qpoases")
D_TOL = 1e-6  # relative, on the step
LAM_TOL = 1e-5  # relative, on the multipliers
FEAS_TOL = 1e-9  # the brute force's feasibility / sign tolerance (scaled)


# -- the brute force ------------------------------------------------------------------------
def brute_force(H, g, A, lba, uba, lbx, ubx):
    """The exact solution ``(d, lam_a, lam_x)`` by enumerating working sets; ``None`` if no
    candidate is feasible (the QP is infeasible)."""
    n, m = H.shape[0], A.shape[0]
    C = np.vstack([A, np.eye(n)])  # the rows, then the variable bounds
    lo, hi = np.concatenate([lba, lbx]), np.concatenate([uba, ubx])
    bounds = np.concatenate([lo, hi])
    tol = FEAS_TOL * (1.0 + np.abs(g).max() + np.abs(bounds[np.isfinite(bounds)]).max())
    eq, ineq = np.nonzero(lo == hi)[0], np.nonzero(lo != hi)[0]
    kkt, feasible = [], []  # (d, lam) of the KKT points; (cost, d) of the feasible points
    for s in range(n - eq.size + 1):
        combos = list(itertools.combinations(ineq, s))
        combos = np.array(combos, dtype=int).reshape(len(combos), s)
        work = np.hstack([np.broadcast_to(eq, (len(combos), eq.size)), combos])
        Cw, k = C[work], work.shape[1]  # (count, k, n)
        if k:  # linearly independent working sets only
            indep = np.linalg.det(Cw @ Cw.transpose(0, 2, 1)) > 1e-10
            work, combos, Cw = work[indep], combos[indep], Cw[indep]
        if not len(work):
            continue
        K = np.zeros((len(work), n + k, n + k))
        K[:, :n, :n] = H
        K[:, :n, n:] = Cw.transpose(0, 2, 1)
        K[:, n:, :n] = Cw
        # one right-hand side per choice of sides of the inequalities (1: upper)
        sides = np.array(list(itertools.product((0, 1), repeat=s)), dtype=int).reshape(2**s, s)
        rhs = np.zeros((len(work), n + k, len(sides)))
        rhs[:, :n] = -g[None, :, None]
        rhs[:, n : n + eq.size] = lo[eq][None, :, None]
        side_val = np.where(sides[None] == 1, hi[combos][:, None], lo[combos][:, None])
        rhs[:, n + eq.size :] = side_val.transpose(0, 2, 1)
        finite = np.isfinite(rhs).all(axis=1)  # (count, sides): no infinite side
        sol = np.linalg.solve(K, np.where(np.isfinite(rhs), rhs, 0.0))
        d = sol[:, :n].transpose(0, 2, 1)  # (count, sides, n)
        Cd = d @ C.T
        ok = finite & ((Cd >= lo - tol) & (Cd <= hi + tol)).all(axis=2)
        lam_s = sol[:, n + eq.size :].transpose(0, 2, 1)  # (count, sides, s)
        signed = np.where(sides[None] == 1, lam_s, -lam_s)  # >= 0 when of the right sign
        dual = (signed >= -tol).all(axis=2)
        for i, j in zip(*np.nonzero(ok), strict=True):
            feasible.append((0.5 * d[i, j] @ H @ d[i, j] + g @ d[i, j], d[i, j]))
            if dual[i, j]:
                lam = np.zeros(m + n)
                lam[work[i]] = sol[i, n:, j]
                kkt.append((d[i, j], lam))
    if not feasible:
        return None
    assert kkt, "brute force: feasible points but no KKT point"
    d, lam = kkt[0]
    for d2, _ in kkt[1:]:  # degenerate instances: every KKT point is the same point
        np.testing.assert_allclose(d2, d, atol=1e-8)
    np.testing.assert_allclose(d, min(feasible, key=lambda c: c[0])[1], atol=1e-8)
    return d, lam[:m], lam[m:]


def multipliers_unique(A, lba, uba, lbx, ubx, d):
    """Whether the constraints active at ``d`` are linearly independent (the multipliers are
    then unique, so comparable)."""
    C = np.vstack([A, np.eye(d.size)])
    lo, hi = np.concatenate([lba, lbx]), np.concatenate([uba, ubx])
    tol = 1e-7 * (1.0 + np.abs(d).max())
    act = (np.abs(C @ d - lo) < tol) | (np.abs(C @ d - hi) < tol)
    return np.linalg.matrix_rank(C[act]) == act.sum() if act.any() else True


def assert_matches(res, truth):
    """``res`` (a QpResult) is a success and equals ``truth = (d, lam_a, lam_x)``."""
    d, lam_a, lam_x = truth
    assert res.ok, res.status
    assert res.status == ""
    np.testing.assert_allclose(res.d, d, rtol=D_TOL, atol=D_TOL * (1.0 + np.abs(d).max()))
    lam_scale = 1.0 + np.abs(np.concatenate([lam_a, lam_x])).max()
    np.testing.assert_allclose(res.lam_a, lam_a, rtol=LAM_TOL, atol=LAM_TOL * lam_scale)
    np.testing.assert_allclose(res.lam_x, lam_x, rtol=LAM_TOL, atol=LAM_TOL * lam_scale)


# -- instances ------------------------------------------------------------------------------
def random_hessian(rng, n, c=0.5):
    """A random positive definite ``M M' + c I``."""
    M = rng.normal(size=(n, n))
    return M @ M.T + c * np.eye(n)


def random_instance(rng, n, m):
    """A feasible QP around a random point ``d0``: two-sided, one-sided and equality rows,
    finite bounds; the gradient pushes the optimum onto some of them."""
    H = random_hessian(rng, n)
    g = 3.0 * rng.normal(size=n)
    A = rng.normal(size=(m, n))
    d0 = rng.uniform(-0.5, 0.5, n)
    lba = A @ d0 - rng.uniform(0.05, 1.0, m)
    uba = A @ d0 + rng.uniform(0.05, 1.0, m)
    kind = rng.random(m)
    lba[kind < 0.15] = -np.inf
    uba[(kind >= 0.15) & (kind < 0.3)] = np.inf
    eq = np.nonzero(kind >= 0.85)[0][: n - 1]  # at most n - 1 equality rows
    lba[eq] = uba[eq] = A[eq] @ d0
    lbx = d0 - rng.uniform(0.1, 1.5, n)
    ubx = d0 + rng.uniform(0.1, 1.5, n)
    return H, g, A, lba, uba, lbx, ubx


@functools.cache
def random_cases():
    """Random feasible instances (n <= 4, m <= 6) with unique multipliers, and their truth."""
    rng = np.random.default_rng(20240531)
    cases = []
    while len(cases) < 60:
        n, m = int(rng.integers(2, 5)), int(rng.integers(1, 7))
        qp = random_instance(rng, n, m)
        truth = brute_force(*qp)
        if multipliers_unique(*qp[2:], truth[0]):
            cases.append((qp, truth))
    return cases


def far_rows(rng, k, n, lo=20.0, hi=50.0):
    """``k`` random rows with bounds far from 0 on both sides (never binding in these tests)."""
    A = rng.normal(size=(k, n))
    return A, -rng.uniform(lo, hi, k), rng.uniform(lo, hi, k)


def spy(monkeypatch, qp):
    """Record ``(rows, k)`` of every solve ``qp`` gives its solver (a screening round)."""
    calls = []
    inner = qp._solve_rows

    def record(*args):
        calls.append((args[7].copy(), args[8]))
        return inner(*args)

    monkeypatch.setattr(qp, "_solve_rows", record)
    return calls


def crossed_row_instance(side, m=10):
    """n = 2: row 0 has slack 1 > screen on both sides (left out at first) but the
    unconstrained optimum (2, 0.5) crosses it at its ``side`` bound; the other rows are
    far."""
    rng = np.random.default_rng(7)
    H = np.array([[2.0, 0.5], [0.5, 1.0]])
    g = -H @ np.array([2.0, 0.5])
    A, lba, uba = far_rows(rng, m, 2)
    sign = 1.0 if side == "upper" else -1.0
    A[0] = sign * np.array([1.0, 0.5])  # upper: x + y/2 <= 1; lower: -x - y/2 >= -1
    lba[0], uba[0] = (-3.0, 1.0) if side == "upper" else (-1.0, 3.0)
    return H, g, A, lba, uba, np.full(2, -5.0), np.full(2, 5.0)


def chain_instance(rows):
    """n = 4, m = 9, screen 0.1: ``rows`` (1 to 4) rows that are crossed one per screening
    round (the first by the unconstrained optimum, each next one by the solution with the
    ones before it), all active at the optimum, all with slack >= 0.7; the others free.
    Found by a search over integer data, constructing each row to cut off the last solution
    but none of the earlier ones."""
    M = np.array([[3, -2, 0, -2], [3, 1, -2, -1], [0, 0, -1, 2], [-1, 0, 1, 2]], dtype=float)
    H = M @ M.T + np.eye(4)
    g = -H @ np.array([0.0, -7.0, -1.0, 10.0])
    chain = np.array(
        [[0, -0.5, 0, 0.75], [-0.25, -0.75, 0.25, -0.5], [-1, 0, -0.5, 0], [-0.5, 0.25, 0.75, 0.25]]
    )
    A = np.zeros((9, 4))
    lba, uba = np.full(9, -np.inf), np.full(9, np.inf)
    A[:rows], uba[:rows] = chain[:rows], np.array([6.0, 3.4, 1.6, 0.7])[:rows]
    return H, g, A, lba, uba, np.full(4, -100.0), np.full(4, 100.0)


# -- the solution against the brute force -----------------------------------------------------
def test_brute_force_solves_a_known_qp():
    """The reference itself on a QP solved by hand: min (x-2)^2/2 + (y+1)^2/2 with x + y = 0
    and y >= -0.2 gives x = 0.2, y = -0.2 (y = -1.5 without the bound)."""
    H, g = np.eye(2), np.array([-2.0, 1.0])
    A, lb = np.array([[1.0, 1.0]]), np.array([0.0])
    d, lam_a, lam_x = brute_force(H, g, A, lb, lb, np.array([-1.0, -0.2]), np.array([1.0, 1.0]))
    np.testing.assert_allclose(d, [0.2, -0.2], atol=1e-12)
    # stationarity d - (2, -1) + lam_a (1, 1) + lam_x = 0 with x free: lam_a = 1.8,
    # lam_x[1] = -0.8 - 1.8 (< 0: y at its lower bound)
    np.testing.assert_allclose(lam_a, [1.8], atol=1e-12)
    np.testing.assert_allclose(lam_x, [0.0, -2.6], atol=1e-12)
    assert brute_force(H, g, A, lb + 5.0, lb + 5.0, -np.ones(2), np.ones(2)) is None


def test_random_instances_cover_every_kind_of_constraint():
    """The random instances have rows inactive, at their lower and upper bounds, equality
    rows, variable bounds at lower and upper: every case below is checked many times."""
    rows = {"inactive": 0, "lower": 0, "upper": 0, "equality": 0}
    bounds = {"lower": 0, "upper": 0}
    for (_, _, _, lba, uba, _, _), (_, lam_a, lam_x) in random_cases():
        for i, lam in enumerate(lam_a):
            kind = "equality" if lba[i] == uba[i] else "inactive"
            if kind == "inactive" and abs(lam) > 1e-8:
                kind = "upper" if lam > 0 else "lower"
            rows[kind] += 1
        bounds["lower"] += int((lam_x < -1e-8).sum())
        bounds["upper"] += int((lam_x > 1e-8).sum())
    assert min(rows.values()) >= 10, rows
    assert min(bounds.values()) >= 10, bounds


@pytest.mark.parametrize("solver", SOLVERS)
def test_solution_and_multipliers_match_brute_force_on_random_qps(solver):
    """d, lam_a, lam_x equal the brute force's on 60 random QPs (n <= 4, m <= 6)."""
    solvers = {}
    for qp, truth in random_cases():
        n, m = qp[0].shape[0], qp[2].shape[0]
        if (n, m) not in solvers:
            solvers[n, m] = DenseQp(n, m, solver=solver)
        assert_matches(solvers[n, m].solve(*qp), truth)


# -- screening -------------------------------------------------------------------------------
@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("side", ["upper", "lower"])
def test_screened_out_row_crossed_by_the_solution_is_added_back(monkeypatch, solver, side):
    """Row 0 (slack 1 > screen) is left out of the first solve; the solution crosses it at
    its ``side`` bound, it is added, and the result is the full QP's with row 0 active."""
    qp = crossed_row_instance(side)
    solver_qp = DenseQp(2, 10, solver=solver)
    calls = spy(monkeypatch, solver_qp)
    res = solver_qp.solve(*qp)
    assert [rows.tolist() for rows, _ in calls] == [[], [0]]
    assert_matches(res, brute_force(*qp))
    bound = qp[4][0] if side == "upper" else qp[3][0]
    assert qp[2][0] @ res.d == pytest.approx(bound, abs=1e-9)
    assert (res.lam_a[0] > 0) == (side == "upper") and res.lam_a[0] != 0


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("rows", [1, 2, 3])
def test_rows_crossed_one_per_round_settle_within_four_rounds(monkeypatch, solver, rows):
    """Rows crossed one per round (the solution with row 0 crosses row 1, ...) are added
    round by round; up to 4 rounds the result is the full QP's."""
    qp = chain_instance(rows)
    solver_qp = DenseQp(4, 9, solver=solver)
    calls = spy(monkeypatch, solver_qp)
    res = solver_qp.solve(*qp)
    assert [r.tolist() for r, _ in calls] == [list(range(i)) for i in range(rows + 1)]
    truth = brute_force(*qp)
    assert (truth[1][:rows] > 0).all()  # every chain row is active at the optimum
    assert_matches(res, truth)


@pytest.mark.parametrize("solver", SOLVERS)
def test_rows_still_crossed_after_the_screened_rounds_end_in_the_full_qp(monkeypatch, solver):
    """Four rows crossed one per round: after the screened rounds the full QP is solved,
    and its answer is the brute force's."""
    qp = chain_instance(4)
    truth = brute_force(*qp)
    assert truth is not None
    solver_qp = DenseQp(4, 9, solver=solver)
    calls = spy(monkeypatch, solver_qp)
    res = solver_qp.solve(*qp)
    assert [r.tolist() for r, _ in calls] == [[], [0], [0, 1], [0, 1, 2], list(range(9))]
    assert res.ok, res.status
    assert_matches(res, truth)
    np.testing.assert_array_equal(solver_qp.lam_a, res.lam_a)


def test_reset_does_not_change_a_result_already_returned():
    qp = chain_instance(1)
    solver_qp = DenseQp(4, 9)
    res = solver_qp.solve(*qp)
    kept = res.lam_a.copy()
    assert kept.any()
    solver_qp.reset()
    np.testing.assert_array_equal(res.lam_a, kept)


@pytest.mark.parametrize("solver", SOLVERS)
def test_screened_random_qps_with_memory_match_brute_force(solver):
    """A sequence of random QPs (n = 3, m = 12, rows near and far from binding, crossed at
    either side) through one DenseQp, as in an SQP: every result equals the brute force's,
    whatever rows the last solve left active."""
    rng = np.random.default_rng(11)
    solver_qp = DenseQp(3, 12, solver=solver)
    for _ in range(25):
        H = random_hessian(rng, 3)
        A = rng.normal(size=(12, 3))
        lba, uba = -rng.uniform(0.02, 2.0, 12), rng.uniform(0.02, 2.0, 12)
        lbx, ubx = -rng.uniform(0.5, 3.0, 3), rng.uniform(0.5, 3.0, 3)
        g = -H @ rng.normal(scale=2.0, size=3)
        qp = (H, g, A, lba, uba, lbx, ubx)
        truth = brute_force(*qp)
        if multipliers_unique(A, lba, uba, lbx, ubx, truth[0]):
            assert_matches(solver_qp.solve(*qp), truth)


# -- what the solver is given first: always, memory, reset, shift ----------------------------
def test_always_rows_are_given_to_the_solver_from_the_first_round(monkeypatch):
    """Far rows marked ``always`` are in the first round; the others far are not."""
    qp = crossed_row_instance("upper")
    always = np.zeros(10, dtype=bool)
    always[[3, 7]] = True
    solver = DenseQp(2, 10, always=always)
    calls = spy(monkeypatch, solver)
    res = solver.solve(*qp)
    assert [r.tolist() for r, _ in calls] == [[3, 7], [0, 3, 7]]
    assert_matches(res, brute_force(*qp))


def test_rows_active_last_time_are_given_first_and_reset_forgets_them(monkeypatch):
    """After a solve with row 0 active, the next solve gives row 0 from the first round (one
    round); ``reset()`` zeroes the memory and screening starts afresh."""
    qp = crossed_row_instance("lower")
    solver = DenseQp(2, 10)
    calls = spy(monkeypatch, solver)
    first = solver.solve(*qp)
    assert len(calls) == 2
    np.testing.assert_array_equal(solver.lam_a, first.lam_a)
    assert np.flatnonzero(solver.lam_a).tolist() == [0]
    calls.clear()
    second = solver.solve(*qp)
    assert [r.tolist() for r, _ in calls] == [[0]]
    np.testing.assert_allclose(second.d, first.d, rtol=1e-12, atol=1e-12)
    solver.reset()
    assert not solver.lam_a.any()
    calls.clear()
    assert_matches(solver.solve(*qp), brute_force(*qp))
    assert [r.tolist() for r, _ in calls] == [[], [0]]


def test_shift_moves_the_multipliers_by_shift_rows(monkeypatch):
    """``shift()`` makes ``lam_a`` the last one indexed by ``shift_rows`` (row i predicted by
    row shift_rows[i]); with the data moved one row on, the next solve gives the solver the
    predicted rows first and needs one round."""
    qp = crossed_row_instance("upper")
    shift_rows = np.r_[0, 0:9]  # row i + 1 is predicted by row i; row 0 by itself
    solver = DenseQp(2, 10, shift_rows=shift_rows)
    last = solver.solve(*qp).lam_a.copy()
    assert np.flatnonzero(last).tolist() == [0]
    solver.shift()
    np.testing.assert_array_equal(solver.lam_a, last[shift_rows])
    order = np.r_[9, 0:9]  # the data moved one row on: the active row 0 is now row 1
    moved = (*qp[:2], qp[2][order], qp[3][order], qp[4][order], *qp[5:])
    calls = spy(monkeypatch, solver)
    assert_matches(solver.solve(*moved), brute_force(*moved))
    assert [r.tolist() for r, _ in calls] == [[0, 1]]


# -- padding to the solver sizes --------------------------------------------------------------
@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize(
    ("near", "size"),
    [(0, 8), (5, 8), (8, 8), (9, 16), (20, 24), (30, 32), (33, 48), (50, 64), (64, 64), (65, 70)],
)
def test_rows_padded_to_the_solver_sizes_match_brute_force(monkeypatch, solver, near, size):
    """m = 70 rows (sizes 8, 16, 24, 32, 48, 64, 70), ``near`` of them within the screen of
    their upper bound (all facing +x); the optimum lies towards -x, across far rows. The
    first round gets the near rows padded with free rows to ``size`` (all 70 rows once above
    64), the crossed ones are added (padded to the next size); the result is the full QP's."""
    rng = np.random.default_rng(near)
    m = 70
    H = random_hessian(rng, 2)
    g = -H @ np.array([-3.0, rng.normal()])
    A = rng.normal(size=(m, 2))
    lba, uba = -rng.uniform(0.3, 3.0, m), rng.uniform(0.3, 3.0, m)
    close = rng.permutation(m)[:near]
    A[close, 0] = np.abs(A[close, 0]) + 0.5
    uba[close] = rng.uniform(0.01, 0.09, near)  # slack < screen = 0.1
    qp = (H, g, A, lba, uba, np.full(2, -4.0), np.full(2, 4.0))
    truth = brute_force(*qp)
    assert multipliers_unique(*qp[2:], truth[0])
    solver_qp = DenseQp(2, m, solver=solver)
    calls = spy(monkeypatch, solver_qp)
    assert_matches(solver_qp.solve(*qp), truth)
    first = sorted(close) if size < m else list(range(m))
    assert (calls[0][0].tolist(), calls[0][1]) == (first, size)


# -- failures --------------------------------------------------------------------------------
def infeasible_cases():
    """Infeasible QPs as ``pytest.param(qp, rounds)``: a row against the bounds; a far row that
    only the second round finds contradicting a near one; random feasible QPs plus a row
    that contradicts one of theirs (m <= 8: one round)."""
    H, g = np.eye(2), np.array([-3.0, 0.0])
    A = np.array([[1.0, 1.0], [1.0, -1.0], [0.0, 1.0]])
    lba, uba = np.array([3.0, -1.0, -1.0]), np.array([4.0, 1.0, 1.0])  # x + y >= 3
    cases = [pytest.param((H, g, A, lba, uba, -np.ones(2), np.ones(2)), 1, id="row-vs-bounds")]
    rng = np.random.default_rng(3)
    A, lba, uba = far_rows(rng, 10, 2)
    A[0], lba[0], uba[0] = (1.0, 0.0), 1.0, 2.0  # x >= 1: near (slack -1)
    A[1], lba[1], uba[1] = (1.0, 1.0), -3.0, 0.5  # x + y <= 0.5: far, crossed by (3, 0)
    lbx, ubx = np.array([-5.0, -0.2]), np.array([5.0, 0.2])
    cases.append(pytest.param((H, g, A, lba, uba, lbx, ubx), 2, id="found-after-screening"))
    for i in range(6):
        H, g, A, lba, uba, lbx, ubx = random_instance(rng, 3, 5)
        j = int(np.flatnonzero(np.isfinite(uba))[0])
        A = np.vstack([A, A[j]])  # a copy of row j beyond its upper bound
        lba, uba = np.r_[lba, uba[j] + 0.5], np.r_[uba, np.inf]
        cases.append(pytest.param((H, g, A, lba, uba, lbx, ubx), 1, id=f"random-{i}"))
    return cases


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize(("qp", "rounds"), infeasible_cases())
def test_infeasible_qp_is_not_ok_and_keeps_the_memory(monkeypatch, solver, qp, rounds):
    """An infeasible QP (the brute force finds no feasible point) gives ok False with a
    status, never an "ok" answer, after ``rounds`` rounds; the memory of the active rows
    (here the last row) is left as it was."""
    assert brute_force(*qp) is None
    n, m = qp[0].shape[0], qp[2].shape[0]
    solver_qp = DenseQp(n, m, solver=solver)
    memory = np.zeros(m)
    memory[-1] = 0.5
    solver_qp.lam_a[:] = memory
    calls = spy(monkeypatch, solver_qp)
    res = solver_qp.solve(*qp)
    assert not res.ok
    assert isinstance(res.status, str) and res.status
    assert len(calls) == rounds
    np.testing.assert_array_equal(solver_qp.lam_a, memory)
    # a failed result still has the solver's last point, and no row multipliers
    assert res.d.shape == (n,) and res.lam_x.shape == (n,)
    np.testing.assert_array_equal(res.lam_a, np.zeros(m))


def test_unknown_solver_is_a_config_error():
    """A solver name other than daqp / qpoases raises ConfigError (a ValueError) naming it."""
    with pytest.raises(ConfigError, match="'osqp'"):
        DenseQp(2, 3, solver="osqp")
    assert issubclass(ConfigError, ValueError)


@pytest.mark.parametrize("solver", SOLVERS)
def test_options_check_accepts_each_solvers_own_silently_and_names_a_bad_one(capfd, solver):
    """``check_options`` tries the options on a one-variable QP: a solver's defaults and a
    valid option of its own pass without a word; an unknown option or solver is one line
    naming the key and the offender."""
    DenseQp.check_options(solver, {})
    own = {"daqp": {"daqp": {"primal_tol": 1e-8}}, "qpoases": {"printLevel": "none"}}[solver]
    DenseQp.check_options(solver, own)
    assert capfd.readouterr().out == ""
    with pytest.raises(ConfigError, match=rf"^solver_options\.qpsol_options: {solver} rejects "
                       r"them: Unknown option: no_such$"):  # fmt: skip
        DenseQp.check_options(solver, {"no_such": 1})
    listed = r"'osqp' is not one of \['daqp', 'qpoases'\]$"
    with pytest.raises(ConfigError, match=rf"^solver_options\.qpsol: {listed}"):
        DenseQp.check_options("osqp", {})


@pytest.mark.parametrize("solver", SOLVERS)
def test_a_solve_prints_nothing_and_the_default_shift_keeps_each_row(capfd, solver):
    """CasADi's timing print is off; without ``shift_rows`` every row predicts itself."""
    qp = crossed_row_instance("upper")
    dense = DenseQp(2, 10, solver=solver)
    lam = dense.solve(*qp).lam_a.copy()
    assert capfd.readouterr().out == ""
    dense.shift()
    np.testing.assert_array_equal(dense.lam_a, lam)
    assert np.count_nonzero(lam) == 1


# -- the crossing tolerance: CROSS_TOL (1 + |d|_inf) --------------------------------------------
def one_row_qp(side, bound, far=0):
    """n = 1: ``min 1/2 d^2 -+ 0.5 d`` (unconstrained optimum +-0.5 towards ``side``) with
    row 0 ``d`` bounded at ``bound`` on ``side``, the other side far, then ``far`` rows
    that never bind; bounds on ``d`` far."""
    upper = side == "upper"
    A, lba, uba = far_rows(np.random.default_rng(3), far, 1)
    A, lba, uba = (
        np.vstack([[1.0], A]),
        np.r_[-9.0 if upper else bound, lba],
        np.r_[bound if upper else 9.0, uba],
    )
    g = np.array([-0.5 if upper else 0.5])
    return np.eye(1), g, A, lba, uba, np.array([-5.0]), np.array([5.0])


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("side", ["upper", "lower"])
@pytest.mark.parametrize(("excess", "added"), [(0.9, False), (1.1, True), (-0.5, False)])
def test_a_screened_out_row_is_crossed_only_beyond_the_tolerance(
    monkeypatch, solver, side, excess, added
):
    """The row (slack ~0.5 > screen: left out at first) is crossed by the unconstrained
    optimum d = +-0.5 by ``excess`` times the tolerance 1e-6 (1 + 0.5): only beyond it is
    the row added back (a second round, ending on the row); inside it, or on the row's
    feasible side, the first answer stands."""
    tol = 1e-6 * 1.5
    bound = 0.5 - excess * tol if side == "upper" else -0.5 + excess * tol
    qp = one_row_qp(side, bound, far=9)  # 10 rows: a first round of 8 can leave them out
    dense = DenseQp(1, 10, solver=solver, screen=0.1)
    calls = spy(monkeypatch, dense)
    res = dense.solve(*qp)
    assert res.ok
    assert [r.tolist() for r, _ in calls] == ([[], [0]] if added else [[]])
    optimum = 0.5 if side == "upper" else -0.5
    assert res.d[0] == pytest.approx(bound if added else optimum, abs=1e-12)


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("where", ["row upper", "row lower", "bound upper", "bound lower"])
@pytest.mark.parametrize(("excess", "ok"), [(0.95, True), (1.05, False)])
def test_a_solver_answer_is_accepted_within_the_tolerance_only(
    monkeypatch, solver, where, excess, ok
):
    """The solver's answer is checked: one that crosses a row or a bound by more than
    1e-6 (1 + |d|) is a failure (with the solver's status), less is accepted. The answer
    is moved to 0.25 past the constraint by ``excess`` times that tolerance (1.25e-6)."""
    H, g, A, lba, uba, lbx, ubx = one_row_qp("upper", 9.0)
    sign = 1.0 if where.endswith("upper") else -1.0
    limit = 0.25 * sign
    if where.startswith("row"):
        (uba if sign > 0 else lba)[0] = limit
    else:
        (ubx if sign > 0 else lbx)[0] = limit
    dense = DenseQp(1, 1, solver=solver, always=np.array([True]))
    q = dense._solver(1)
    run = q.run

    def answer_moved():
        run()
        q.out["x"][:] = limit + sign * excess * 1e-6 * 1.25

    monkeypatch.setattr(q, "run", answer_moved)
    res = dense.solve(H, g, A, lba, uba, lbx, ubx)
    assert res.ok is ok
    assert (res.status == "") is ok


@pytest.mark.parametrize("solver", SOLVERS)
def test_a_row_whose_slack_is_the_screen_width_is_left_out_at_first(monkeypatch, solver):
    """``screen``: a row with slack 0.25 at d = 0 and screen 0.25 is left out of the first
    round (and added back, as the optimum 0.5 crosses it)."""
    qp = one_row_qp("upper", 0.25, far=9)
    dense = DenseQp(1, 10, solver=solver, screen=0.25)
    calls = spy(monkeypatch, dense)
    res = dense.solve(*qp)
    assert res.ok and res.d[0] == pytest.approx(0.25, abs=1e-12)
    assert [r.tolist() for r, _ in calls] == [[], [0]]


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("fault", ["shifted", "nan"])
def test_an_answer_the_solver_calls_optimal_but_that_crosses_its_bounds_is_named_so(solver, fault):
    """A solver can report success on ill-conditioned data with an answer across its
    bounds; the QP layer refuses it and says both: the solver's own status and how far
    the answer is out (here a 1e-3 shift added to the solver's true optimum, so at
    ``d >= 1`` the answer is out by exactly 1e-3), or that it is not finite."""
    qp = DenseQp(2, 1, solver)
    args = (np.eye(2), np.zeros(2), np.array([[1.0, 0.0]]), np.ones(1), np.full(1, np.inf),
            -5 * np.ones(2), 5 * np.ones(2))  # fmt: skip
    assert qp.solve(*args).ok  # d = (1, 0): the row at its lower bound
    for q in qp._solvers.values():
        run = q.run

        def faulty(q=q, run=run):
            run()
            q.out["x"][:] = q.out["x"] - 1e-3 if fault == "shifted" else np.nan

        q.run = faulty
    res = qp.solve(*args)
    status = "optimal (DAQP exit flag 1)" if solver == "daqp" else "Successful return."
    out = "crosses its bounds by 1.0e-03" if fault == "shifted" else "is not finite"
    assert not res.ok and res.status == f"{status}, but the answer {out}"
