"""The transcription's stage functions against the costs computed here, task by task and
stage by stage: each task sees its own parameters (wherever it stands among the tasks),
the command of its stage (none at the terminal one), the previous command and the
control period.
"""

import casadi as ca
import numpy as np
import pytest

from aeromanip.nmpc.constraints import Bounds
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.transcription import Transcription
from aeromanip.references import Lissajous
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import CogVelocity, ControlRate, EndEffectorTracking, Task

X8 = load_robot("x8-3dof")
DT, N = 0.1, 5


class StepTravel(Task):
    """A user task: the first DoF's travel over the step ``u[0] dt``; at the terminal
    stage, where there is no command, the first DoF itself."""

    name = "step_travel"

    def residual(self, stage):
        if stage.u is None:
            return stage.x[0]
        return stage.u[0] * stage.dt


def test_each_tasks_stage_and_terminal_cost_is_its_formula_at_every_stage():
    ref = Lissajous([0.4, 0.3, 0.5], [0.1, 0.2, 0.05], [0.5, 0.3, 0.2])
    pb = Problem(X8, N, DT, Bounds.from_robot(X8))
    # the task with parameters is not the first: its own slice of each stage's parameters
    pb.add_task(ControlRate(), weight=0.3, terminal_weight=0.7, level=None)
    pb.add_task(EndEffectorTracking(ref), weight=2.0, terminal_weight=5.0)
    pb.add_task(StepTravel(), weight=3.0, terminal_weight=11.0)
    pb.add_task(CogVelocity(), weight=0.0)  # no terminal term, and weighted out here
    # a second task with parameters: the parameters are stage-major, each task its slice
    ref2 = Lissajous([0.2, -0.1, 0.6], [0.05, 0.1, 0.02], [0.7, 0.4, 0.9])
    pb.add_task(EndEffectorTracking(ref2), weight=0.5, terminal_weight=0.25, name="second")
    tr = Transcription(pb, pb.entries)
    rng = np.random.default_rng(4)
    X = rng.uniform(-0.5, 0.5, (N + 1, 7)) + np.array([0, 0, 1, 0, 0.3, 0.4, -0.8])
    U, u_prev, t0 = rng.normal(0, 0.3, (N, 7)), rng.normal(0, 0.3, 7), 1.3
    p = tr.parameters(X[0], u_prev, pb.stage_params(t0))
    costs = tr.costs(tr.pack(X, U, u_prev), p)  # tasks x stages

    x = ca.SX.sym("x", 7)
    ee = ca.Function("ee", [x], [pb.kin.ee_position(x)])  # pinned in test_task_residuals
    targets = ref.sample(t0 + DT * np.arange(N + 1))
    targets2 = ref2.sample(t0 + DT * np.arange(N + 1))
    U_before = np.vstack([u_prev, U])  # the command before each stage
    expected = np.zeros((5, N + 1))
    for k in range(N + 1):
        e = np.asarray(ee(X[k])).ravel() - targets[k]
        e2 = np.asarray(ee(X[k])).ravel() - targets2[k]
        if k < N:
            expected[:, k] = [
                0.3 * np.sum((U[k] - U_before[k]) ** 2),
                2.0 * e @ e,
                3.0 * (U[k, 0] * DT) ** 2,
                0.0,
                0.5 * e2 @ e2,
            ]
        else:  # the terminal terms: the last command, the tracking error, the DoF itself
            expected[:, k] = [
                0.7 * U[-1] @ U[-1],
                5.0 * e @ e,
                11.0 * X[N, 0] ** 2,
                0.0,
                0.25 * e2 @ e2,
            ]
    np.testing.assert_allclose(costs, expected, rtol=1e-12, atol=1e-14)
    # the stacked residuals are the tasks' own rows (none for a task without a terminal
    # term) and their squared norm is the cost
    r = ca.Function("r", [tr.w, tr.p], [tr.residuals])(tr.pack(X, U, u_prev), p)
    assert r.numel() == N * (7 + 3 + 1 + 2 + 3) + (7 + 3 + 1 + 3)
    assert float(ca.sumsqr(r)) == pytest.approx(expected.sum(), rel=1e-12)


def test_a_row_only_the_first_command_moves_is_movable():
    """``g_movable``: the command-rate rows of stage 0, ``u0 - v0``, depend on the measured
    ``v0`` and on ``u0`` alone (``u0``'s x the first decision variable): movable."""
    pb = Problem(X8, N, DT, Bounds.from_robot(X8).with_accel(np.full(7, 2.0)))
    pb.add_task(EndEffectorTracking(Lissajous([0.4, 0.3, 0.5], [0.1] * 3, [0.5] * 3)))
    tr = Transcription(pb, pb.entries)
    kind, stage = np.asarray(tr.g_kind), np.asarray(tr.g_stage)
    first = np.flatnonzero((kind == "accel") & (stage == 0))
    assert len(first) == 7 and tr.g_movable[first].all()


def test_a_packed_plan_starts_where_the_nlp_pins_its_start():
    """With rate responses: ``pack(X, U, u_prev, rates)`` puts at stage 0 the ``z0`` that
    ``parameters`` (and so ``variable_bounds``) pins: the measured rates, not ``u_prev``."""
    tau = np.array([0.3, 0.25, 0.2, 0.08, 0.0, 0.0, 0.01])
    pb = Problem(X8, N, DT, Bounds.from_robot(X8), response_tau=tau)
    pb.add_task(EndEffectorTracking(Lissajous([0.4, 0.3, 0.5], [0.1] * 3, [0.5] * 3)))
    tr = Transcription(pb, pb.entries)
    rng = np.random.default_rng(7)
    X, U = rng.normal(0, 0.3, (N + 1, 7)), rng.normal(0, 0.3, (N, 7))
    u_prev, rates = rng.normal(0, 0.3, 7), rng.normal(0, 0.3, 7)
    w = tr.pack(X, U, u_prev, rates)
    p = tr.parameters(X[0], u_prev, pb.stage_params(0.0), rates)
    lbw, ubw = tr.variable_bounds(p)
    np.testing.assert_array_equal(w[: tr.nz], lbw[: tr.nz])
    np.testing.assert_array_equal(w[: tr.nz], ubw[: tr.nz])
    np.testing.assert_array_equal(w[2 * 7 : tr.nz], rates[tau > 0])
