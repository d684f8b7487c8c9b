"""The condensed (dense) QP model of the SQP backend: its Hessian (Gauss-Newton with the
hierarchy rows' curvature, exact by finite differences, convexified), damping, start, KKT
error and state rows."""

import numpy as np
import pytest

from aeromanip.nmpc.backends import SolveRequest
from aeromanip.nmpc.strategies import Hierarchical, Weighted
from nmpc_helpers import FAST, X0, make_problem


# -- the dense (condensed) model's Hessian, its damping and its KKT error ----------------------
@pytest.fixture(scope="module")
def stagewise_level():
    """Level 1 of a stagewise hierarchy (each stage's tracking cost a row: curved rows
    whose Gauss-Newton curvature the model adds), its model, ``v`` and ``p``."""
    h = Hierarchical(make_problem(horizon=4), mode="stagewise", backend="sqp", options=FAST)
    model = h.solvers[1].backend.model
    tr = model.tr
    p = tr.parameters(X0, np.zeros(7), h.problem.stage_params(0.0))
    U = np.tile([0.05, -0.02, 0.01, 0.1, 0.1, -0.1, 0.05], (tr.N, 1))
    w = tr.pack(X0 + np.vstack([np.zeros(7), np.cumsum(0.5 * U, axis=0)]), U, np.zeros(7))
    v, _, _ = model.start(SolveRequest(w, p, tr.lbg, tr.ubg, None, None, True))
    return model, v, p


def test_the_dense_gauss_newton_hessian_adds_each_hierarchy_rows_curvature(stagewise_level):
    """``2 J'J`` plus, for each stage row ``c = sum_e r_e^2`` of the level above with a
    multiplier ``lam > 0`` (a row bounded above), ``2 lam sum_e grad r_e grad r_e'``: summed
    here element by element, each element's row found from the transcription."""
    model, v, p = stagewise_level
    assert model.nh > 0
    lin = model.linearize(v, p)
    J, A, Jh = lin.data
    lam_c = np.random.default_rng(2).normal(size=model.nc)  # both signs: lam < 0 adds none
    expected = 2.0 * J.T @ J
    grads = Jh.reshape(model.nh, model.nU, order="F")
    e = 0
    for row, r in model.tr.hier_residuals:
        lam = lam_c[list(model.keep).index(row)]
        for _ in range(r.numel()):
            expected += 2.0 * max(lam, 0.0) * np.outer(grads[e], grads[e])
            e += 1
    assert e == model.nh
    np.testing.assert_allclose(model._hessian(J, Jh, None, lam_c, np.zeros(model.nU), A),
                               expected, rtol=1e-12, atol=1e-12)  # fmt: skip
    # step(): Gauss-Newton unless asked (the exact Hessian exists), plus the
    # regularisation and ``damping`` times the largest diagonal entry
    reg = model.opts["regularization"]
    for damping in (0.0, 0.5):
        model.step(v, lin, lam_c, np.zeros(model.nU), p, False, damping)
        shift = reg + damping * float(np.diag(expected).max())
        np.testing.assert_allclose(model._last_H, expected + shift * np.eye(model.nU),
                                   rtol=1e-12, atol=1e-12)  # fmt: skip


def test_the_dense_models_start_takes_clips_and_shifts_what_it_is_given(stagewise_level):
    """``start``: the commands of ``w0`` clipped to their bounds (both sides); the NLP's
    multipliers of the kept rows, the states' bounds and the commands' bounds, only when
    both vectors are given, moved a stage on with the QP's memory on a shifted start (a
    command's from the next stage, the last stage's its own), forgotten on a cold one."""
    model, _, p = stagewise_level
    tr, nx, nU = model.tr, model.tr.nx, model.nU
    rng = np.random.default_rng(4)
    w0 = np.zeros(tr.w.numel())
    w0[model.u_idx] = rng.uniform(-3.0, 3.0, nU)  # the command bounds are +-1 (m/s, rad/s)
    lam_g, lam_x = rng.normal(size=tr.g.numel()), rng.normal(size=tr.w.numel())
    U, lam_c, lam_u = model.start(SolveRequest(w0, p, tr.lbg, tr.ubg, lam_g, lam_x, False))
    np.testing.assert_array_equal(U, np.clip(w0[model.u_idx], model.lbU, model.ubU))
    assert U.min() == model.lbU.min() and U.max() == model.ubU.max()
    np.testing.assert_array_equal(lam_c, np.r_[lam_g[model.keep], lam_x[model.state_idx]])
    np.testing.assert_array_equal(lam_u, lam_x[model.u_idx])
    model.qp.lam_a[:] = lam_c
    _, shifted_c, shifted_u = model.start(SolveRequest(w0, p, tr.lbg, tr.ubg, lam_g, lam_x, True))
    np.testing.assert_array_equal(shifted_c, lam_c[model.qp.shift_rows])
    np.testing.assert_array_equal(model.qp.lam_a, lam_c[model.qp.shift_rows])
    np.testing.assert_array_equal(shifted_u, np.r_[lam_u[nx:], lam_u[-nx:]])
    for only in ((lam_g, None), (None, lam_x)):  # one of the two: none used
        _, c, u = model.start(SolveRequest(w0, p, tr.lbg, tr.ubg, *only, False))
        assert not c.any() and not u.any()
    assert not model.qp.lam_a.any()  # the cold start (no row multipliers) forgot them
    # the hierarchy's rows bind by design: in every QP's first round
    hier = [list(model.keep).index(r) for rows in tr.hier_rows for r in rows]
    assert hier and model.qp.always[hier].all() and model.qp.always.sum() == len(hier)


def test_the_dense_exact_hessian_is_the_lagrangians_by_finite_differences(stagewise_level):
    """``hess(v, p, lam)``: the Hessian in the commands of ``f + lam' c`` (the cost and
    the kept rows, the hierarchy's curved ones and the clearance among them), against
    central differences of the gradient ``grad f + A' lam`` that ``linearize`` gives."""
    model, v, p = stagewise_level
    lam = np.random.default_rng(8).normal(size=model.nc)
    H = np.asarray(model.hess(v, p, lam)[0]).reshape(model.nU, model.nU, order="F")

    def grad_l(u):
        lin = model.linearize(u, p)
        return lin.grad + lin.data[1].T @ lam

    h = 1e-6
    fd = np.column_stack(
        [(grad_l(v + h * e) - grad_l(v - h * e)) / (2 * h) for e in np.eye(model.nU)]
    )
    assert np.abs(H).max() > 1.0
    np.testing.assert_allclose(H, fd, rtol=0, atol=1e-6 * np.abs(H).max())


def test_the_exact_hessian_is_made_convex_on_the_bounds_with_multipliers(
    stagewise_level, monkeypatch
):
    """An exact Hessian with negative curvature along command ``j``, whose bound has a
    multiplier (no row has): ``convexify.convexified``'s penalty on that variable, the smallest
    of ``1, 10, 100 ...`` times the diagonal's scale that makes it positive definite
    (here 10: ``-1 + 10``), not a penalty elsewhere nor the eigenvalues' reflection."""
    model, v, p = stagewise_level
    n, j = model.nU, 9
    Hf = np.eye(n)
    Hf[j, j] = -1.0
    monkeypatch.setattr(model, "hess", lambda *args: [Hf.ravel(order="F")])
    lam_v = np.zeros(n)
    lam_v[j] = 0.3
    model.step(v, model.linearize(v, p), np.zeros(model.nc), lam_v, p, True)
    expected = np.eye(n)
    expected[j, j] = 9.0
    reg = model.opts["regularization"]
    np.testing.assert_allclose(model._last_H, expected + reg * np.eye(n), rtol=0, atol=1e-12)


def test_damping_adds_its_share_of_the_largest_diagonal_entry(stagewise_level, monkeypatch):
    """Levenberg-Marquardt: ``damping`` times the Hessian's largest *diagonal* entry on
    its diagonal (here off the first row, and smaller than off-diagonal entries)."""
    model, v, p = stagewise_level
    n = model.nU
    H = np.full((n, n), 5.0) + np.diag(np.linspace(1.0, 2.0, n))  # largest diagonal: 7
    H[n // 2, n // 2] = 8.0
    monkeypatch.setattr(model, "_hessian", lambda *args: H.copy())
    model.step(v, model.linearize(v, p), np.zeros(model.nc), np.zeros(n), p, False, 0.25)
    shift = model.opts["regularization"] + 0.25 * 8.0
    np.testing.assert_allclose(model._last_H, H + shift * np.eye(n), rtol=0, atol=1e-12)


def test_the_dense_kkt_error_is_the_largest_of_its_three_parts():
    """Row complementarity, bound complementarity and stationarity, each made the
    largest in turn on a one-variable, one-row stand-in."""
    from aeromanip.nmpc.backends.sqp.condensed_qp import CondensedQpModel
    from aeromanip.nmpc.backends.sqp.qp_model import Linearization

    model = object.__new__(CondensedQpModel)
    model.lbU, model.ubU = np.array([-1.0]), np.array([1.0])
    A = np.array([[1.0]])

    def kkt(c, lam_c, v, lam_v, grad):
        lin = Linearization(0.0, np.array([grad]), np.array([c]), np.array([0.0]),
                            np.array([1.0]), (None, A, None))  # fmt: skip
        return model.kkt_error(np.array([v]), lin, np.array([lam_c]), np.array([lam_v]))

    assert kkt(0.5, 2.0, 0.0, 0.0, -2.0) == pytest.approx(1.0)  # row: 2 x 0.5 from its top
    assert kkt(1.0, 0.0, 0.25, -3.0, 3.0) == pytest.approx(3.75)  # bound: 3 x 1.25
    assert kkt(1.0, 0.0, 0.0, 0.0, 0.125) == pytest.approx(0.125)  # stationarity


def test_the_qp_solvers_own_options_reach_it():
    """``solver_options.qpsol_options`` go to the dense QP solver as given."""
    own = {"daqp": {"primal_tol": 1e-7, "iter_limit": 500}}
    opts = {**FAST, "qpsol": "daqp", "qpsol_options": own}
    model = Weighted(make_problem(horizon=3), "sqp", opts).solvers[0].backend.model
    assert model.qp.opts["daqp"] == own["daqp"]


def test_the_dense_models_state_rows_are_the_bounded_states_after_the_first():
    """States become rows of the commands where they have a bound on either side,
    stages 1 to N (stage 0 is the measured state); here ``x``, ``y``, yaw unbounded, ``z``
    bounded below only. Gauss-Newton only: no exact Hessian is built."""
    pb = make_problem(horizon=3, box={"z": (0.8, np.inf)})
    opts = {**FAST, "qpsol": "daqp", "hessian": "gauss-newton"}
    model = Weighted(pb, "sqp", opts).solvers[0].backend.model
    tr, s, nx = model.tr, model.tr.stride, model.tr.nx
    names = pb.robot.state_names
    bounded = [i for i, n in enumerate(names) if n not in ("x", "y", "yaw")]
    assert names[2] == "z" and 2 in bounded and np.isinf(tr.ubw[s + 2])
    expected = [k * s + i for k in range(1, pb.horizon + 1) for i in bounded]
    np.testing.assert_array_equal(model.state_idx, expected)
    assert model.state_idx.dtype.kind == "i" and nx == len(names)
    assert model.hess is None
