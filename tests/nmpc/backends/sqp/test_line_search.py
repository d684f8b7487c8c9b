"""The SQP's line search: the l1 merit's sufficient decrease, the second-order
correction (condensed and sparse models), the damping after short steps.
"""

from __future__ import annotations

from types import SimpleNamespace

import casadi as ca
import numpy as np
import pytest

from aeromanip.nmpc.backends import SolveRequest
from aeromanip.nmpc.backends.sqp.dense_qp import QpResult
from aeromanip.nmpc.backends.sqp.solver import (
    MAX_SOC,
    SOC_MIN_RISE,
    _damping,
    _line_search,
)
from aeromanip.nmpc.backends.sqp.sparse_qp import SparseQpModel
from aeromanip.nmpc.constraints import Bounds, UserConstraint
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.strategies import Weighted
from aeromanip.references import Constant
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import ControlRate, EndEffectorTracking
from nmpc_helpers import X0, rest


def test_the_second_order_correction_solves_the_last_qp_with_rows_taken_at_the_full_step():
    """``CondensedQpModel.correction``: the last QP (its Hessian and gradient) with each row's
    value taken at ``v + d`` less its linear part, ``c(v + d) - A d``, checked against
    CasADi's qrqp on that QP built here; near a solution whose curved row (the end
    effector's horizontal reach) binds, the corrected step leaves it far less than the
    plain one (second order)."""
    _, model, p, v, lin, lam_c, lam_v = _near_a_binding_reach("daqp")
    d = model.step(v, lin, lam_c, lam_v, p, False).d
    soc = model.correction(v, d, lin, p)
    assert soc.ok and np.count_nonzero(soc.lam_a) > 0  # the corrected rows bind
    A = lin.data[1]
    c = model.merit_f(v + d, p)[1] - A @ d
    H = model._last_H
    qp = ca.conic("soc", "qrqp", {"h": ca.DM(H).sparsity(), "a": ca.DM(A).sparsity()},
                  {"print_iter": False, "print_header": False, "print_info": False})  # fmt: skip
    ref = qp(h=H, g=lin.grad, a=A, lba=lin.lbc - c, uba=lin.ubc - c,
             lbx=model.lbU - v, ubx=model.ubU - v)  # fmt: skip
    np.testing.assert_allclose(soc.d, np.asarray(ref["x"]).ravel(), atol=1e-6)
    plain = model.merit(v + d, p)[1]
    assert plain > 1e-4 and model.merit(v + soc.d, p)[1] < 0.2 * plain


def test_the_sparse_models_correction_solves_the_last_qp_with_rows_taken_at_the_full_step():
    """``SparseQpModel.correction`` (HPIPM), as the condensed one: the last QP (its
    Hessian blocks, the NLP's gradient) with the rows ``g(v + d) - A d``, where ``g`` and
    ``A`` come from CasADi on the whole NLP (not the model's stage Functions), checked
    against qrqp on that QP assembled here (a row of the commands among them); the
    corrected step leaves the curved row (the end effector's reach) far less than the
    plain one."""
    speed = UserConstraint("speed", lambda st: ca.sumsqr(st.u[:3]), 0.0, 4.0, uses_command=True)
    tr, model, p, v, lin, lam_c, lam_v = _near_a_binding_reach("hpipm", speed)
    assert isinstance(model, SparseQpModel)
    d = model.step(v, lin, lam_c, lam_v, p, False).d
    soc = model.correction(v, d, lin, p)
    reach = (tr.lbg == 0.0) & (tr.ubg == 0.2**2)
    assert soc.ok and np.abs(soc.lam_a[reach]).max() > 0  # the corrected reach binds
    base = lin.data["v"]  # the iterate clipped into the variable bounds (stage 0 pinned)
    rows = ca.Function("rows", [tr.w, tr.p], [tr.g, ca.jacobian(tr.g, tr.w)])
    A = np.asarray(rows(base, p)[1])
    step = v + d - base
    c = np.asarray(rows(base + step, p)[0]).ravel() - A @ step
    Hs, HT = model._last_qp[1]
    H = np.zeros((tr.w.numel(),) * 2)
    for k, block in enumerate([*Hs, HT]):
        i = k * model.ns
        H[i : i + block.shape[0], i : i + block.shape[0]] = block
    lbw, ubw = tr.variable_bounds(p)
    qp = ca.conic("soc", "qrqp", {"h": ca.DM(H).sparsity(), "a": ca.DM(A).sparsity()},
                  {"print_iter": False, "print_header": False, "print_info": False})  # fmt: skip
    ref = qp(h=H, g=lin.grad, a=A, lba=tr.lbg - c, uba=tr.ubg - c, lbx=lbw - base,
             ubx=ubw - base)  # fmt: skip
    np.testing.assert_allclose(soc.d, np.asarray(ref["x"]).ravel() + base - v, atol=1e-6)
    plain = model.merit(v + d, p)[1]
    assert plain > 1e-4 and model.merit(v + soc.d, p)[1] < 0.2 * plain


class MeritLine:
    """A stand-in QP model along one direction ``d`` from ``v = 0``: ``merit`` at the
    trial ``alpha d`` is ``table[alpha]`` (cost, violation); an optional second-order
    correction returns ``soc``."""

    def __init__(self, table, soc=None):
        self.table, self.soc, self.tried = table, soc, []
        if soc is not None:
            self.correction = lambda v, d, lin, p: soc

    def merit(self, w, p):
        alpha = round(float(w[0]) / 2.0, 12)  # d = [2.0]
        self.tried.append(alpha)
        if alpha not in self.table:
            return 1e9, 0.0
        return self.table[alpha]


def search(model, viol0=0.0, mu=10.0, grad=-3.0, max_soc=MAX_SOC, counted=None, min_rise=0.0):
    """``_line_search`` from cost 5 and row violation ``viol0`` along ``d = [2]``: the
    merit is ``phi0 = 5 + mu viol0``, its slope ``2 grad - mu viol0``. The step length
    and the corrected step; the count of corrections appended to ``counted``."""
    lin = SimpleNamespace(f=5.0, grad=np.array([grad]), c=np.array([viol0]),
                          lbc=np.array([-1.0]), ubc=np.array([0.0]))  # fmt: skip
    alpha, soc, solved = _line_search(
        model, np.zeros(1), np.array([2.0]), None, lin, mu, max_soc, min_rise
    )
    if counted is not None:
        counted.append(solved)
    return alpha, soc


def test_the_line_search_takes_the_first_step_with_sufficient_decrease_of_the_merit():
    """Armijo on the l1 merit ``f + mu viol``: a trial ``alpha`` is taken when its merit
    is at most ``phi0 + 1e-4 alpha min(slope, 0)``, the slope being ``grad'd - mu viol0``;
    halving from 1 down to below 1e-3. Each case sits on one side of that line."""
    slope = 2 * -3.0 - 10.0 * 0.5
    phi0 = 5.0 + 10.0 * 0.5
    edge = phi0 + 1e-4 * 1.0 * slope  # the full step's threshold, exactly
    assert search(MeritLine({1.0: (edge, 0.0)}), viol0=0.5) == (1.0, None)
    # just short of it (by less than the slope's share would move it): rejected
    short = MeritLine({1.0: (edge + 1e-9, 0.0), 0.5: (phi0 - 1.0, 0.0)})
    assert search(short, viol0=0.5) == (0.5, None) and short.tried == [1.0, 0.5]
    # the violation at the trial counts with mu: 0.1 x 10 more than the cost's decrease
    assert search(MeritLine({1.0: (phi0 - 0.5, 0.1), 0.5: (1.0, 0.0)}), viol0=0.5)[0] == 0.5
    # at 0.5 the threshold is phi0 + 1e-4 x 0.5 x slope
    half = phi0 + 1e-4 * 0.5 * slope
    assert search(MeritLine({1.0: (phi0, 0.0), 0.5: (half, 0.0)}), viol0=0.5)[0] == 0.5
    assert search(MeritLine({1.0: (phi0, 0.0), 0.5: (half + 1e-9, 0.0),
                             0.25: (0.0, 0.0)}), viol0=0.5)[0] == 0.25  # fmt: skip
    # an ascent direction (slope > 0): no increase allowed at all
    assert search(MeritLine({1.0: (5.0 + 1e-6, 0.0), 0.5: (4.0, 0.0)}), grad=1.0)[0] == 0.5
    # nothing accepted: halved until below 1e-3, the shortest step taken as it is
    none = MeritLine({})
    assert search(none)[0] == 0.5**10 and none.tried == [0.5**k for k in range(11)]


def test_the_line_search_takes_a_corrected_full_step_only_if_the_correction_solved():
    """The full step rejected with its rows' violation raised, a model's second-order
    correction is tried as a full step (and returned with it); a correction whose QP
    failed is not used."""
    good = QpResult(np.array([1.9]), np.zeros(1), np.zeros(1), True, "")
    table = {1.0: (40.0, 1.0), 0.95: (1.0, 0.0), 0.5: (2.0, 0.0)}  # 1.9 = 0.95 d
    assert search(MeritLine(table, soc=good)) == (1.0, good)
    failed = QpResult(np.array([1.9]), np.zeros(1), np.zeros(1), False, "x")
    assert search(MeritLine(table, soc=failed)) == (0.5, None)
    # judged as a full step: threshold 5 + 1e-4 x 1 x (-6)
    near = {1.0: (40.0, 1.0), 0.95: (5.0 - 8e-4, 0.0), 0.5: (2.0, 0.0)}
    assert search(MeritLine(near, soc=good)) == (1.0, good)
    above = {1.0: (40.0, 1.0), 0.95: (5.0 - 6e-4 + 1e-9, 0.0), 0.5: (2.0, 0.0)}
    assert search(MeritLine(above, soc=good)) == (0.5, None)


def test_the_line_search_corrects_only_a_full_step_that_raised_the_violation():
    """IPOPT's rule: a full step rejected for its cost alone (the rows' violation not
    above the current one) is not corrected, only shortened; one whose violation rose
    is, by any amount (a bounded solve's: beyond rounding's, ``SOC_MIN_RISE``). The
    corrections tried are counted."""
    good = QpResult(np.array([1.9]), np.zeros(1), np.zeros(1), True, "")

    def tried(viol0, viol_full, min_rise=0.0):
        model = MeritLine({1.0: (50.0, viol_full), 0.95: (0.0, 0.0), 0.5: (0.0, 0.0)})
        calls, counted = [], []
        model.correction = lambda v, d, lin, p: calls.append(d) or good
        alpha, soc = search(model, viol0=viol0, counted=counted, min_rise=min_rise)
        assert counted == [len(calls)]
        return len(calls), alpha, soc

    assert tried(0.0, 0.0) == (0, 0.5, None)  # the cost alone rejected it
    assert tried(0.5, 0.5) == (0, 0.5, None)  # violation as before: not raised
    assert tried(0.5, 0.4) == (0, 0.5, None)  # lowered
    assert tried(0.5, 0.5 + 1e-15) == (1, 1.0, good)  # raised, however little
    assert tried(0.0, 1e-15) == (1, 1.0, good)
    bounded = SOC_MIN_RISE
    assert tried(0.5, 0.5 + 2 * bounded, bounded) == (1, 1.0, good)
    assert tried(0.0, 2 * bounded, bounded) == (1, 1.0, good)
    assert tried(0.0, bounded / 2, bounded) == (0, 0.5, None)  # rounding: not raised
    assert tried(0.5, 0.5 + bounded / 2, bounded) == (0, 0.5, None)


@pytest.mark.parametrize("max_soc", [0, 1, 3, MAX_SOC])
def test_corrections_in_a_row_stop_at_max_soc_and_are_counted(max_soc):
    """Each correction cuts the violation (by more than ``KAPPA_SOC``) and is still
    rejected for its cost: the line search tries ``max_soc`` of them (``MAX_SOC`` the
    most; a bounded solve passes what its budget has left), counts them, then backtracks."""
    alphas = [0.95, 0.9, 0.85, 0.8, 0.75, 0.7]  # the corrected steps / d
    assert len(alphas) > MAX_SOC
    table = {1.0: (50.0, 1.0), 0.5: (0.0, 0.0)}
    table.update({a: (50.0, 0.9 - 0.1 * k) for k, a in enumerate(alphas)})
    model = MeritLine(table)
    corrections = iter(alphas)
    model.correction = lambda v, d, lin, p: QpResult(
        np.array([2.0 * next(corrections)]), np.zeros(1), np.zeros(1), True, ""
    )
    counted = []
    assert search(model, viol0=0.5, max_soc=max_soc, counted=counted) == (0.5, None)
    assert counted == [max_soc]
    assert model.tried == [1.0, *alphas[:max_soc], 0.5]


def test_where_a_correction_is_a_whole_solve_it_is_tried_only_if_it_may_turn_the_trial():
    """A model whose correction is a whole QP solve (``correction_is_a_solve``: the
    sparse model's interior point) tries one only while the rows' rise over the
    iterate's violation (times ``mu``) is at least what the trial misses the acceptance
    level by otherwise: a correction moves the rows, not the cost. The other models keep
    IPOPT's rule (any rise). From cost 5 and violation 0.5 (``mu`` 10), the level is
    ``10 - 1.1e-3``."""
    good = QpResult(np.array([1.9]), np.zeros(1), np.zeros(1), True, "")

    def tried(full, solve_each, then=(0.0, 0.0)):
        model = MeritLine({1.0: full, 0.95: then, 0.5: (0.0, 0.0)})
        model.correction_is_a_solve = solve_each
        calls, counted = [], []
        model.correction = lambda v, d, lin, p: calls.append(d) or good
        search(model, viol0=0.5, counted=counted)
        return len(calls)

    # rise 10 x (1.0 - 0.5) = 5; missed otherwise by 50 + 5 - 10: the cost rejected it
    assert tried((50.0, 1.0), True) == 0
    assert tried((50.0, 1.0), False) == 1
    # missed otherwise by 5.1 + 5 - 10 = 0.1 < 5: the rows' rise rejected it
    assert tried((5.1, 1.0), True) == 1
    # at the edge: a cost at the level misses it otherwise by the rise exactly
    level = 10.0 + 1e-4 * (2 * -3.0 - 10.0 * 0.5)
    assert tried((level, 1.0), True) == 1
    assert tried((level + 0.01, 1.0), True) == 0  # misses by 5.01


def test_where_a_correction_is_a_whole_solve_the_next_is_tried_only_if_it_may_turn_it():
    """After a correction that cut the rows' violation but left the trial rejected by its
    cost, a model whose corrections are whole solves stops (then backtracks); the
    others go on while each cuts the violation by ``KAPPA_SOC``, up to ``MAX_SOC``."""
    alphas = [0.95, 0.9, 0.85, 0.8]
    table = {1.0: (5.1, 1.0), 0.5: (0.0, 0.0)}  # the full step: its rows' rise rejected it
    table.update({a: (50.0, 0.9 - 0.1 * k) for k, a in enumerate(alphas)})  # then the cost

    def tried(solve_each):
        model = MeritLine(table)
        model.correction_is_a_solve = solve_each
        corrections = iter(alphas)
        model.correction = lambda v, d, lin, p: QpResult(
            np.array([2.0 * next(corrections)]), np.zeros(1), np.zeros(1), True, ""
        )
        counted = []
        assert search(model, viol0=0.5, counted=counted) == (0.5, None)
        return counted[0]

    assert tried(True) == 1
    assert tried(False) == MAX_SOC


def test_the_damping_grows_tenfold_after_a_short_step_and_fades_after_full_ones():
    """Levenberg-Marquardt damping: from 0 to 1e-3 at the first shortened step, x10 at
    each next one; /10 after a full step, back to 0 once below 1e-3."""
    assert _damping(0.0, 1.0) == 0.0
    assert _damping(0.0, 0.5) == 1e-3
    assert _damping(1e-3, 0.25) == pytest.approx(1e-2)
    assert _damping(1e-2, 1.0) == pytest.approx(1e-3)  # exactly the floor: kept
    assert _damping(1e-3 * 10.0, 1.0) >= 1e-3
    assert _damping(5e-3, 1.0) == 0.0  # 5e-4 < 1e-3


def _near_a_binding_reach(qpsol: str, *constraints: UserConstraint) -> tuple:
    """The end effector tracked toward a target beyond its reach limit (a curved row
    that binds), solved by the SQP on ``qpsol``'s QP, and an iterate 0.02 (normal noise)
    from that solution, linearised: ``tr, model, p, v, lin, lam_c, lam_v``."""
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 3, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.6, 0.4, 0.3])), weight=10.0)
    pb.add_task(ControlRate(), weight=0.1, level=None)
    for c in (UserConstraint("ee_near", _reach_squared, 0.0, 0.2**2), *constraints):
        pb.add_constraint(c)
    strat = Weighted(pb, "sqp", {"codegen": False, "qpsol": qpsol, "seed": "none"})
    tr, backend = strat.transcription, strat.solvers[0].backend
    model = backend.model
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    sol = backend.solve(SolveRequest(tr.pack(*rest(pb), np.zeros(7)), p, tr.lbg, tr.ubg))
    assert sol.success
    v, lam_c, lam_v = model.start(
        SolveRequest(sol.w, p, tr.lbg, tr.ubg, sol.lam_g, sol.lam_x, False)
    )
    v = v + 0.02 * np.random.default_rng(1).normal(size=v.size)  # near the solution
    return tr, model, p, v, model.linearize(v, p), lam_c, lam_v


def _reach_squared(st):
    """The end effector's horizontal distance from the origin, squared [m^2]."""
    ee = st.kin.ee_position(st.x)
    return ee[0] ** 2 + ee[1] ** 2
