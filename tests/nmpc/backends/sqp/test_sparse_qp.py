"""The sparse (multiple-shooting, HPIPM) QP model of the SQP backend: its step check,
merit, KKT error, exact and Gauss-Newton Hessian blocks and row products against the
NLP's own derivatives (CasADi), and hierarchies solved as IPOPT solves them.
"""

from __future__ import annotations

from types import SimpleNamespace

import casadi as ca
import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.experiment.scenario import load_scenarios
from aeromanip.nmpc.backends import SolveRequest
from aeromanip.nmpc.backends.sqp.convexify import convexified_blocks, reduced_convexified
from aeromanip.nmpc.backends.sqp.dense_qp import QpResult
from aeromanip.nmpc.backends.sqp.ocp_ipm import RiccatiQp
from aeromanip.nmpc.backends.sqp.solver import (
    DEFAULTS,
    SqpBackend,
)
from aeromanip.nmpc.backends.sqp.sparse_qp import SparseQpModel
from aeromanip.nmpc.constraints import Bounds, Clearance
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.strategies import Hierarchical, Weighted
from aeromanip.references import Constant
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import CogAlignment, CogVelocity, ControlRate, EndEffectorTracking
from aeromanip.tasks.posture import Posture
from nmpc_helpers import X0, rest

# --- the sparse (HPIPM) QP model: its step check and its merit ---------------------------------


@pytest.fixture(scope="module")
def sparse_model(small_problem):
    opts = {"codegen": False, "qpsol": "hpipm"}
    if "seed" in DEFAULTS:
        opts["seed"] = "none"
    strat = Weighted(small_problem, "sqp", opts)
    tr, model = strat.transcription, strat.solvers[0].backend.model
    assert type(model).__name__ == "SparseQpModel"
    p = tr.parameters(X0, np.zeros(7), small_problem.stage_params(0.0))
    model.start(SolveRequest(tr.pack(*rest(small_problem), np.zeros(7)), p, tr.lbg, tr.ubg))
    return small_problem, tr, model, p


def test_a_qp_step_that_leaves_a_variable_bound_on_either_side_is_not_a_solution(sparse_model):
    """Steps along the dynamics (the gap rows hold exactly) that command the platform's x
    beyond its speed limit: only a variable bound is crossed, on one side or the other."""
    pb, tr, model, p = sparse_model
    v = tr.pack(*rest(pb), np.zeros(7))
    lin = model.linearize(v, p)
    assert model._solved(lin, np.zeros_like(v)) == (True, "")
    for side in (+1.0, -1.0):
        U = np.zeros((pb.horizon, 7))
        U[0, 0] = side * (pb.bounds.u_upper[0] + 0.5)
        step = tr.pack(*rest(pb, U), np.zeros(7)) - v
        ok, status = model._solved(lin, step)
        assert not ok and status
        U[0, 0] = side * 0.5 * pb.bounds.u_upper[0]  # inside: a solution of the rows
        assert model._solved(lin, tr.pack(*rest(pb, U), np.zeros(7)) - v) == (True, "")


def test_the_merit_pins_stage_zero_to_the_measured_state(sparse_model):
    pb, tr, model, p = sparse_model
    v = tr.pack(*rest(pb), np.zeros(7))
    f0, viol0 = model.merit(v, p)
    assert viol0 < 1e-12
    for side in (+1.0, -1.0):
        moved = v.copy()
        moved[tr.index_x[0]] += side * 0.1
        assert model.merit(moved, p) == (f0, viol0)


def test_the_linearisation_pins_stage_zero_to_the_measured_state_from_either_side(sparse_model):
    """A guess whose stage-0 state is above or below the measured one is linearised at the
    measured state (the variable bounds of stage 0 are the state itself)."""
    pb, tr, model, p = sparse_model
    v = tr.pack(*rest(pb), np.zeros(7))
    at = model.linearize(v, p)
    for side in (+1.0, -1.0):
        moved = v.copy()
        moved[tr.index_x[0]] += side * 0.1
        lin = model.linearize(moved, p)
        np.testing.assert_array_equal(lin.data["v"], v)
        assert lin.f == at.f and np.array_equal(lin.grad, at.grad)


def test_the_sparse_model_takes_the_multipliers_only_when_both_come(sparse_model):
    """``start``: the rows' and the variables' multipliers are the given ones (moved a stage
    on with ``shift``) only when both are given; one alone starts both at zero."""
    pb, tr, model, p = sparse_model
    w = tr.pack(*rest(pb), np.zeros(7))
    rng = np.random.default_rng(3)
    lam_g, lam_x = rng.normal(size=tr.g.numel()), rng.normal(size=w.size)
    for given in ((lam_g, None), (None, lam_x)):
        _, lam_c, lam_v = model.start(SolveRequest(w, p, tr.lbg, tr.ubg, *given, True))
        assert not lam_c.any() and not lam_v.any()
        assert lam_c.shape == (tr.g.numel(),) and lam_v.shape == w.shape
    _, lam_c, lam_v = model.start(SolveRequest(w, p, tr.lbg, tr.ubg, lam_g, lam_x, False))
    assert np.array_equal(lam_c, lam_g) and np.array_equal(lam_v, lam_x)
    _, lam_c, lam_v = model.start(SolveRequest(w, p, tr.lbg, tr.ubg, lam_g, lam_x, True))
    assert np.array_equal(lam_c, lam_g[tr.shift_g]) and np.array_equal(lam_v, lam_x[tr.shift_w])


def test_a_converged_sqps_qp_residuals_are_a_hundredth_of_its_tolerance_within_limits():
    """HPIPM's residual tolerance: 1e-2 times a converged SQP's ``tol``, no looser than
    1e-8 and no tighter than 1e-10; an RTI's is its own (1e-7) whatever its ``tol``."""
    from aeromanip.nmpc.backends.sqp.hpipm import HPIPM_LIMITS, qp_tolerance

    assert qp_tolerance("sqp", 1e-6) == pytest.approx(1e-8)  # the default tol
    assert qp_tolerance("sqp", 1e-7) == pytest.approx(1e-9)
    assert qp_tolerance("sqp", 1e-9) == 1e-10  # the backend matrix test's
    assert qp_tolerance("sqp", 0.0) == 1e-10  # only the acceptable level ends a solve
    assert qp_tolerance("sqp", 1e-3) == 1e-8
    rti = HPIPM_LIMITS["rti"][0]  # a real-time iteration's: whatever the SQP's tol
    assert qp_tolerance("rti", 1e-3) == qp_tolerance("rti", 1e-9) == rti < 1e-6


@pytest.mark.parametrize(("rti", "sqp_tol", "qp_tol"), [(False, 1e-6, 1e-8),
                         (False, 1e-9, 1e-10), (True, 1e-9, 1e-7)])  # fmt: skip
def test_the_sparse_models_hpipm_has_its_limits_and_prints_nothing(
    monkeypatch, capfd, small_problem, rti, sqp_tol, qp_tol
):
    """The HPIPM solver a sparse model builds gets the limits of its kind (a converged
    SQP's or an RTI's: iterations ``HPIPM_LIMITS``, residuals from the SQP's ``tol``), the
    user's HPIPM options added key by key (one given keeps the others); a solve prints
    nothing (no timings)."""
    from aeromanip.nmpc.backends.sqp.hpipm import HPIPM_LIMITS

    made, real = [], ca.conic

    def conic(name, solver, sparsity, opts):
        if name.startswith("aeromanip_hpipm_"):  # not the options' trial QP
            made.append((solver, opts))
        return real(name, solver, sparsity, opts)

    monkeypatch.setattr(ca, "conic", conic)
    opts = {"codegen": False, "qpsol": "hpipm", "seed": "none", "rti": rti, "tol": sqp_tol,
            "qpsol_options": {"hpipm": {"warm_start": True}}}  # fmt: skip
    strat = Weighted(small_problem, "sqp", opts)
    monkeypatch.undo()
    # the solver of the SQP's tolerance, and one of the tightest (after a near-failed line
    # search) unless that is the same
    tols = [qp_tol] if qp_tol == HPIPM_LIMITS["rti" if rti else "sqp"][0] else [qp_tol, 1e-10]
    assert len(made) == len(tols)
    for (solver, given), tol in zip(made, tols, strict=True):
        iterations = HPIPM_LIMITS["rti" if rti else "sqp"][1]
        assert solver == "hpipm" and given["print_time"] is False
        hpipm = given["hpipm"]
        assert hpipm["warm_start"] is True and hpipm["mode"] == "robust"
        assert hpipm["iter_max"] == iterations
        assert all(hpipm[f"res_{r}_max"] == pytest.approx(tol) for r in "gbdm")
    tr = strat.transcription
    p = tr.parameters(X0, np.zeros(7), small_problem.stage_params(0.0))
    capfd.readouterr()
    assert strat.solve(p, [tr.pack(*rest(small_problem), np.zeros(7))]).success
    assert capfd.readouterr().out == ""
    assert HPIPM_LIMITS["rti"] != HPIPM_LIMITS["sqp"]


def test_hpipm_options_are_tried_on_hpipm_and_auto_checks_both_solvers():
    """``qpsol = "hpipm"``: its own options pass, an unknown one or a value of the wrong type
    is one line naming it; ``"auto"`` may use either QP solver (dense up to
    ``condense_max_horizon``, the Riccati interior point beyond, which takes none), so
    without a horizon its options must suit both, whatever that limit."""
    SqpBackend.check_options({"qpsol": "hpipm", "qpsol_options": {"hpipm": {"iter_max": 30}}})
    with pytest.raises(ConfigError, match=r"^solver_options\.qpsol_options: hpipm rejects "
                       r"them: Unknown option: no_such$"):  # fmt: skip
        SqpBackend.check_options({"qpsol": "hpipm", "qpsol_options": {"no_such": 1}})
    with pytest.raises(ConfigError, match=r"^solver_options\.qpsol_options: hpipm rejects "
                       r"them: .*OT_INT cannot be cast to OT_DICT"):  # fmt: skip
        SqpBackend.check_options({"qpsol": "hpipm", "qpsol_options": {"hpipm": 3}})
    opts = {"qpsol": "auto", "condense_max_horizon": 100, "qpsol_options": {"hpipm": {}}}
    with pytest.raises(ConfigError, match=r"^solver_options\.qpsol_options: daqp "
                       r"rejects them: Unknown option: hpipm$"):  # fmt: skip
        SqpBackend.check_options(opts)
    opts = {"qpsol": "auto", "condense_max_horizon": 1, "qpsol_options": {"daqp": {}}}
    with pytest.raises(ConfigError, match=r"^solver_options\.qpsol_options: daqp: qpsol "
                       r"'riccati' takes no options"):  # fmt: skip
        SqpBackend.check_options(opts)


def test_a_refused_key_inside_hpipm_options_is_named():
    """HPIPM's own refusal of a key inside ``hpipm = {...}`` says only "Unknown option":
    the check names the key and its value, the first refused one among good ones."""
    opts = {"qpsol": "hpipm", "qpsol_options": {"hpipm": {"iter_max": 30, "iter_maxx": 3}}}
    with pytest.raises(ConfigError, match=r"^solver_options\.qpsol_options: hpipm rejects "
                       r"them: .*\(hpipm\.iter_maxx = 3\)$"):  # fmt: skip
        SqpBackend.check_options(opts)


@pytest.mark.parametrize("horizon", [12, 13, 50])
def test_auto_at_a_known_horizon_checks_the_qp_solver_it_picks(horizon):
    """With the horizon known (a scenario's, or the transcription's when the backend is
    built), ``"auto"``'s options need suit only the solver picked there: DAQP's options
    are taken up to ``condense_max_horizon`` (12), and refused beyond it by the Riccati
    interior point, which takes none, in one line, from the scenario file as from the
    API; HPIPM's are taken where ``qpsol = "hpipm"`` names it."""
    opts = {"qpsol_options": {"daqp": {"iter_limit": 100}}}
    sets = [f"controller.horizon={horizon}", "controller.backend='sqp'",
            "controller.solver_options.qpsol_options={daqp={iter_limit=100}}"]  # fmt: skip
    if horizon <= 12:
        SqpBackend.check_options(opts, horizon)
        load_scenarios("flight", sets)
        return
    one_line = r"^solver_options\.qpsol_options: daqp: qpsol 'riccati' takes no options"
    with pytest.raises(ConfigError, match=one_line):
        SqpBackend.check_options(opts, horizon)
    with pytest.raises(ConfigError, match=one_line):
        load_scenarios("flight", sets)
    hpipm = {"qpsol": "hpipm", "qpsol_options": {"hpipm": {"iter_max": 30}}}
    SqpBackend.check_options(hpipm, horizon)


def test_an_unknown_sqp_option_is_named_with_every_known_one():
    with pytest.raises(ConfigError) as err:
        SqpBackend.check_options({"tolerance": 1e-6})
    known = ", ".join(DEFAULTS)
    assert str(err.value) == f"solver_options.tolerance: unknown sqp option (known: {known})"


def sparse_clearance_point(accel: bool):
    """The sparse model of a 3-step tracking and CoG-velocity problem with the clearance
    rows (and, if ``accel``, command-rate rows), linearised at a moving plan: ``tr, model,
    p, w, lin``."""
    x8 = load_robot("x8-3dof")
    bounds = Bounds.from_robot(x8)
    pb = Problem(x8, 3, 0.5, bounds.with_accel(np.full(7, 2.0)) if accel else bounds)
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0)
    pb.add_task(CogVelocity(), weight=1.0)  # bilinear: the Hessian depends on u
    pb.add_task(ControlRate(), weight=0.1, level=None)
    pb.add_constraint(Clearance(0.1))
    strat = Weighted(pb, "sqp", {"codegen": False, "qpsol": "hpipm", "seed": "none"})
    tr, model = strat.transcription, strat.solvers[0].backend.model
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    U = np.tile([0.1, -0.05, 0.02, 0.1, 0.2, -0.1, 0.1], (pb.horizon, 1))
    w = tr.pack(*rest(pb, U), np.zeros(7))
    model.start(SolveRequest(w, p, tr.lbg, tr.ubg, None, None, True))
    lin = model.linearize(w, p)
    return tr, model, p, w, lin


def test_the_sparse_models_exact_hessian_blocks_are_the_nlps_lagrangian_hessian():
    """``SparseQpModel._hessian_blocks(exact=True)``: each stage's block (its
    state and command) and the terminal one are the blocks of the NLP's Lagrangian
    Hessian ``f + lam' g`` (CasADi's derivatives; the model rows are linear, the problem
    couples no two stages), plus the regularisation; with the clearance rows (curved), the
    command-rate rows (in every stage but the terminal one) and random multipliers on
    every row."""
    tr, model, p, w, lin = sparse_clearance_point(accel=True)
    lam = np.random.default_rng(5).normal(size=tr.g.numel())
    Hs, HT = model._hessian_blocks(lin, lam, p, True)
    L = tr.f + ca.dot(ca.DM(lam), tr.g)
    H = np.asarray(ca.Function("H", [tr.w, tr.p], [ca.hessian(L, tr.w)[0]])(w, p))
    reg, s, N = model.opts["regularization"], tr.stride, tr.N
    for k in range(N):
        block = H[k * s : (k + 1) * s, k * s : (k + 1) * s] + reg * np.eye(s)
        np.testing.assert_allclose(Hs[k], block, atol=1e-9, rtol=1e-9)
    np.testing.assert_allclose(HT, H[N * s :, N * s :] + reg * np.eye(tr.nz), atol=1e-9)
    assert np.abs(Hs - 2.0 * np.einsum("kri,krj->kij", lin.data["J"], lin.data["J"])).max() > 1e-3


def test_the_sparse_models_row_products_are_the_nlps_jacobian_times_a_step():
    """``SparseQpModel._a_times(lin, d)``, assembled block by block (the dynamics'
    gaps, each stage's rows, the terminal rows), is ``J d`` with ``J`` CasADi's Jacobian
    of the NLP's rows at the linearisation point; with the clearance rows (curved)."""
    tr, model, p, w, lin = sparse_clearance_point(accel=False)
    J = np.asarray(ca.Function("J", [tr.w, tr.p], [ca.jacobian(tr.g, tr.w)])(w, p))
    d = np.random.default_rng(11).normal(size=w.size)
    np.testing.assert_allclose(model._a_times(lin, d), J @ d, atol=1e-9, rtol=1e-9)
    lam = np.random.default_rng(12).normal(size=J.shape[0])
    np.testing.assert_allclose(model._at_lam(lin, lam), J.T @ lam, atol=1e-9, rtol=1e-9)
    lbw, ubw = tr.variable_bounds(p)  # the iterate returned is clipped to them
    far = w + 50.0 * np.sign(np.random.default_rng(13).normal(size=w.size))
    assert np.isfinite(lbw).any() and np.isfinite(ubw).any()
    np.testing.assert_array_equal(model.result(far, p, lam, d)[0], np.clip(far, lbw, ubw))
    res = model._qp(model.qp, lin, *model._hessian_blocks(lin, np.zeros(J.shape[0]), p, False))
    assert res.ok and res.status == ""  # HPIPM's answer, checked with these products


@pytest.mark.parametrize("where", ["row upper", "row lower", "bound upper", "bound lower"])
@pytest.mark.parametrize(("excess", "ok"), [(0.95, True), (1.05, False)])
def test_the_sparse_models_qp_answer_is_checked_to_its_tolerance(where, excess, ok):
    """``SparseQpModel._solved``: HPIPM's answer is accepted only if it keeps the
    linearised rows and the bounds to ``QP_FEASIBILITY (1 + |d|)``; here a step of 0.25
    crosses one of them by ``excess`` times that (1.25e-6). A step that is not finite is
    refused as such."""
    model = object.__new__(SparseQpModel)
    A = np.array([[1.0, 0.0], [0.0, 1.0]])
    model._a_times = lambda lin, d: A @ d
    far = np.full(2, 9.0)
    lin = SimpleNamespace(c=np.zeros(2), lbc=-far, ubc=far.copy(),
                          data={"v": np.zeros(2), "lbw": -far, "ubw": far.copy()})  # fmt: skip
    sign = 1.0 if where.endswith("upper") else -1.0
    if where.startswith("row"):
        (lin.ubc if sign > 0 else lin.lbc)[0] = 0.25 * sign
    else:
        (lin.data["ubw"] if sign > 0 else lin.data["lbw"])[1] = 0.25 * sign
    step = np.zeros(2)
    step[0 if where.startswith("row") else 1] = sign * (0.25 + excess * 1e-6 * 1.25)
    assert model._solved(lin, step) == (
        (True, "") if ok else (False, "infeasible or not converged")
    )
    assert model._solved(lin, np.array([np.nan, 0.0])) == (False, "not finite")


def test_the_sparse_kkt_error_is_the_largest_part_and_ignores_pinned_variables():
    """Row complementarity, free variables' bound complementarity and stationarity, each
    made the largest in turn; a pinned variable (``lbw = ubw``, e.g. the measured state)
    carries any multiplier: neither its stationarity nor its complementarity counts."""
    model = object.__new__(SparseQpModel)
    model._at_lam = lambda lin, lam: np.array([lam[0], 0.0])  # one row: on variable 0

    def kkt(c, lam_c, v0, lam_v0, grad0):
        # variable 1 is pinned at 0 with a stationarity residual of 5: never counted
        lin = SimpleNamespace(grad=np.array([grad0, 5.0]), c=np.array([c]),
                              lbc=np.array([0.0]), ubc=np.array([1.0]),
                              data={"v": np.array([v0, 0.0]), "lbw": np.array([-1.0, 0.0]),
                                    "ubw": np.array([1.0, 0.0])})  # fmt: skip
        lam_v = np.array([lam_v0, 0.0])
        return model.kkt_error(lin.data["v"], lin, np.array([lam_c]), lam_v)

    assert kkt(0.5, 2.0, 0.0, 0.0, -2.0) == pytest.approx(1.0)  # row: 2 x 0.5 from its top
    assert kkt(1.0, 0.0, 0.25, -3.0, 3.0) == pytest.approx(3.75)  # bound: 3 x 1.25
    assert kkt(1.0, 0.0, 0.0, 0.0, 0.125) == pytest.approx(0.125)  # stationarity


@pytest.mark.parametrize("opts", [{"hessian": "gauss-newton"}, {"rti": True}])
def test_the_sparse_model_builds_no_exact_hessian_it_will_not_use(opts):
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 2, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0)
    base = {"codegen": False, "qpsol": "hpipm", "seed": "none"}
    model = Weighted(pb, "sqp", {**base, **opts}).solvers[0].backend.model
    assert model.f_hess is None and model.t_hess is None
    assert Weighted(pb, "sqp", base).solvers[0].backend.model.f_hess is not None


@pytest.mark.parametrize("mode", ["stagewise", "strict", "residual"])
def test_hpipm_solves_a_hierarchy_as_ipopt_does(mode):
    """Each mode the sparse model takes (the higher level's rows per stage: its cost
    (``stagewise``) or its residuals (``strict``, ``residual``)): each level's optimal cost
    as IPOPT's on the same NLPs. (Without the cost rows' Gauss-Newton curvature in its
    Hessian the stagewise lower level ran to the iteration limit.)"""
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 4, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0, level=0)
    pb.add_task(CogAlignment(), weight=1.0, level=1)
    pb.add_task(ControlRate(), weight=0.1, level=None)
    opts = {"codegen": False, "qpsol": "hpipm", "seed": "none", "tol": 1e-9}
    hp = Hierarchical(pb, mode=mode, backend="sqp", options=opts)
    tr = hp.transcription
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    w0 = tr.pack(*rest(pb), np.zeros(7))
    assert type(hp.solvers[1].backend.model).__name__ == "SparseQpModel"
    got = hp.solve(p, [w0, None])
    ref = Hierarchical(pb, mode=mode, backend="ipopt").solve(p, [w0, None])
    assert got.success and ref.success and got.status == ref.status == "ok"
    for mine, theirs in zip(got.levels, ref.levels, strict=True):
        assert mine.cost == pytest.approx(theirs.cost, rel=1e-4, abs=1e-9)
    # 50 is the limit; 15 before indefinite exact blocks were reflected (18 since)
    assert got.levels[1].iterations <= 20


def test_the_sparse_gauss_newton_blocks_carry_the_stagewise_cost_rows_curvature():
    """Gauss-Newton blocks: ``2 J'J`` plus, per higher-level cost row ``|r_j|^2`` of the
    stage, ``2 max(lam_j, 0) J_j' J_j`` with ``J_j`` CasADi's Jacobian of the
    transcription's residuals ``r_j`` in that stage's variables (random multipliers); the
    third level of three, so two cost rows a stage (one bilinear in the state and the
    command), after the clearance rows."""
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 3, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0, level=0)
    pb.add_task(CogVelocity(), weight=1.0, level=1)  # its rows' curvature depends on u
    pb.add_task(Posture(["q2"], [0.3]), weight=1.0, level=2)
    pb.add_task(ControlRate(), weight=0.1, level=None)
    pb.add_constraint(Clearance(0.1))  # path rows before the cost rows in each stage
    opts = {"codegen": False, "qpsol": "hpipm", "seed": "none"}
    st = Hierarchical(pb, mode="stagewise", backend="sqp", options=opts).solvers[2]
    tr, model = st.tr, st.backend.model
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    U = np.tile([0.1, -0.05, 0.02, 0.1, 0.2, -0.1, 0.1], (pb.horizon, 1))
    w = tr.pack(*rest(pb, U), np.zeros(7))
    model.start(SolveRequest(w, p, tr.lbg, tr.ubg, None, None, True))
    lin = model.linearize(w, p)
    lam = np.random.default_rng(6).normal(size=tr.g.numel())
    Hs, HT = model._hessian_blocks(lin, lam, p, False)
    s, N, reg = tr.stride, tr.N, model.opts["regularization"]
    full = np.zeros((w.size, w.size))
    for row, r in tr.hier_residuals:
        J = np.asarray(ca.Function("J", [tr.w, tr.p], [ca.jacobian(r, tr.w)])(w, p))
        full += 2.0 * max(lam[row], 0.0) * J.T @ J
    assert len(tr.hier_residuals) == 2 * (N + 1) and np.abs(full).max() > 1e-3
    for k in range(N):
        gn = 2.0 * lin.data["J"][k].T @ lin.data["J"][k] + reg * np.eye(s)
        block = full[k * s : (k + 1) * s, k * s : (k + 1) * s]
        np.testing.assert_allclose(Hs[k], gn + block, atol=1e-9, rtol=1e-9)
    gnT = 2.0 * lin.data["JT"].T @ lin.data["JT"] + reg * np.eye(tr.nz)
    np.testing.assert_allclose(HT, gnT + full[N * s :, N * s :], atol=1e-9, rtol=1e-9)


def test_hpipm_refuses_the_hierarchy_mode_that_couples_every_stage():
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 3, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0, level=0)
    pb.add_task(CogAlignment(), weight=1.0, level=1)
    msg = r"^solver_options\.qpsol: hpipm needs stage-wise rows; hierarchy mode 'total' "
    with pytest.raises(ConfigError, match=msg + r"couples every stage \(use qpsol = 'daqp'"):
        Hierarchical(pb, mode="total", backend="sqp", options={"codegen": False, "qpsol": "hpipm"})


@pytest.mark.parametrize(
    ("exact_step", "ok", "kept"),
    [
        ([0.1, -0.2], True, True),  # descends (grad'd = -0.3): the exact step is taken
        ([0.1, -0.2], False, False),  # the exact QP failed
        ([1e3 + 1.0, -2e3], True, False),  # longer than MAX_STEP: an unbounded QP
        ([1e3, -1e3], True, True),  # exactly MAX_STEP long, descending: taken
        ([0.3, 0.2], True, False),  # ascends a little (grad'd = 0.7)
        ([0.2, -0.1], True, True),  # grad'd = 0 exactly: not an ascent
    ],
)
def test_the_sparse_models_exact_step_falls_back_on_gauss_newton(exact_step, ok, kept):
    """``SparseQpModel.step(exact=True)``: where the exact Hessian's QP fails,
    gives a step longer than ``MAX_STEP`` or one that does not descend (``grad'd > 0``),
    the Gauss-Newton QP's step is taken instead; either is moved by the iterate's clipping
    (``lin.data["v"] - v``). The two QPs are stand-ins returning the given steps."""
    model = object.__new__(SparseQpModel)
    model.tr = SimpleNamespace(model=SimpleNamespace(A=np.eye(2), B=np.zeros((2, 0))))
    model._active, model._pivots = (lambda lin, lam_c, lam_v: (None, None, 0.0)), None
    gn_step = np.array([-0.05, 0.01])
    # positive definite stand-in blocks, told apart by their scale: 1 exact, 2 Gauss-Newton
    model._hessian_blocks = lambda lin, lam, p, exact: (
        (1.0 if exact else 2.0) * np.eye(2)[None],
        np.eye(2),
    )
    solvers = []  # the QP solver each QP was given
    model.qp, model.qp_accurate = "loose", "accurate"
    model._qp = lambda qp, lin, Hs, _: (
        solvers.append(qp)
        or (
            QpResult(np.array(exact_step, float), np.zeros(1), np.zeros(2), ok, "" if ok else "x")
            if Hs[0, 0, 0] == 1.0
            else QpResult(gn_step.copy(), np.zeros(1), np.zeros(2), True, "")
        )
    )
    v, clipped = np.array([0.0, 0.0]), np.array([0.01, 0.0])
    lin = SimpleNamespace(grad=np.array([1.0, 2.0]), data={"v": clipped})
    res = model.step(v, lin, np.zeros(1), np.zeros(2), np.zeros(0), True)
    expected = np.array(exact_step, float) if kept else gn_step
    np.testing.assert_array_equal(res.d, expected + clipped - v)
    assert res.ok is (ok or not kept)
    assert solvers == ["loose"] * (1 if kept else 2)
    gn = model.step(v, lin, np.zeros(1), np.zeros(2), np.zeros(0), False)
    np.testing.assert_array_equal(gn.d, gn_step + clipped - v)
    solvers.clear()  # asked for accuracy: every QP of the step by the accurate solver
    model.step(v, lin, np.zeros(1), np.zeros(2), np.zeros(0), True, accurate=True)
    assert solvers == ["accurate"] * (1 if kept else 2)


@pytest.mark.parametrize("solver", ["riccati", "hpipm"])
def test_the_exact_hessian_reaches_the_qp_convexified_on_the_dynamics_null_space(solver):
    """``step`` with the exact Hessian hands the QP the blocks ``reduced_convexified``
    gives for the model's dynamics and the last QP's active rows: an indefinite
    condensed Hessian is changed; an indefinite block whose condensed Hessian is positive
    definite (here: negative curvature in the pinned ``x_0``) goes as it is to the
    Riccati interior point, and reflected (``convexified_blocks``) to HPIPM, whose
    square-root recursion factors every block."""
    model = object.__new__(SparseQpModel)
    A, B = np.eye(2), np.array([[1.0], [0.5]])
    model.tr = SimpleNamespace(model=SimpleNamespace(A=A, B=B))
    model.ns, model.nz = 3, 2
    model._active, model._pivots = (lambda lin, lam_c, lam_v: (None, None, 0.0)), None
    blocks = {"stage": np.diag([-1e-3, 0.5, 2.0])[None], "terminal": np.eye(2)}
    model._hessian_blocks = lambda lin, lam, p, exact: (blocks["stage"], blocks["terminal"])
    seen = []
    model.qp = model.qp_accurate = object.__new__(RiccatiQp) if solver == "riccati" else "qp"
    model._qp = lambda qp, lin, Hs, HT: (
        seen.append((Hs, HT)) or QpResult(np.zeros(3), np.zeros(1), np.zeros(3), True, "")
    )
    lin = SimpleNamespace(grad=np.ones(3), data={"v": np.zeros(3)})
    model.step(np.zeros(3), lin, np.zeros(1), np.zeros(3), np.zeros(0), True)
    if solver == "riccati":
        assert seen[0][0] is blocks["stage"]  # x_0 is pinned: its curvature does not count
    else:
        np.testing.assert_allclose(seen[0][0][0], np.diag([1e-3, 0.5, 2.0]), atol=1e-15)
    seen.clear()  # the command's curvature below what the terminal cost gives back
    blocks["stage"] = np.diag([1.0, 0.5, -3.0])[None]
    model.step(np.zeros(3), lin, np.zeros(1), np.zeros(3), np.zeros(0), True)
    want = reduced_convexified(blocks["stage"], blocks["terminal"], (A, B))
    if solver == "hpipm":
        want = convexified_blocks(*want)
    np.testing.assert_array_equal(seen[0][0], want[0])
    reduced = B.T @ blocks["terminal"] @ B  # B' P B, P the terminal block
    assert -3.0 + reduced[0, 0] < 0.0 < seen[0][0][0, 2, 2] + reduced[0, 0]
