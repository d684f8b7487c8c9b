"""The real-time iteration in compiled C (``sparse_rti``) against the Python loop's on the
same model and QP solver: the same commands, where it applies and where not, and the
Python loop taking over a step whose QP the C did not solve.
"""

from __future__ import annotations

import numpy as np
import pytest

from aeromanip.experiment.scenario import load_scenarios
from aeromanip.nmpc.backends.sqp.hpipm import HPIPM_LIMITS
from aeromanip.nmpc.controller import Controller

pytestmark = pytest.mark.codegen  # the model's Functions and the step are compiled


def _flight(strategy, horizon=20):
    sets = ["sim='kinematic'", f"controller.horizon={horizon}", f"controller.dt={5 / horizon}",
            "controller.weights_dt=0.5", f"controller.strategy='{strategy}'",
            "duration=3"]  # fmt: skip
    return load_scenarios("flight", sets)[""]


def _loop(sc, strategy, options, steps=8, before_step=None):
    hierarchy = sc.hierarchy if strategy == "hierarchical" else None
    ctrl = Controller(sc.problem, strategy, "sqp-rti", options, hierarchy=hierarchy)
    x, U = sc.x0.copy(), []
    for k in range(steps):
        if before_step is not None:
            before_step(ctrl)
        cmd = ctrl.step(x, k * sc.problem.dt)
        assert cmd.status == "ok", cmd.message
        U.append(cmd.u)
        x = x + sc.problem.dt * cmd.u
    return ctrl, np.array(U)


@pytest.mark.parametrize("strategy", ["weighted", "hierarchical"])
def test_the_compiled_rti_commands_as_the_python_loop(strategy, monkeypatch):
    # both loops' QPs to residuals of 1e-8: there the same interior point stops at the
    # same iteration in both (at the RTI's own 1e-7 the last bits of the two
    # linearisations can end it one iteration apart, 4e-9 in the commands)
    monkeypatch.setitem(HPIPM_LIMITS, "rti", (1e-8, HPIPM_LIMITS["rti"][1]))
    sc = _flight(strategy)
    ctrl, compiled = _loop(sc, strategy, {"compiled_loop": True})
    assert all(st.backend.rti is not None for st in ctrl.strategy.solvers)
    ctrl, python = _loop(sc, strategy, {"compiled_loop": False})
    assert all(st.backend.rti is None for st in ctrl.strategy.solvers)
    assert np.abs(python).max() > 0.05  # it flies
    np.testing.assert_allclose(compiled, python, rtol=0, atol=1e-9)


def test_where_the_compiled_rti_does_not_apply_the_python_loop_runs():
    sc = _flight("weighted")
    for backend, options in (("sqp", None), ("sqp-rti", {"qpsol": "hpipm"})):
        ctrl = Controller(sc.problem, "weighted", backend, options)
        assert ctrl.strategy.solvers[0].backend.rti is None, (backend, options)
    stagewise = load_scenarios(
        "flight", ["controller.horizon=20", "controller.hierarchy.mode='stagewise'"]
    )
    sc = stagewise[""]
    ctrl = Controller(sc.problem, "hierarchical", "sqp-rti", None, hierarchy=sc.hierarchy)
    assert ctrl.strategy.solvers[1].backend.rti is None  # its cost rows' curvature


def test_a_step_whose_qp_the_c_did_not_solve_is_the_python_loops():
    """The QP held to one interior-point iteration: the C step reports it unsolved and
    the Python loop takes the step (checking the answer), as it does without the C."""
    sc = _flight("weighted")

    def one_iteration(ctrl):
        for st in ctrl.strategy.solvers:
            st.backend.model.qp.settings[4] = 1.0

    ctrl, compiled = _loop(sc, "weighted", {"compiled_loop": True}, 3, one_iteration)
    _, python = _loop(sc, "weighted", {"compiled_loop": False}, 3, one_iteration)
    assert ctrl.strategy.solvers[0].backend.rti is not None
    np.testing.assert_allclose(compiled, python, rtol=0, atol=1e-12)
