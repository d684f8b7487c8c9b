"""The ``sqp`` backend against independent truth (IPOPT on the same NLP), RTI, codegen."""

import re

import casadi as ca
import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.nmpc.constraints import Bounds, Clearance
from aeromanip.nmpc.controller import Controller
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.strategies import Hierarchical, Weighted
from aeromanip.references import Constant
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import ControlRate, EndEffectorTracking
from nmpc_helpers import FAST, X0, make_problem

X8 = load_robot("x8-3dof")


def check_feasible(pb, cmd, tol=1e-6):
    b = pb.bounds
    X, U = cmd.plan_x, cmd.plan_u
    assert np.all(X[1:] >= b.x_lower - tol) and np.all(X[1:] <= b.x_upper + tol)
    assert np.all(b.u_lower - tol <= U) and np.all(b.u_upper + tol >= U)
    clear = pb.kin.clearance()
    assert min(float(np.min(np.asarray(clear(x)))) for x in X[1:]) >= 0.1 - tol
    np.testing.assert_allclose(X[1:], X[:-1] + pb.dt * U, atol=1e-10)


def two_steps(pb, strategy, backend, options=None, **kw):
    """Two closed-loop steps (the second warm-started), the last command returned."""
    ctrl = Controller(pb, strategy, backend, options, **kw)
    first = ctrl.step(X0, 0.0)
    return ctrl.step(X0 + pb.dt * first.u, pb.dt)


def test_weighted_reaches_the_ipopt_optimum():
    pb = make_problem(levels=(0, 0))
    ref = two_steps(pb, "weighted", "ipopt")
    cmd = two_steps(pb, "weighted", "sqp", FAST)
    assert cmd.status == ref.status == "ok"
    np.testing.assert_allclose(cmd.plan_u, ref.plan_u, atol=1e-4)
    for name, c in ref.task_costs.items():
        assert cmd.task_costs[name] == pytest.approx(c, rel=1e-4, abs=1e-8)
    check_feasible(pb, cmd)


def test_active_clearance_each_solution_is_the_others_optimum():
    """A target only reachable by folding the arm up: non-convex, with several local optima
    (from a cold start the two methods may find different ones); each backend, started at
    the other's solution, stays there: both are KKT points of the same NLP."""
    pb = make_problem(levels=(0, 0), target=(0.2, 0.0, 0.95), box={"z": (1.0, 1.0 + 1e-9)})
    tr = Weighted(pb, "ipopt").transcription
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    cold = tr.pack(np.repeat(X0[None], 11, 0), np.zeros((10, 7)), np.zeros(7))
    for first, second in (("ipopt", "sqp"), ("sqp", "ipopt")):
        a = Weighted(pb, first, FAST if first == "sqp" else None).solve(p, [cold])
        b = Weighted(pb, second, FAST if second == "sqp" else None).solve(p, [a.w])
        assert a.success and b.success
        np.testing.assert_allclose(tr.unpack(b.w)[1], tr.unpack(a.w)[1], atol=1e-5)
    ctrl = Controller(pb, "weighted", "sqp", FAST)
    x = X0.copy()
    for k in range(12):
        cmd = ctrl.step(x, k * pb.dt)
        assert cmd.status == "ok"
        check_feasible(pb, cmd)
        x = x + pb.dt * cmd.u


@pytest.mark.parametrize("mode", ["stagewise", "total", "residual"])
def test_hierarchy_reaches_the_ipopt_optimum(mode):
    pb = make_problem()
    ref = two_steps(pb, "hierarchical", "ipopt", hierarchy={"mode": mode})
    cmd = two_steps(pb, "hierarchical", "sqp", FAST, hierarchy={"mode": mode})
    assert cmd.status == ref.status == "ok"
    assert [lv.success for lv in cmd.levels] == [True, True]
    np.testing.assert_allclose(cmd.plan_u, ref.plan_u, atol=1e-4)
    assert cmd.levels[0].cost == pytest.approx(ref.levels[0].cost, rel=1e-4, abs=1e-9)
    assert cmd.levels[1].cost == pytest.approx(ref.levels[1].cost, rel=1e-4, abs=1e-9)
    # the primary task keeps its optimum within the hierarchy's tolerance
    n_rows = 1 if mode == "total" else pb.horizon + 1
    assert cmd.task_costs["tracking"] <= cmd.levels[0].cost * (1 + 1e-3) + 1e-6 * n_rows + 1e-9
    check_feasible(pb, cmd)


def test_rti_iterated_converges_to_the_ipopt_solution():
    pb = make_problem(levels=(0, 0))
    ipopt, rti = Weighted(pb, "ipopt"), Weighted(pb, "sqp-rti", FAST)
    tr = ipopt.transcription
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    w_ref = ipopt.solve(p, [tr.pack(np.repeat(X0[None], 11, 0), np.zeros((10, 7)), np.zeros(7))]).w
    w = tr.pack(np.repeat(X0[None], 11, 0), np.zeros((10, 7)), np.zeros(7))
    steps = []
    for _ in range(40):
        res = rti.solve(p, [w])
        assert res.success and res.iterations == 1
        steps.append(np.abs(res.w - w).max())
        w = res.w
    assert steps[-1] < 1e-7
    np.testing.assert_allclose(tr.unpack(w)[1], tr.unpack(w_ref)[1], atol=1e-5)


def test_rti_closed_loop_tracks_like_the_converged_controller():
    pb = make_problem(levels=(0, 0), box={"z": (0.5, 2.0)})
    finals = {}
    for backend in ("sqp", "sqp-rti"):
        ctrl, x = Controller(pb, "weighted", backend, FAST), X0.copy()
        for k in range(25):
            cmd = ctrl.step(x, k * pb.dt)
            assert cmd.status == "ok"
            check_feasible(pb, cmd)
            x = x + pb.dt * cmd.u
        finals[backend] = np.asarray(pb.kin.ee_position(x)).ravel()
    np.testing.assert_allclose(finals["sqp-rti"], finals["sqp"], atol=1e-3)


def test_failures_fall_back_then_stop():
    pb = make_problem(levels=(0, 0))
    ctrl = Controller(pb, "weighted", "sqp", {**FAST, "max_iter": 1, "seed_max_iter": 1})
    cmd = ctrl.step(X0, 0.0)
    assert cmd.status == "stopped" and np.all(cmd.u == 0.0)
    assert "Maximum_Iterations" in cmd.message
    good = Controller(pb, "weighted", "sqp", FAST)
    first = good.step(X0, 0.0)
    good.time_budget_s = 1e-9
    second = good.step(X0 + pb.dt * first.u, pb.dt)
    assert second.status == "fallback"
    np.testing.assert_allclose(second.u, first.plan_u[1])


def test_infeasible_start_is_a_status_not_a_crash():
    x = X0.copy()
    x[5] = 3.0  # far beyond the shoulder limit: no command brings it back in one step
    cmd = Controller(make_problem(levels=(0, 0)), "weighted", "sqp", FAST).step(x, 0.0)
    assert cmd.status == "stopped" and cmd.message


def test_bad_options_are_config_errors():
    pb = make_problem(levels=(0, 0))
    with pytest.raises(ConfigError, match="unknown sqp option"):
        Controller(pb, "weighted", "sqp", {"max_iters": 3})
    with pytest.raises(ConfigError, match="qpsol"):
        Controller(pb, "weighted", "sqp", {**FAST, "qpsol": "nope"})
    with pytest.raises(ConfigError, match="hessian"):
        Controller(pb, "weighted", "sqp", {**FAST, "hessian": "bfgs"})


def test_hierarchical_sqp_strategy_keeps_level_order():
    pb = make_problem()
    h = Hierarchical(pb, backend="sqp", options=FAST)
    assert [len(st.entries) for st in h.solvers] == [1, 1]


def test_residual_mode_keeps_the_primary_optimum_and_improves_the_secondary():
    pb = make_problem()
    only = Problem(X8, 10, 0.5)
    only.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0)
    only.add_task(ControlRate(), weight=0.1, level=None)
    only.add_constraint(Clearance(0.1))
    alone = Controller(only, "weighted", "ipopt").step(X0, 0.0)
    for backend, opts in (("ipopt", None), ("sqp", FAST)):
        cmd = Controller(pb, "hierarchical", backend, opts, hierarchy={"mode": "residual"})
        cmd = cmd.step(X0, 0.0)
        assert cmd.status == "ok"
        primary = alone.task_costs["tracking"]
        assert cmd.levels[0].cost == pytest.approx(primary, rel=1e-4, abs=1e-9)
        assert cmd.task_costs["tracking"] <= primary * (1 + 1e-3) + 1e-6 * (pb.horizon + 1)
        assert cmd.levels[1].gain > 0.0
        check_feasible(pb, cmd)


def test_convexified_hessian_keeps_the_step_on_the_active_set():
    """Indefinite H, positive definite on null(C): the penalty makes it positive definite
    and the equality-constrained QP's step is that of the exact H (KKT solved directly)."""
    from aeromanip.nmpc.backends.sqp.convexify import convexified

    rng = np.random.default_rng(3)
    n, m = 8, 3
    C = rng.normal(size=(m, n))
    Z = np.linalg.svd(C)[2][m:].T  # null space of C
    B = rng.normal(size=(n, n))
    H = Z @ (np.eye(n - m) + 0.1 * (B[: n - m, : n - m] @ B[: n - m, : n - m].T)) @ Z.T
    H -= 5.0 * C.T @ C  # strongly negative curvature across the constraints
    assert np.linalg.eigvalsh(H).min() < 0.0
    g, r = rng.normal(size=n), rng.normal(size=m)

    def kkt_step(Hm):
        K = np.block([[Hm, C.T], [C, np.zeros((m, m))]])
        return np.linalg.solve(K, np.concatenate([-g, r]))[:n]

    Hc = convexified(H, C, np.zeros(0, dtype=int))
    assert np.linalg.eigvalsh(Hc).min() > 0.0
    np.testing.assert_allclose(kkt_step(Hc), kkt_step(H), atol=1e-9)
    P = np.eye(n) * 2.0
    assert convexified(P, C, np.zeros(0, dtype=int)) is P  # already convex: unchanged


@pytest.mark.parametrize("strategy", ["weighted", "hierarchical"])
def test_acceptable_level_ends_a_solve_that_cannot_reach_tol(strategy):
    """With tol out of reach, the acceptable level ends each solve at IPOPT's answer
    (hierarchical: level 1 under the degenerate stage-wise bounds it exists for)."""
    pb = make_problem(box={"z": (0.5, 2.0)})
    ref = two_steps(pb, strategy, "ipopt")
    opts = {**FAST, "tol": 0.0, "acceptable_tol": 1e-6, "acceptable_iter": 3}
    cmd = two_steps(pb, strategy, "sqp", opts)
    assert cmd.status == "ok"
    assert {lv.status for lv in cmd.levels} == {"Solved_To_Acceptable_Level"}
    np.testing.assert_allclose(cmd.plan_u, ref.plan_u, atol=1e-4)


@pytest.mark.parametrize("mode", ["stagewise", "residual", "total"])
def test_multiplier_shift_maps_each_row_to_its_twin_one_stage_on(mode):
    """The NLP's and the SQP's shift maps: a row moves to the row of the same kind and
    place one stage on (never across kinds); rows without a twin keep their place."""
    from aeromanip.nmpc.backends.sqp.solver import SqpBackend
    from aeromanip.nmpc.transcription import Transcription

    pb = make_problem()
    higher = [[e for e in pb.entries if e.level == 0]]
    own = [e for e in pb.entries if e.level != 0]
    tr = Transcription(pb, own, higher, mode)
    kind, stage = np.array(tr.g_kind), np.array(tr.g_stage)
    moved = tr.shift_g != np.arange(len(kind))
    assert np.all(kind[tr.shift_g] == kind)
    assert np.all(stage[tr.shift_g][moved] == stage[moved] + 1)
    # every gap row but the last stage's moves on, stage 0 included
    gaps = np.flatnonzero(kind == "gap")
    assert np.all(moved[gaps[stage[gaps] < pb.horizon - 1]])
    assert set(np.unique(kind[moved])) >= {"gap", "path"}
    # variables: stage k's to stage k+1's, the last stage's stay
    s, n = tr.stride, tr.w.numel()
    np.testing.assert_array_equal(tr.shift_w[: n - s], np.arange(s, n)[: n - s])
    sqp = SqpBackend(tr, {**FAST, "qpsol": "daqp"}).model  # the condensed model's rows
    rows = [(tr.g_kind[r], tr.g_stage[r]) for r in sqp.keep]
    rows += [(f"state{i % s}", i // s) for i in sqp.state_idx]
    for r, t in enumerate(sqp.qp.shift_rows):
        assert rows[t][0] == rows[r][0]
        assert rows[t][1] in (rows[r][1], rows[r][1] + 1)


def test_the_residual_box_of_each_stage_bounds_its_cost_at_every_corner():
    """``mode = "residual"``: each higher-level residual row ``i`` of stage ``k`` may move
    ``delta_k`` either way from its optimal value ``R_i``, with ``delta_k`` the one that
    makes ``(sum_i |R_i| + m_k delta_k)^2 = (sum_i |R_i|)^2 + m_k tol_k`` (``m_k`` rows,
    ``tol_k = max(abs_tol, rel_tol |c*_k|)``): recomputed here from the rows' values."""
    h = Hierarchical(make_problem(), mode="residual", rel_tol=1e-2, abs_tol=1e-6)
    st = h.solvers[1]
    tr = st.tr
    U = np.tile([0.05, -0.02, 0.01, 0.0, 0.1, -0.1, 0.05], (tr.N, 1))
    X = X0 + np.vstack([np.zeros(7), np.cumsum(0.5 * U, axis=0)])
    w = tr.pack(X, U, np.zeros(7))
    p = tr.parameters(X0, np.zeros(7), h.problem.stage_params(0.0))
    c_star = np.linspace(1e-5, 3e-2, tr.N + 1)  # one per stage: both tolerances in play
    lo, hi = h._residual_box(st, 0, w, p, c_star)
    rows = np.asarray(tr.hier_rows[0], dtype=int)
    R = np.asarray(ca.Function("g", [tr.w, tr.p], [tr.g])(w, p)).ravel()[rows]
    stage = np.asarray(tr.g_stage)[rows]
    assert len(np.unique(stage)) > 2
    for k in np.unique(stage):
        sel = stage == k
        delta = 0.5 * (hi[sel] - lo[sel])
        np.testing.assert_allclose(delta, delta[0], rtol=1e-6)  # one delta per stage
        np.testing.assert_allclose(lo[sel], R[sel] - delta[0], rtol=0, atol=1e-14)
        a, m = np.abs(R[sel]).sum(), sel.sum()
        tol = max(1e-6, 1e-2 * c_star[k])
        assert (a + m * delta[0]) ** 2 - a * a == pytest.approx(m * tol, rel=1e-6)


# -- Hierarchical.solve's bookkeeping: totals, per-level reports, partial and failed ends ----
def recorded_levels(monkeypatch, fail_level=None):
    """Each level's solve recorded (a real one); ``fail_level``'s replaced by a failure
    that still took 7 iterations and 0.25 s."""
    from aeromanip.nmpc import strategies
    from aeromanip.nmpc.backends.base import NlpResult

    real, results = strategies._solve_level, []

    def level(st, p, w0, ubg=None, lbg=None):
        i = len(results)
        if i == fail_level:
            n = st.tr.w.numel()
            res = NlpResult(np.full(n, 3.0), None, None, np.nan, False, "Stalled", 7, 0.25)
        else:
            res = real(st, p, w0, ubg, lbg)
        results.append(res)
        return res

    monkeypatch.setattr(strategies, "_solve_level", level)
    return results


@pytest.fixture(scope="module")
def two_levels():
    """Alignment first, tracking second: the lower level's cost depends on ``p``."""
    h = Hierarchical(make_problem(levels=(1, 0), horizon=4), mode="strict", backend="ipopt")
    tr = h.transcription
    p = tr.parameters(X0, np.zeros(7), h.problem.stage_params(0.0))
    return h, p, tr.pack(np.repeat(X0[None], 5, 0), np.zeros((4, 7)), np.zeros(7))


def test_a_hierarchys_result_adds_up_its_levels_and_reports_each(monkeypatch, two_levels):
    h, p, w0 = two_levels
    results = recorded_levels(monkeypatch)
    out = h.solve(p, [w0, None])
    assert [r.success for r in results] == [True, True] and out.success and out.status == "ok"
    assert out.iterations == sum(r.iterations for r in results) > results[1].iterations
    assert out.solve_time_s == pytest.approx(sum(r.solve_time_s for r in results), rel=1e-12)
    assert out.transcription is h.transcription and len(out.level_w) == 2
    np.testing.assert_array_equal(out.w, results[1].w)
    for rep, res in zip(out.levels, results, strict=True):
        assert (rep.success, rep.status, rep.iterations) == (True, res.status, res.iterations)
        assert rep.solve_time_s == res.solve_time_s
    C0, C1 = (h.transcription.costs(r.w, p) for r in results)
    assert out.levels[0].gain == 0.0
    assert out.levels[1].cost == pytest.approx(C1[h.rows[1]].sum(), rel=1e-12)
    gain = C0[h.rows[1]].sum() - C1[h.rows[1]].sum()  # tracking at level 0's answer - own
    assert gain > 0 and out.levels[1].gain == pytest.approx(gain, rel=1e-9)


def test_a_failed_lower_level_keeps_the_higher_ones_answer_as_partial(monkeypatch, two_levels):
    h, p, w0 = two_levels
    results = recorded_levels(monkeypatch, fail_level=1)
    out = h.solve(p, [w0, None])
    assert out.success and out.status == "partial: Stalled" and len(out.level_w) == 1
    np.testing.assert_array_equal(out.w, results[0].w)
    assert out.iterations == results[0].iterations + 7
    assert out.solve_time_s == pytest.approx(results[0].solve_time_s + 0.25, rel=1e-12)
    failed = out.levels[1]
    assert (failed.success, failed.status, failed.iterations) == (False, "Stalled", 7)
    assert failed.solve_time_s == 0.25 and np.isnan(failed.cost) and np.isnan(failed.gain)


def test_a_failed_first_level_is_a_failed_step_with_no_answer(monkeypatch, two_levels):
    h, p, w0 = two_levels
    recorded_levels(monkeypatch, fail_level=0)
    out = h.solve(p, [w0, None])
    assert out.success is False and out.status == "Stalled"
    assert out.transcription is h.transcription
    assert out.w.shape == (h.transcription.w.numel(),) and np.isnan(out.w).all()
    assert (out.iterations, out.solve_time_s) == (7, 0.25)
    assert len(out.levels) == 1 and not out.levels[0].success


@pytest.mark.parametrize("fails", [False, True])
def test_a_weighted_step_reports_its_one_solve(monkeypatch, fails):
    """``Weighted.solve``: one level report (level 0) whose cost and objective are the
    NLP's objective at the answer (CasADi's ``f`` of the transcription), gain and loss 0,
    the solve's status, iterations and time, and the answer as the only level answer; a
    failed solve (7 iterations, 0.25 s) reports its own status and NaN cost and loss."""
    w = Weighted(make_problem(levels=(0, 0), horizon=3), "ipopt")
    tr = w.transcription
    p = tr.parameters(X0, np.zeros(7), w.problem.stage_params(0.0))
    w0 = tr.pack(np.repeat(X0[None], 4, 0), np.zeros((3, 7)), np.zeros(7))
    results = recorded_levels(monkeypatch, fail_level=0 if fails else None)
    out = w.solve(p, [w0])
    (res,), (rep,) = results, out.levels
    assert out.transcription is tr and (out.success, rep.success) == (not fails, not fails)
    assert (out.iterations, out.solve_time_s) == (rep.iterations, rep.solve_time_s)
    assert (rep.iterations, rep.solve_time_s) == (res.iterations, res.solve_time_s)
    assert rep.level == 0 and rep.status == res.status and rep.gain == 0.0
    assert len(out.level_w) == 1 and out.level_w[0] is res.w and out.w is res.w
    if fails:
        assert out.status == "Stalled" and (res.iterations, res.solve_time_s) == (7, 0.25)
        assert np.isnan(rep.cost) and np.isnan(rep.objective) and np.isnan(rep.loss)
        return
    f = float(ca.Function("f", [tr.w, tr.p], [tr.f])(res.w, p))
    assert out.status == "ok" and rep.loss == 0.0 and res.iterations > 0
    assert rep.cost == pytest.approx(f, rel=1e-9) and rep.objective == rep.cost


def test_strict_bounds_pin_each_higher_row_that_a_decision_moves_and_free_the_rest(two_levels):
    """``mode = "strict"``: level 1's copy of level 0's rows is pinned (``lbg = ubg``) to
    their values at level 0's answer, except rows no decision variable moves (e.g.
    stage 0's, set by the measured state alone), which are left out (``-inf, inf``)."""
    h, p, w0 = two_levels
    w = h.solve(p, [w0, None]).level_w[0]
    st = h.solvers[1]
    rows = np.asarray(st.tr.hier_rows[0])
    lbg, ubg = h._bounds(1, p, [np.zeros(1)], [w])
    R = np.asarray(ca.Function("g", [st.tr.w, st.tr.p], [st.tr.g])(w, p)).ravel()[rows]
    moved = st.tr.g_movable[rows]
    assert moved.any() and not moved.all()
    np.testing.assert_array_equal(lbg[rows][moved], R[moved])
    np.testing.assert_array_equal(ubg[rows][moved], R[moved])
    assert np.all(np.isneginf(lbg[rows][~moved])) and np.all(np.isposinf(ubg[rows][~moved]))


@pytest.mark.parametrize(("key", "top"), [("rel_tol", 1.0), ("abs_tol", 1e6)])
def test_a_hierarchys_tolerances_are_checked_on_their_closed_range(key, top):
    pb = make_problem(horizon=2)
    for fine in (0.0, top):
        Hierarchical(pb, **{key: fine})
    for bad in (-1e-9, 2.0 * top):
        msg = f"hierarchy.{key}: must be in [0, {top:g}], got {bad}"
        with pytest.raises(ConfigError, match=f"^{re.escape(msg)}$"):
            Hierarchical(pb, **{key: bad})


def test_a_problem_without_any_row_solves_as_ipopt_does():
    """No constraint and every bound infinite: the dense SQP's QPs have no row at all (its
    merit's penalty has no multiplier to scale); it reaches IPOPT's optimum."""
    inf = np.full(7, np.inf)
    pb = Problem(X8, 3, 0.5, Bounds(Bounds.from_robot(X8).names, -inf, inf, -inf, inf))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0)
    pb.add_task(ControlRate(), weight=0.1)
    costs = []
    for backend, opts in (("sqp", {"codegen": False, "seed": "none"}), ("ipopt", None)):
        strat = Weighted(pb, backend, opts)
        tr = strat.transcription
        if backend == "sqp":
            assert strat.solvers[0].backend.model.nc == 0
        p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
        out = strat.solve(p, [tr.pack(np.repeat(X0[None], 4, 0), np.zeros((3, 7)), np.zeros(7))])
        assert out.success
        costs.append(out.levels[0].cost)
    assert costs[0] == pytest.approx(costs[1], rel=1e-6, abs=1e-9)


def test_a_problem_without_a_task_is_refused_by_the_weighted_strategy():
    pb = Problem(X8, 2, 0.5, Bounds.from_robot(X8))
    with pytest.raises(ConfigError, match=r"^tasks: the problem has no task$"):
        Weighted(pb)


def test_a_hierarchy_needs_a_task_with_a_level():
    pb = Problem(X8, 2, 0.5, Bounds.from_robot(X8))
    pb.add_task(ControlRate(), weight=0.1, level=None)
    with pytest.raises(
        ConfigError, match=r"^tasks: a hierarchy needs at least one task with a level$"
    ):
        Hierarchical(pb)


def test_the_ipopt_seed_answers_within_the_bounds_where_plain_ipopt_relaxes_them():
    """The stress bench's ``fast`` flight (velocity bounds binding from the first step):
    IPOPT with its defaults answers up to ~1e-8 beyond an active bound (its
    ``bound_relax_factor``); the SQP's seed, built by ``_seeded``, answers within every
    bound exactly, so a strict hierarchy's next level starts feasible."""
    from aeromanip.bench.controller_speed import bench_scenario
    from aeromanip.nmpc.backends import SolveRequest, make_backend

    sc = bench_scenario("fast", 10.0)
    ctrl = Controller(sc.problem, "weighted", "sqp", {"codegen": False})
    tr, backend = ctrl.strategy.transcription, ctrl.strategy.solvers[0].backend
    p = tr.parameters(sc.x0, np.zeros(sc.x0.size), sc.problem.stage_params(2.0))
    request = SolveRequest(ctrl.initial_guesses(sc.x0)[0], p, tr.lbg, tr.ubg)
    lbw, ubw = tr.variable_bounds(p)

    def beyond(w):
        return max((lbw - w).max(), (w - ubw).max())

    plain = make_backend(tr, "ipopt", {}).solve(request)
    assert plain.success and beyond(plain.w) > 1e-9  # relaxed: the contrast is real
    backend._seeded(request)
    seed = backend._ipopt.solve(request)
    assert seed.success and beyond(seed.w) <= 0.0
