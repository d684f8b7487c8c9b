"""Direct checks of the hierarchy's settings, the control-rate term's previous command, the
warm start and the fallback: each against a value computed here, independently of the code
under test (kinematics Functions for costs, an own reading of the variable layout, a
separate solve of level 0 alone for its optimum).

Tolerances: IPOPT (tol 1e-8) relaxes every bound by ``bound_relax_factor`` = 1e-8 times
``max(1, |bound|)`` and meets ``g = s`` to its tol, so a converged point may pass a
constraint bound by up to ~2e-8 ``max(1, |bound|)`` (``IPOPT_SLACK``). An active bound is
met to within 1e-6 (``ACTIVE``): at convergence slack x multiplier is ~tol, with
multipliers here well above 1e-2.
"""

import dataclasses
import functools
from types import SimpleNamespace

import numpy as np
import pytest

from aeromanip.nmpc.constraints import Bounds, Clearance
from aeromanip.nmpc.controller import Controller
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.strategies import Hierarchical, StrategyResult, Weighted
from aeromanip.nmpc.transcription import shift_map
from aeromanip.references import Constant
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import CogAlignment, ControlRate, EndEffectorTracking

X8 = load_robot("x8-3dof")
NX = 7
X0 = np.array([0.0, 0.0, 1.0, 0.0, 0.3, 0.4, -0.8])
N, DT = 6, 0.5
TRACK_W, COG_W, RATE_W = 10.0, 1.0, 0.1
HELD_XY = {"x": (0.0, 1e-9), "y": (0.0, 1e-9)}  # the platform may only climb and yaw
IPOPT_SLACK = 2e-8
ACTIVE = 1e-6
# per-DoF control-rate weights W and terminal weights W_s (all different, to see each)
RATE_WEIGHTS = {"x": 0.2, "y": 0.3, "z": 0.1, "yaw": 0.05, "q1": 0.4, "q2": 0.15, "q3": 0.25}
W_RATE = np.array(list(RATE_WEIGHTS.values()))
W_TERM = np.array([1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0])


def make_problem(target, with_cog=True, horizon=N, box=HELD_XY):
    """Tracking at level 0, CoG alignment at level 1 (optional), control rate regulariser."""
    pb = Problem(X8, horizon, DT, Bounds.from_robot(X8, platform_box=box))
    pb.add_task(EndEffectorTracking(Constant(list(target))), weight=TRACK_W, level=0)
    if with_cog:
        pb.add_task(CogAlignment(), weight=COG_W, level=1)
    pb.add_task(ControlRate(), weight=RATE_W, level=None)
    pb.add_constraint(Clearance(0.1))
    return pb


KIN = make_problem((0.0, 0.0, 0.0)).kin
EE_AT_X0 = np.asarray(KIN.ee_position(X0)).ravel()
# "far": beyond the arm's reach with the platform's x, y held (level 0's optimum > 0 at
# every stage, rel_tol matters); "here": the end effector is on the target already
# (level 0's optimum ~0, abs_tol matters)
TARGETS = {"far": np.array([0.8, 0.3, 0.6]), "here": EE_AT_X0}


def tracking_residuals(X, target):
    """Weighted tracking residuals ``sqrt(W) (p_e(x_k) - target)`` per stage: (len(X), 3)."""
    return np.array(
        [np.sqrt(TRACK_W) * (np.asarray(KIN.ee_position(x)).ravel() - target) for x in X]
    )


def tracking_costs(X, target):
    """Level 0's cost per stage, from the kinematics."""
    return np.sum(tracking_residuals(X, target) ** 2, axis=1)


def cog_costs(X):
    """Level 1's cost per stage: weighted squared body-frame xy offset of the arm CoG."""
    return np.array([COG_W * np.sum(np.asarray(KIN.cog_body(x)).ravel()[:2] ** 2) for x in X])


def layout(w, horizon=N):
    """Own reading of the documented variable order ``[z0, u0, ..., z_N]``, ``z = [x; v]``:
    states X (N+1, nx), carried previous commands V (N+1, nx), commands U (N, nx)."""
    w = np.asarray(w, dtype=float)
    s = 3 * NX
    assert w.size == horizon * s + 2 * NX
    Z = np.array([w[k * s : k * s + 2 * NX] for k in range(horizon + 1)])
    U = np.array([w[k * s + 2 * NX : (k + 1) * s] for k in range(horizon)])
    return Z[:, :NX], Z[:, NX:], U


def shifted(X, U, x0):
    """The plan moved one stage on, last entries repeated, measured state first."""
    Xs = np.vstack([X[1:], X[-1:]])
    Xs[0] = x0
    return Xs, np.vstack([U[1:], U[-1:]])


@functools.cache
def case(name):
    """Problem, parameters, cold start and level 0's own optimum per stage ``c*_k``, the
    latter from solving level 0's task and the regulariser alone (a weighted problem)."""
    target = TARGETS[name]
    pb = make_problem(target)
    alone = Weighted(make_problem(target, with_cog=False), "ipopt")
    tr = alone.transcription
    p = tr.parameters(X0, np.zeros(NX), pb.stage_params(0.0))
    cold = tr.pack(np.repeat(X0[None], N + 1, 0), np.zeros((N, NX)), np.zeros(NX))
    res = alone.solve(p, [cold])
    assert res.success
    c_star = tracking_costs(tr.unpack(res.w)[0], target)
    return SimpleNamespace(pb=pb, target=target, p=p, cold=cold, c_star=c_star)


@functools.cache
def hierarchy(name, mode="stagewise", rel_tol=1e-3, abs_tol=1e-6):
    """One solve of the two-level hierarchy on ``case(name)`` from the cold start, and the
    per-stage costs of both levels at its solution."""
    c = case(name)
    h = Hierarchical(c.pb, mode=mode, rel_tol=rel_tol, abs_tol=abs_tol)
    res = h.solve(c.p, [c.cold])
    assert res.success and res.status == "ok"
    assert [lv.success for lv in res.levels] == [True, True]
    X = h.transcription.unpack(res.w)[0]
    return SimpleNamespace(
        h=h, res=res, X=X, level0=tracking_costs(X, c.target), level1=cog_costs(X)
    )


# --- hierarchy settings ----------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "rel_tol", "abs_tol"),
    [("far", 1e-3, 1e-6), ("far", 1e-1, 1e-6), ("far", 1e-1, 1e-2), ("here", 1e-3, 1e-2)],
)
def test_stagewise_level0_cost_stays_within_its_documented_bound_and_reaches_it(
    name, rel_tol, abs_tol
):
    c = case(name)
    s = hierarchy(name, "stagewise", rel_tol, abs_tol)
    # level 0 solved inside the hierarchy found the same optimum as level 0 alone
    assert s.res.levels[0].cost == pytest.approx(c.c_star.sum(), rel=1e-8, abs=1e-14)
    bound = c.c_star + np.maximum(abs_tol, rel_tol * np.abs(c.c_star))
    assert np.all(s.level0 <= bound + IPOPT_SLACK * np.maximum(1.0, bound))
    # the bound is what limits level 1: met at some stage (stage 0's state is given)
    assert s.level0[0] == pytest.approx(c.c_star[0], rel=1e-12)
    assert np.min(np.abs(s.level0 - bound)[1:]) < ACTIVE
    # the transcription's per-stage costs agree with the kinematics
    costs = s.h.transcription.costs(s.res.w, c.p)
    np.testing.assert_allclose(costs[0], s.level0, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(costs[1], s.level1, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("mode", ["stagewise", "total", "residual"])
def test_larger_rel_tol_trades_level0_cost_for_level1_cost(mode):
    tight, loose = hierarchy("far", mode, 1e-3), hierarchy("far", mode, 1e-1)
    assert loose.level0.sum() > tight.level0.sum() * (1 + 1e-2)
    assert loose.level1.sum() < tight.level1.sum() * (1 - 1e-2)


@pytest.mark.parametrize("mode", ["stagewise", "total", "residual"])
def test_larger_abs_tol_trades_level0_cost_for_level1_cost_where_the_optimum_is_zero(mode):
    c = case("here")
    assert c.c_star.max() < 1e-12  # rel_tol * c* is negligible: abs_tol decides
    tight, loose = hierarchy("here", mode, 1e-3, 1e-6), hierarchy("here", mode, 1e-3, 1e-2)
    assert loose.level0.sum() > 1e-3 > 1e-4 > tight.level0.sum()
    assert loose.level1.sum() < tight.level1.sum() * (1 - 1e-2)
    # ... and rel_tol, a fraction of ~0, changes nothing
    other = hierarchy("here", mode, 1e-1, 1e-2)
    np.testing.assert_allclose(other.X, loose.X, atol=1e-9)


@pytest.mark.parametrize(
    ("name", "rel_tol", "abs_tol"), [("far", 1e-1, 1e-6), ("here", 1e-3, 1e-2)]
)
def test_total_mode_bounds_the_sum_over_stages_not_each_stage(name, rel_tol, abs_tol):
    c = case(name)
    s = hierarchy(name, "total", rel_tol, abs_tol)
    total_star = c.c_star.sum()
    bound = total_star + max(abs_tol, rel_tol * abs(total_star))
    assert s.level0.sum() <= bound + IPOPT_SLACK * max(1.0, bound)
    assert s.level0.sum() == pytest.approx(bound, abs=ACTIVE)  # the bound is used
    if name == "far":  # some stage goes past what the stage-wise bound would allow
        stage_bound = c.c_star + np.maximum(abs_tol, rel_tol * c.c_star)
        assert np.max(s.level0 - stage_bound) > 0.1


@pytest.mark.parametrize(("name", "rel_tol", "abs_tol"), [("far", 1e-3, 1e-6), ("far", 1e-1, 1e-6)])
def test_residual_mode_keeps_each_level0_residual_in_its_documented_box(name, rel_tol, abs_tol):
    c = case(name)
    s = hierarchy(name, "residual", rel_tol, abs_tol)
    # the box is built around level 0's own solution R*_k, with half-width delta_k such
    # that sum_i (|R*_ki| + delta_k)^2 = c*_k + tol_k (the cost bound at every corner)
    R_star = tracking_residuals(s.h.transcription.unpack(s.res.level_w[0])[0], c.target)
    R = tracking_residuals(s.X, c.target)
    c_k = np.sum(R_star**2, axis=1)
    np.testing.assert_allclose(c_k, c.c_star, rtol=1e-8, atol=1e-14)
    tol = np.maximum(abs_tol, rel_tol * c_k)
    delta = np.empty(N + 1)
    for k in range(N + 1):  # the identity above as a quadratic in delta, its positive root
        a, m = np.abs(R_star[k]).sum(), R_star.shape[1]
        roots = np.roots([m, 2.0 * a, np.sum(R_star[k] ** 2) - c_k[k] - tol[k]])
        delta[k] = roots.real.max()
        assert delta[k] > 0
    edge = np.abs(R_star) + delta[:, None]  # |box bounds|
    slack = IPOPT_SLACK * np.maximum(1.0, edge)
    dev = np.abs(R - R_star)
    assert np.all(dev <= delta[:, None] + slack)
    assert np.min(np.abs(dev - delta[:, None])[1:]) < ACTIVE  # the box binds somewhere
    # inside the box the cost bound holds, as documented (to first order in the slack)
    assert np.all(s.level0 <= c_k + tol + np.sum(2.0 * edge * slack + slack**2, axis=1))


@pytest.mark.parametrize("mode", ["stagewise", "total", "residual"])
def test_level_reports_give_own_cost_without_regularisers_and_the_gain(mode):
    c = case("far")
    s = hierarchy("far", mode)
    lv0, lv1 = s.res.levels
    w0, w1 = s.res.level_w
    np.testing.assert_array_equal(w1, s.res.w)
    X0_sol, X1_sol = (s.h.transcription.unpack(w)[0] for w in (w0, w1))
    assert (lv0.level, lv1.level) == (0, 1)
    assert lv0.cost == pytest.approx(tracking_costs(X0_sol, c.target).sum(), rel=1e-12)
    assert lv0.cost == pytest.approx(c.c_star.sum(), rel=1e-8)
    assert lv1.cost == pytest.approx(cog_costs(X1_sol).sum(), rel=1e-12)
    assert lv0.gain == 0.0
    gain = cog_costs(X0_sol).sum() - cog_costs(X1_sol).sum()
    assert lv1.gain == pytest.approx(gain, rel=1e-10)
    assert lv1.gain > 0.0


# --- the control rate's previous command --------------------------------------------------


def rate_problem(horizon=N):
    """Tracking plus a control rate with per-DoF weights W and terminal weights W_s."""
    pb = Problem(X8, horizon, DT, Bounds.from_robot(X8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=TRACK_W)
    pb.add_task(ControlRate(), weight=RATE_WEIGHTS, terminal_weight=W_TERM, level=None)
    pb.add_constraint(Clearance(0.1))
    return pb


def spy(ctrl, inner=None):
    """Replace ``ctrl.strategy.solve`` by a recorder of each call's parameters, guesses and
    result; ``inner`` (default: the real solve) gives the result."""
    calls = []
    solve = inner or ctrl.strategy.solve

    def recording(p, guesses):
        res = solve(p, guesses)
        kept = [None if g is None else np.array(g) for g in guesses]
        calls.append(SimpleNamespace(p=np.array(p), guesses=kept, res=res))
        return res

    ctrl.strategy.solve = recording
    return calls


def failing(tr):
    """A strategy solve that always fails (as an infeasible NLP would)."""

    def solve(p, guesses):
        n = tr.w.numel()
        return StrategyResult(np.full(n, np.nan), tr, False, "Infeasible_Problem_Detected", 3, 0.0)

    return solve


def rate_costs(U, u_prev):
    """Independent control-rate cost per stage: ``||W^1/2 (U[k] - U[k-1])||^2`` with
    ``U[-1] = u_prev``, then the terminal ``||W_s^1/2 U[N-1]||^2``."""
    prev = np.vstack([u_prev[None], U[:-1]])
    return np.append(np.sum(W_RATE * (U - prev) ** 2, axis=1), np.sum(W_TERM * U[-1] ** 2))


def test_control_rate_at_stage0_is_measured_against_the_applied_command():
    pb = rate_problem()
    ctrl = Controller(pb, "weighted", "ipopt")
    calls = spy(ctrl)
    tr = ctrl.strategy.transcription
    rate = [e.name for e in pb.entries].index("control_rate")
    first = ctrl.step(X0, 0.0)
    u_a = first.u
    np.testing.assert_array_equal(u_a, first.plan_u[0])
    assert np.linalg.norm(u_a) > 0.05  # a previous command that shows in the cost
    np.testing.assert_array_equal(ctrl.u_prev, u_a)
    x1 = X0 + DT * u_a + np.array([0.01, -0.02, 0.0, 0.01, 0.02, 0.0, -0.01])
    second = ctrl.step(x1, DT)
    assert second.status == "ok"
    p = calls[-1].p
    np.testing.assert_array_equal(p[:NX], x1)
    np.testing.assert_array_equal(p[NX : 2 * NX], u_a)
    expected = rate_costs(second.plan_u, u_a)
    per_stage = tr.costs(calls[-1].res.w, p)[rate]
    np.testing.assert_allclose(per_stage, expected, rtol=1e-10, atol=1e-14)
    # stage 0 and the terminal stage spelled out (paper eq. 4)
    d0 = second.plan_u[0] - u_a
    assert per_stage[0] == pytest.approx(np.sum(W_RATE * d0**2), rel=1e-10)
    assert per_stage[N] == pytest.approx(np.sum(W_TERM * second.plan_u[N - 1] ** 2), rel=1e-10)
    assert second.task_costs["control_rate"] == pytest.approx(expected.sum(), rel=1e-10)
    # the first step was measured against zero (nothing applied yet)
    expected_first = rate_costs(first.plan_u, np.zeros(NX)).sum()
    assert first.task_costs["control_rate"] == pytest.approx(expected_first, rel=1e-10)


def test_previous_command_after_fallback_stop_and_reset_is_the_one_applied():
    pb = rate_problem()
    ctrl = Controller(pb, "weighted", "ipopt")
    calls = spy(ctrl)
    first = ctrl.step(X0, 0.0)
    ctrl.time_budget_s = 1e-12  # every solve is now over budget: failed
    x1 = X0 + DT * first.u
    second = ctrl.step(x1, DT)
    assert second.status == "fallback" and "over budget" in second.message
    np.testing.assert_array_equal(second.u, first.plan_u[1])
    np.testing.assert_array_equal(ctrl.u_prev, first.plan_u[1])
    third = ctrl.step(x1 + DT * second.u, 2 * DT)
    np.testing.assert_array_equal(calls[-1].p[NX : 2 * NX], first.plan_u[1])
    np.testing.assert_array_equal(ctrl.u_prev, third.u)
    # reset with a command applied by someone else: the next solve starts from it
    u_ext = np.array([0.1, -0.2, 0.05, 0.0, 0.3, -0.1, 0.2])
    ctrl.reset(u_prev=u_ext)
    np.testing.assert_array_equal(ctrl.u_prev, u_ext)
    ctrl.time_budget_s = None
    fourth = ctrl.step(x1, 3 * DT)
    assert fourth.status == "ok"
    p = calls[-1].p
    np.testing.assert_array_equal(p[NX : 2 * NX], u_ext)
    rate = [e.name for e in pb.entries].index("control_rate")
    per_stage = ctrl.strategy.transcription.costs(calls[-1].res.w, p)[rate]
    np.testing.assert_allclose(per_stage, rate_costs(fourth.plan_u, u_ext), rtol=1e-10)
    # a stop applies zero: the next step's previous command is zero
    ctrl.strategy.solve = failing(ctrl.strategy.transcription)
    ctrl.reset(u_prev=u_ext)
    stop = ctrl.step(x1, 4 * DT)
    assert stop.status == "stopped"
    np.testing.assert_array_equal(ctrl.u_prev, np.zeros(NX))


# --- warm start -------------------------------------------------------------------------


def test_first_guess_is_rest_at_x0_and_next_is_the_last_plan_shifted():
    pb = rate_problem()
    ctrl = Controller(pb, "weighted", "ipopt")
    calls = spy(ctrl)
    first = ctrl.step(X0, 0.0)
    X, V, U = layout(calls[0].guesses[0])
    np.testing.assert_array_equal(X, np.repeat(X0[None], N + 1, 0))
    np.testing.assert_array_equal(U, np.zeros((N, NX)))
    np.testing.assert_array_equal(V, np.zeros((N + 1, NX)))
    # the measured state differs from the prediction: stage 0 takes it, the rest shifts
    x1 = X0 + DT * first.u + 0.01
    ctrl.step(x1, DT)
    X, V, U = layout(calls[1].guesses[0])
    Xe, Ue = shifted(first.plan_x, first.plan_u, x1)
    np.testing.assert_array_equal(X, Xe)
    np.testing.assert_array_equal(X[1:-1], first.plan_x[2:])
    np.testing.assert_array_equal(U, Ue)
    np.testing.assert_array_equal(U[:-1], first.plan_u[1:])
    np.testing.assert_array_equal(V[0], first.u)  # the applied command
    np.testing.assert_array_equal(V[1:], Ue)  # v[k+1] = u[k]
    assert len(calls[1].guesses) == 1


def test_reset_makes_the_next_start_cold_guess_and_multipliers():
    """The solver gets no multipliers on a cold start, the last step's moved one stage on
    (``shift_g``, ``shift_w``) on a warm one, and none again after ``reset``."""
    pb = rate_problem()
    ctrl = Controller(pb, "weighted", "ipopt")
    st = ctrl.strategy.solvers[0]
    tr = st.tr
    seen = []

    class Recorder:
        """Stands for the nlpsol: records its arguments."""

        def __init__(self, f):
            self.f = f

        def __call__(self, **kw):
            seen.append({k: np.array(v, dtype=float) for k, v in kw.items()})
            return self.f(**kw)

        def stats(self):
            return self.f.stats()

    st.backend.solver = Recorder(st.backend.solver)
    first = ctrl.step(X0, 0.0)
    assert "lam_g0" not in seen[0] and "lam_x0" not in seen[0]
    lam_g, lam_x = st.warm.lam_g.copy(), st.warm.lam_x.copy()
    assert np.abs(lam_g).max() > 1e-3  # multipliers worth passing on
    x1 = X0 + DT * first.u
    ctrl.step(x1, DT)
    np.testing.assert_array_equal(seen[1]["lam_g0"], lam_g[tr.shift_g])
    np.testing.assert_array_equal(seen[1]["lam_x0"], lam_x[tr.shift_w])
    ctrl.reset()
    ctrl.step(x1, 2 * DT)
    assert "lam_g0" not in seen[2] and "lam_x0" not in seen[2]
    X, V, U = layout(seen[2]["x0"].ravel())
    np.testing.assert_array_equal(X, np.repeat(x1[None], N + 1, 0))
    np.testing.assert_array_equal(U, np.zeros((N, NX)))
    np.testing.assert_array_equal(V, np.zeros((N + 1, NX)))
    assert len(seen) == 3  # no retries hid in between


@pytest.mark.parametrize("backend", ["ipopt", "sqp"])
@pytest.mark.parametrize("mode", ["strict", "stagewise"])
def test_hierarchy_levels_start_from_documented_guesses(backend, mode):
    """Levels below the first start from the higher level's solution of this step (IPOPT,
    and an SQP in strict mode, whose level must start on the pinned rows); an SQP level of
    a relaxed mode from its own last solution, shifted."""
    pb = make_problem(TARGETS["far"])
    opts = {"codegen": False} if backend == "sqp" else None
    # the regulariser at full weight in every level: with strict mode's 10 % the SQP's
    # level 1 fails here (test below); this test is about where each level starts
    hierarchy = {"mode": mode, "regularizer_scale": 1.0}
    ctrl = Controller(pb, "hierarchical", backend, opts, hierarchy=hierarchy)
    calls = spy(ctrl)
    starts = [[], []]
    for i, st in enumerate(ctrl.strategy.solvers):

        def record(request, _solve=st.backend.solve, _i=i):
            starts[_i].append(np.array(request.w0))
            return _solve(request)

        st.backend.solve = record
    first = ctrl.step(X0, 0.0)
    x1 = X0 + DT * first.u + 0.01
    second = ctrl.step(x1, DT)
    assert first.status == second.status == "ok"
    assert [len(s) for s in starts] == [2, 2]
    w0_prev, w1_prev = calls[0].res.level_w
    w0_now = calls[1].res.level_w[0]
    # step 1, level 1: level 0's solution (no own solution yet)
    np.testing.assert_array_equal(starts[1][0], w0_prev)
    for lvl, w_prev in enumerate((w0_prev, w1_prev)):
        X, _, U = layout(w_prev)
        Xe, Ue = shifted(X, U, x1)
        Xg, Vg, Ug = layout(calls[1].guesses[lvl])
        np.testing.assert_array_equal(Xg, Xe)
        np.testing.assert_array_equal(Ug, Ue)
        np.testing.assert_array_equal(Vg, np.vstack([first.u[None], Ue]))
    np.testing.assert_array_equal(starts[0][1], calls[1].guesses[0])
    if backend == "sqp" and mode != "strict":
        np.testing.assert_array_equal(starts[1][1], calls[1].guesses[1])
    else:
        np.testing.assert_array_equal(starts[1][1], w0_now)


def test_the_strict_sqp_solves_level_one_toward_an_unreachable_target():
    """With the regulariser at 10 % in level 0 the arm is stretched to its bounds toward
    the unreachable target; level 1 starts from level 0's answer (the IPOPT seed's, on a
    cold start), which must lie within the bounds: 1e-8 beyond them (IPOPT's default
    relaxation) DAQP found level 1's first QP, the higher rows pinned, infeasible."""
    ctrl = Controller(make_problem(TARGETS["far"]), "hierarchical", "sqp", {"codegen": False})
    cmd = ctrl.step(X0, 0.0)
    assert cmd.status == "ok", [lv.status for lv in cmd.levels]


def test_pack_unpack_round_trip_and_the_documented_layout():
    tr = Weighted(rate_problem()).transcription
    rng = np.random.default_rng(7)
    X, U, u_prev = rng.normal(size=(N + 1, NX)), rng.normal(size=(N, NX)), rng.normal(size=NX)
    w = tr.pack(X, U, u_prev)
    Xw, Vw, Uw = layout(w)
    np.testing.assert_array_equal(Xw, X)
    np.testing.assert_array_equal(Uw, U)
    np.testing.assert_array_equal(Vw, np.vstack([u_prev[None], U]))
    Xu, Uu = tr.unpack(w)
    np.testing.assert_array_equal(Xu, X)
    np.testing.assert_array_equal(Uu, U)
    # shift_w moves every stage's variables one stage on; the last stage keeps its own
    Xs, Vs, Us = layout(w[tr.shift_w])
    np.testing.assert_array_equal(Xs, np.vstack([X[1:], X[-1:]]))
    np.testing.assert_array_equal(Vs, np.vstack([Vw[1:], Vw[-1:]]))
    np.testing.assert_array_equal(Us, np.vstack([U[1:], U[-1:]]))


def test_shift_map_sends_each_row_to_its_twin_one_stage_on():
    rows = [
        ("gap", 0), ("gap", 0), ("gap", 0), ("hier0", 0),
        ("gap", 1), ("gap", 1), ("gap", 1), ("path", 1), ("hier0", 1),
        ("path", 2), ("hier0", 2), ("terminal", 2),
        ("hier1", -1),
    ]  # fmt: skip
    expected = [4, 5, 6, 8, 4, 5, 6, 9, 10, 9, 10, 11, 12]
    np.testing.assert_array_equal(shift_map(rows), expected)


# --- fallback ---------------------------------------------------------------------------


def test_fallback_applies_clipped_successive_plan_commands_then_stops():
    pb = rate_problem(horizon=5)
    ctrl = Controller(pb, "weighted", "ipopt")
    first = ctrl.step(X0, 0.0)
    assert first.status == "ok"
    U1 = first.plan_u
    # narrower command bounds from now on: half of what the rest of the plan asks
    cap = 0.5 * np.abs(U1[1:]).max(axis=0)
    lo, hi = -cap, cap.copy()
    lo[4] = -np.inf  # one DoF bounded on one side only
    pb.bounds = dataclasses.replace(pb.bounds, u_lower=lo, u_upper=hi)
    calls = spy(ctrl, failing(ctrl.strategy.transcription))
    x = X0 + DT * first.u
    clipped = 0
    for k in range(1, 5):
        cmd = ctrl.step(x, k * DT)
        assert cmd.status == "fallback"
        assert cmd.message == "Infeasible_Problem_Detected"
        expected = np.minimum(np.maximum(U1[k], lo), hi)
        np.testing.assert_array_equal(cmd.u, expected)
        np.testing.assert_array_equal(ctrl.u_prev, expected)
        np.testing.assert_array_equal(cmd.plan_u, U1)
        assert all(np.isnan(v) for v in cmd.task_costs.values())
        clipped += int(np.sum(expected != U1[k]))
        x = x + DT * cmd.u
    assert 0 < clipped < 4 * NX  # some entries clipped, some not
    # the N-th failure in a row: nothing left of the plan, stop
    for k in (5, 6):
        cmd = ctrl.step(x, k * DT)
        assert cmd.status == "stopped"
        np.testing.assert_array_equal(cmd.u, np.zeros(NX))
        np.testing.assert_array_equal(cmd.plan_x, np.repeat(x[None], 6, 0))
        np.testing.assert_array_equal(cmd.plan_u, np.zeros((5, NX)))
    assert len(calls) == 6
    # the fallback's next guess is the cold one: the plan was dropped
    X, V, U = layout(calls[-1].guesses[0], horizon=5)
    np.testing.assert_array_equal(X, np.repeat(x[None], 6, 0))
    np.testing.assert_array_equal(U, np.zeros((5, NX)))
    np.testing.assert_array_equal(V, np.zeros((6, NX)))  # zero applied at the stop


@pytest.mark.parametrize(
    "backend, own",
    [
        ("sqp", True),
        ("sqp-rti", True),
        ("aeromanip.nmpc.backends.sqp.solver:SqpBackend", True),  # a user's name for an SQP
        ("ipopt", False),
    ],
)
def test_a_relaxed_level_starts_from_its_own_guess_when_the_backend_needs_no_feasible_start(
    backend, own
):
    """A relaxed (``stagewise``) level: the choice follows
    ``Backend.needs_feasible_start`` (the SQP: False), not the
    name: an SQP named ``"package.module:Class"`` starts from its own guess too; a strict
    hierarchy never does (it starts from the level above's solution)."""
    from nmpc_helpers import FAST, make_problem

    opts = FAST if backend != "ipopt" else None
    relaxed = Hierarchical(make_problem(horizon=2), "stagewise", backend=backend, options=opts)
    assert relaxed.own_guess is own
    strict = Hierarchical(make_problem(horizon=2), "strict", backend=backend, options=opts)
    assert strict.own_guess is False
