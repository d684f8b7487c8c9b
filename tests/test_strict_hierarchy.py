"""The strict hierarchy (paper eq. 5): higher levels stay at their optimum, on every backend;
and what the run log reports about it (per-level loss, the exact rho, each point's
clearance)."""

import numpy as np
import pytest

from aeromanip.experiment.closed_loop import simulate
from aeromanip.experiment.scenario import load_scenarios
from aeromanip.nmpc.constraints import Bounds, Clearance
from aeromanip.nmpc.controller import Controller
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.transcription import Transcription
from aeromanip.references import Constant
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import CogAlignment, ControlRate, EndEffectorTracking, Posture

X8 = load_robot("x8-3dof")
X0 = np.array([0.0, 0.0, 1.0, 0.0, 0.3, 0.4, -0.8])
OPTIONS = {
    "ipopt": {"ipopt.tol": 1e-10},
    "fatrop": {"fatrop.tol": 1e-10},
    "sqp": {"codegen": False},
}


def problem(target=(0.5, 0.3, 0.6), horizon=6):
    pb = Problem(X8, horizon, 0.5, Bounds.from_robot(X8, platform_box={"z": (0.5, 2.0)}))
    pb.add_task(EndEffectorTracking(Constant(list(target))), weight=10.0, level=0)
    pb.add_task(CogAlignment(), weight=1.0, level=1)
    pb.add_task(ControlRate(), weight=0.1, terminal_weight=0.5, level=None)
    pb.add_constraint(Clearance(0.1))
    return pb


def cog_cost(pb, X):
    """The CoG task's cost along a plan (weight 1): sum over stages of |cog_xy|^2."""
    return sum(float(np.sum(np.asarray(pb.kin.cog_body(x)).ravel()[:2] ** 2)) for x in X)


def weighted_alone(pb, level_tasks):
    """Level 0's own problem (its tasks and the regulariser), solved by IPOPT: its optimum."""
    alone = Problem(X8, pb.horizon, pb.dt, pb.bounds)
    for e in pb.entries:
        if e.name in level_tasks or e.level is None:
            alone.add_task(e.task, e.weight, e.terminal_weight, level=0, name=e.name)
    alone.constraints = list(pb.constraints)
    return Controller(alone, "weighted", "ipopt", OPTIONS["ipopt"]).step(X0, 0.0)


@pytest.mark.parametrize("backend", ["ipopt", "fatrop", "sqp"])
def test_level_zero_keeps_its_optimum_and_level_one_gains(backend):
    pb = problem()
    cmd = Controller(pb, "hierarchical", backend, OPTIONS[backend]).step(X0, 0.0)
    assert cmd.status == "ok", cmd.message
    lv0, lv1 = cmd.levels
    # the applied plan gives level 0 its optimal cost, to the solver's accuracy ...
    assert abs(lv0.loss) <= 1e-7 * max(lv0.cost, 1e-8)
    assert cmd.task_costs["tracking"] == pytest.approx(lv0.cost, rel=1e-7, abs=1e-12)
    # ... which is level 0's own optimum (an independent IPOPT solve of level 0 alone)
    alone = weighted_alone(pb, {"tracking"})
    assert lv0.objective == pytest.approx(sum(alone.task_costs.values()), rel=1e-6)
    # the tracking residuals are the same at every stage (pinned, not only their sum)
    ee = np.array([np.asarray(pb.kin.ee_position(x)).ravel() for x in cmd.plan_x])
    ee_alone = np.array([np.asarray(pb.kin.ee_position(x)).ravel() for x in alone.plan_x])
    np.testing.assert_allclose(ee, ee_alone, atol=1e-6)
    # level 1 made the CoG offset smaller within what level 0 left free
    assert lv1.gain > 0.1 * cmd.task_costs["cog"]
    assert cog_cost(pb, cmd.plan_x) == pytest.approx(cmd.task_costs["cog"], rel=1e-9)
    assert cog_cost(pb, cmd.plan_x) < 0.9 * cog_cost(pb, alone.plan_x)


def test_the_stagewise_mode_lets_the_lower_level_take_its_tolerance():
    """The paper's relaxed form, for contrast: level 0 loses up to its tolerance."""
    pb = problem()
    strict = Controller(pb, "hierarchical", "ipopt", OPTIONS["ipopt"]).step(X0, 0.0)
    relaxed = Controller(
        pb, "hierarchical", "ipopt", OPTIONS["ipopt"], hierarchy={"mode": "stagewise"}
    ).step(X0, 0.0)
    assert relaxed.levels[0].loss > 1e3 * max(abs(strict.levels[0].loss), 1e-12)
    assert relaxed.task_costs["cog"] < strict.task_costs["cog"]


def test_rows_no_decision_can_move_are_the_stage_zero_rows_without_the_command():
    pb = problem()
    tr = Transcription(pb, [e for e in pb.entries if e.name == "cog"], [[pb.entries[0]]], "strict")
    rows = np.asarray(tr.hier_rows[0])
    stages = np.asarray(tr.g_stage)[rows]
    # tracking depends on the state only: its stage-0 rows are fixed by the measured x0
    np.testing.assert_array_equal(~tr.g_movable[rows], stages == 0)
    # the gap rows of stage 0 contain u0: movable
    assert tr.g_movable[tr.gap_rows].all()


def test_a_posture_task_settles_the_yaw_pan_split():
    """Yaw and the pan joint turned together move neither the EE nor the CoG: only a
    posture term decides them (weight 0: they stay where the regulariser leaves them)."""
    pb = problem()
    pb.add_task(Posture(["yaw", "q1"]), weight=1.0, level=1)
    x0 = X0.copy()
    x0[3] = x0[4] = 0.4  # yaw and pan turned together
    cmd = Controller(pb, "hierarchical", "ipopt", OPTIONS["ipopt"]).step(x0, 0.0)
    assert cmd.status == "ok"
    assert abs(cmd.plan_x[-1, 3]) < abs(x0[3]) and abs(cmd.plan_x[-1, 4]) < abs(x0[4])
    assert abs(cmd.levels[0].loss) <= 1e-7 * max(cmd.levels[0].cost, 1e-8)


def test_the_log_reports_losses_exact_rho_and_every_points_clearance():
    sc = load_scenarios("waypoints", ["duration=3"], only="hierarchical")["hierarchical"]
    log = simulate(sc)
    s = log.summary()
    assert s["levels"]["0"]["loss_rel_mean"] < 1e-6
    assert {"level0_loss", "level1_loss", "level0_objective"} <= set(log.names)
    kin = sc.problem.kin
    for k in range(len(log)):
        x = np.array([log.column(c)[k] for c in ("x", "y", "z", "yaw", "q1", "q2", "q3")])
        # rho exactly, from NumPy's eigenvalues of J_eq J_eq^T (no regularisation)
        J = np.asarray(kin.jeq("xyz")(x))
        lam = np.linalg.eigvalsh(J @ J.T)
        assert log.column("cond")[k] == pytest.approx(lam[-1] / lam[0], rel=1e-9)
        depth = np.asarray(kin.clearance()(x)).ravel()
        got = [log.column(f"clear_{p}")[k] for p in kin.default_clearance_points()]
        np.testing.assert_allclose(got, depth, atol=1e-12)
        assert log.column("clearance")[k] == pytest.approx(depth.min(), abs=1e-12)
