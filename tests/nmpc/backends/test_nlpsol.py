"""The CasADi ``nlpsol`` backends (IPOPT, fatrop): a failed or interrupted solve, the
solver's status and iteration count, warm multipliers, option keys.

Truths: the backend's docstrings; the solver's own stats; Python's SIGINT rules.
"""

from __future__ import annotations

import signal
import threading
import time

import casadi as ca
import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends import SolveRequest
from aeromanip.nmpc.constraints import Bounds
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.strategies import Weighted
from aeromanip.references import Constant
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import EndEffectorTracking
from nmpc_helpers import X0, rest


def test_an_option_key_that_is_not_a_string_is_one_line():
    from aeromanip.nmpc.backends.nlpsol import IpoptBackend

    with pytest.raises(ConfigError, match=r"^solver_options: keys must be strings, got 7$"):
        IpoptBackend.check_options({"ipopt.tol": 1e-6, 7: 1.0})


def _tracking_ipopt():
    """A 3-step tracking problem and its weighted IPOPT backend."""
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, 3, 0.5, Bounds.from_robot(x8))
    pb.add_task(EndEffectorTracking(Constant([0.5, 0.3, 0.6])), weight=10.0)
    return pb, Weighted(pb, "ipopt").solvers[0].backend


@pytest.mark.parametrize(
    ("raised", "status"),
    [
        ("evaluation failed\nat nmpc_ipopt: NaN in f", "at nmpc_ipopt: NaN in f"),
        (
            "Error in Function::call\nevaluation failed\nat nmpc_ipopt: NaN in f",
            "at nmpc_ipopt: NaN in f",
        ),
        ("", "solver error"),
    ],
)
def test_a_solver_that_raises_is_a_failed_solve_with_its_last_line(raised, status):
    """Also with the iterations the solver's stats count and the solve's wall time."""
    pb, backend = _tracking_ipopt()
    tr = backend.tr

    class Raising:
        def __call__(self, **args):
            time.sleep(0.002)
            raise RuntimeError(raised)

        def stats(self):
            return {"iter_count": 4}

    backend.solver = Raising()
    t0 = time.perf_counter()
    res = backend.solve(
        SolveRequest(
            tr.pack(*rest(pb), np.zeros(7)),
            tr.parameters(X0, np.zeros(7), pb.stage_params(0.0)),
            tr.lbg,
            tr.ubg,
        )
    )
    assert (res.success, res.status, res.iterations) == (False, status, 4)
    assert np.isnan(res.w).all() and np.isnan(res.f)
    assert 0.002 <= res.solve_time_s <= time.perf_counter() - t0


@pytest.mark.parametrize("interrupted", [False, True])
def test_an_ipopt_solve_cut_by_ctrl_c_raises_it_again_and_a_solve_reports_its_time(
    interrupted, monkeypatch
):
    """The solver's stats say it was interrupted: the solve raises ``KeyboardInterrupt``
    (Python's own SIGINT handler, main thread); otherwise it reports its wall time."""
    from aeromanip.nmpc.backends import nlpsol
    from aeromanip.nmpc.backends.nlpsol import INTERRUPTED_STATUS

    # Python's own handler, whatever the test runner installed (xdist workers do)
    monkeypatch.setattr(nlpsol.signal, "getsignal", lambda _: nlpsol.signal.default_int_handler)
    pb, backend = _tracking_ipopt()
    tr, solver = backend.tr, backend.solver
    status = INTERRUPTED_STATUS if interrupted else "Solve_Succeeded"

    class Stopped:
        def __call__(self, **args):
            return solver(**args)

        def stats(self):
            return {**solver.stats(), "return_status": status}

    backend.solver = Stopped()
    args = (tr.pack(*rest(pb), np.zeros(7)), tr.parameters(X0, np.zeros(7), pb.stage_params(0.0)))
    t0 = time.perf_counter()
    if interrupted:
        with pytest.raises(KeyboardInterrupt):
            backend.solve(SolveRequest(*args, tr.lbg, tr.ubg))
    else:
        res = backend.solve(SolveRequest(*args, tr.lbg, tr.ubg))
        assert res.success and 0 < res.solve_time_s <= time.perf_counter() - t0


def test_a_solves_iterations_are_the_solvers_count_or_0_where_it_reports_none():
    from aeromanip.nmpc.backends.nlpsol import _iterations

    assert _iterations({"iter_count": 7}) == 7
    assert _iterations({}) == 0


def test_a_solvers_status_is_its_text_or_casadis_name_for_a_number():
    """``nlpsol._status_text``: IPOPT's text as it is; fatrop's number with CasADi's
    unified name; nothing reported is ``unknown``."""
    from aeromanip.nmpc.backends.nlpsol import _status_text

    assert _status_text({"return_status": "Solve_Succeeded"}) == "Solve_Succeeded"
    assert _status_text({}) == "unknown"
    fatrop = {"return_status": 2, "unified_return_status": "SOLVER_RET_INFEASIBLE"}
    assert _status_text(fatrop) == "SOLVER_RET_INFEASIBLE (code 2)"
    assert _status_text({"return_status": 2}) == "SOLVER_RET_UNKNOWN (code 2)"


def test_a_solve_cut_by_casadi_catching_ctrl_c_raises_it_again_only_where_python_would(
    monkeypatch,
):
    """``nlpsol._reraise_interrupt``: in the main thread with Python's own SIGINT handler
    the swallowed Ctrl-C becomes a ``KeyboardInterrupt``; with another handler (the
    CLI's, which defers the signal) or in another thread it does not."""
    from aeromanip.nmpc.backends import nlpsol

    handlers = {signal.SIGINT: signal.default_int_handler}  # SIGINT's is what is asked
    monkeypatch.setattr(nlpsol.signal, "getsignal", handlers.get)
    with pytest.raises(KeyboardInterrupt):
        nlpsol._reraise_interrupt()
    raised = []

    def in_thread():
        try:
            nlpsol._reraise_interrupt()
        except KeyboardInterrupt:
            raised.append(True)

    worker = threading.Thread(target=in_thread)
    worker.start()
    worker.join()
    assert raised == []
    handlers[signal.SIGINT] = lambda *a: None
    nlpsol._reraise_interrupt()  # another handler: nothing raised


def test_a_warm_ipopt_solve_starts_from_the_multipliers_moved_a_stage_on_by_default():
    """The same for IPOPT: ``lam_g0``/``lam_x0`` reach it as ``lam[shift_g]``/``[shift_w]``."""
    pb, backend = _tracking_ipopt()
    tr, given = backend.tr, []

    class Recording:  # the solver, recording what it is given
        def __init__(self, solver):
            self.solver, self.stats = solver, solver.stats

        def __call__(self, **args):
            given.append(args)
            return self.solver(**args)

    backend.solver = Recording(backend.solver)
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    first = backend.solve(SolveRequest(tr.pack(*rest(pb), np.zeros(7)), p, tr.lbg, tr.ubg))
    backend.solve(SolveRequest(first.w, p, tr.lbg, tr.ubg, first.lam_g, first.lam_x))
    np.testing.assert_array_equal(given[1]["lam_g0"], first.lam_g[tr.shift_g])
    np.testing.assert_array_equal(given[1]["lam_x0"], first.lam_x[tr.shift_w])
    backend.solve(SolveRequest(first.w, p, tr.lbg, tr.ubg, first.lam_g, first.lam_x, shift=False))
    np.testing.assert_array_equal(given[2]["lam_g0"], first.lam_g)  # this step's: as given
    np.testing.assert_array_equal(given[2]["lam_x0"], first.lam_x)


def test_a_successful_solve_reports_the_nlps_cost_and_rows_at_its_answer():
    """``f`` is the NLP's objective at the answer ``w`` and the answer keeps its rows and
    bounds (evaluated here with the transcription's own expressions)."""
    pb, backend = _tracking_ipopt()
    tr = backend.tr
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))
    res = backend.solve(SolveRequest(tr.pack(*rest(pb), np.zeros(7)), p, tr.lbg, tr.ubg))
    f, g = (np.asarray(v).ravel() for v in ca.Function("fg", [tr.w, tr.p], [tr.f, tr.g])(res.w, p))
    assert res.success and res.status == "Solve_Succeeded"
    assert res.f == pytest.approx(float(f[0]), rel=1e-12) and res.f > 0.0
    assert np.all(g >= tr.lbg - 1e-8) and np.all(g <= tr.ubg + 1e-8)
    lbw, ubw = tr.variable_bounds(p)
    assert np.all(res.w >= lbw - 1e-8) and np.all(res.w <= ubw + 1e-8)
