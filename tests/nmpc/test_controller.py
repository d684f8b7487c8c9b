"""NMPC core: reaching, constraints, hierarchy, weights, backends, fallback, errors."""

import itertools

import casadi as ca
import numpy as np
import pytest

from aeromanip.errors import ConfigError, InfeasibleProblemError, StateError
from aeromanip.nmpc.constraints import Bounds, Clearance, UserConstraint
from aeromanip.nmpc.controller import Controller
from aeromanip.nmpc.problem import MAX_WEIGHT, Problem
from aeromanip.references import Constant
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import (
    CogAlignment,
    ConditionNumber,
    ControlRate,
    EndEffectorTracking,
    Stage,
    Task,
)

X8 = load_robot("x8-3dof")
X0 = np.array([0.0, 0.0, 1.0, 0.0, 0.3, 0.4, -0.8])
TARGET = [0.5, 0.3, 0.6]


def make_problem(levels=(0, 1), cog_weight=1.0, target=TARGET, box=None, horizon=10, dt=0.5):
    bounds = Bounds.from_robot(X8, platform_box=box)
    pb = Problem(X8, horizon, dt, bounds)
    pb.add_task(EndEffectorTracking(Constant(target)), weight=10.0, level=levels[0])
    if levels[1] is not None:
        pb.add_task(CogAlignment(), weight=cog_weight, level=levels[1])
    pb.add_task(ControlRate(), weight=0.1, level=None)
    pb.add_constraint(Clearance(0.1))
    return pb


def closed_loop(ctrl, x, steps):
    cmds = []
    for k in range(steps):
        cmd = ctrl.step(x, k * ctrl.problem.dt)
        cmds.append(cmd)
        x = x + ctrl.problem.dt * cmd.u
    return x, cmds


def check_solution_feasible(pb, cmd, tol=1e-6):
    b = pb.bounds
    X, U = cmd.plan_x, cmd.plan_u
    assert np.all(X[1:] >= b.x_lower - tol) and np.all(X[1:] <= b.x_upper + tol)
    assert np.all(b.u_lower - tol <= U) and np.all(b.u_upper + tol >= U)
    clear = pb.kin.clearance()
    for x in X[1:]:
        assert np.all(np.asarray(clear(x)) >= 0.1 - tol)
    # the plan obeys the model x[k+1] = x[k] + dt u[k]
    np.testing.assert_allclose(X[1:], X[:-1] + pb.dt * U, atol=1e-8)


@pytest.mark.parametrize("backend", ["ipopt", "fatrop"])
def test_reachable_target_is_reached_within_bounds(backend):
    pb = make_problem(box={"z": (0.5, 2.0)})
    ctrl = Controller(pb, "weighted", backend)
    x, cmds = closed_loop(ctrl, X0, 25)
    assert all(c.status == "ok" for c in cmds)
    np.testing.assert_allclose(np.asarray(pb.kin.ee_position(x)).ravel(), TARGET, atol=1e-3)
    for c in cmds:
        check_solution_feasible(pb, c)


def test_active_bounds_and_clearance_hold():
    """A target only reachable by folding the arm up: clearance and joint limits bind."""
    pb = make_problem(target=[0.2, 0.0, 0.95], box={"z": (1.0, 1.0 + 1e-9)})
    ctrl = Controller(pb, "weighted")
    x, cmds = closed_loop(ctrl, X0, 12)
    depth = np.asarray(pb.kin.clearance()(x)).ravel()
    assert depth.min() == pytest.approx(0.1, abs=1e-5)  # the constraint is active
    for c in cmds:
        check_solution_feasible(pb, c)


@pytest.mark.parametrize("mode", ["stagewise", "total"])
def test_hierarchy_keeps_primary_optimum_and_improves_secondary(mode):
    # primary alone
    ref = Controller(make_problem(levels=(0, None)), "weighted").step(X0, 0.0)
    primary_alone = ref.task_costs["tracking"]
    # hierarchy
    pb = make_problem(levels=(0, 1))
    cmd = Controller(pb, "hierarchical", hierarchy={"mode": mode}).step(X0, 0.0)
    assert cmd.status == "ok"
    n_rows = pb.horizon + 1 if mode == "stagewise" else 1
    allowed = primary_alone * (1 + 1e-3) + 1e-6 * n_rows
    assert cmd.levels[0].cost == pytest.approx(primary_alone, rel=1e-5, abs=1e-9)
    assert cmd.task_costs["tracking"] <= allowed + 1e-9
    # the secondary cost at the hierarchy's solution is lower than at the primary-only one
    assert _cog_cost(pb, cmd.plan_x) == pytest.approx(cmd.task_costs["cog"], rel=1e-9)
    # stage 0 is the measured state: compare what the optimisation can change
    cog_without, cog_with = _cog_cost(pb, ref.plan_x[1:]), _cog_cost(pb, cmd.plan_x[1:])
    assert cog_with < 0.5 * cog_without
    assert cmd.levels[1].gain > 0.0


def _cog_cost(pb, states):
    """Sum over ``states`` of the squared body-frame xy CoG offset (unit weights)."""
    c = pb.kin.cog_body
    return float(sum(np.sum(np.asarray(c(x)).ravel()[:2] ** 2) for x in states))


@pytest.mark.parametrize("mode", ["stagewise", "total"])
def test_three_levels_each_keeps_higher_optima(mode):
    pb = make_problem(levels=(0, 1))
    pb.add_task(ConditionNumber("xyz"), weight=1e-4, level=2)
    hierarchy = {"mode": mode}
    cmd = Controller(pb, "hierarchical", hierarchy=hierarchy).step(X0, 0.0)
    assert [lv.level for lv in cmd.levels] == [0, 1, 2]
    assert all(lv.success for lv in cmd.levels)
    two = Controller(make_problem(levels=(0, 1)), "hierarchical", hierarchy=hierarchy)
    two_cmd = two.step(X0, 0.0)
    # levels 0 and 1 keep (within tolerance) their optimum from the two-level problem
    n = pb.horizon + 1
    assert cmd.task_costs["tracking"] <= two_cmd.levels[0].cost * 1.001 + 1e-6 * n
    assert cmd.task_costs["cog"] <= two_cmd.levels[1].cost * 1.001 + 1e-6 * n + 1e-9
    # ...and level 2 lowers the condition number's cost below what the two levels leave
    rho_cost = pb.kin.condition_number("xyz")

    def cond_cost(plan_x):
        return sum((1.0 - float(rho_cost(x))) ** 2 for x in plan_x[1:])  # x0 is given

    assert cond_cost(cmd.plan_x) < 0.99 * cond_cost(two_cmd.plan_x)
    assert cmd.levels[2].gain > 0.0


def test_raising_a_weight_lowers_that_task_cost():
    costs = []
    for w in [0.01, 0.1, 1.0, 10.0]:
        pb = make_problem(levels=(0, 0), cog_weight=w, target=[0.6, 0.3, 0.6])
        cmd = Controller(pb, "weighted").step(X0, 0.0)
        costs.append(cmd.task_costs["cog"] / w)
    assert all(a > b for a, b in itertools.pairwise(costs)), costs


def test_backends_reach_the_same_optimum():
    plans = {}
    for backend in ["ipopt", "fatrop"]:
        cmd = Controller(make_problem(levels=(0, 0)), "weighted", backend).step(X0, 0.0)
        assert cmd.status == "ok"
        plans[backend] = cmd
    np.testing.assert_allclose(plans["ipopt"].plan_u, plans["fatrop"].plan_u, atol=1e-4)
    assert plans["ipopt"].task_costs["tracking"] == pytest.approx(
        plans["fatrop"].task_costs["tracking"], rel=1e-4, abs=1e-8
    )


def test_forced_failure_falls_back_to_previous_plan_then_stops():
    pb = make_problem(levels=(0, 0))
    good = Controller(pb, "weighted")
    first = good.step(X0, 0.0)
    assert first.status == "ok"
    # now make every solve fail: a budget no solver can meet
    good.time_budget_s = 1e-9
    x = X0 + pb.dt * first.u
    second = good.step(x, pb.dt)
    assert second.status == "fallback" and "over budget" in second.message
    np.testing.assert_allclose(second.u, first.plan_u[1])
    statuses = [good.step(x, k * pb.dt).status for k in range(2, 2 + pb.horizon)]
    assert statuses[-1] == "stopped"
    assert np.all(good.step(x, 99.0).u == 0.0)


def test_solver_failure_without_plan_stops():
    pb = make_problem(levels=(0, 0))
    ctrl = Controller(pb, "weighted", solver_options={"ipopt.max_iter": 1})
    cmd = ctrl.step(X0, 0.0)
    assert cmd.status == "stopped" and np.all(cmd.u == 0.0)
    assert "Maximum_Iterations" in cmd.message


def test_initial_state_outside_hard_bounds_is_a_status_not_a_crash():
    pb = make_problem(levels=(0, 0))
    x = X0.copy()
    x[5] = 3.0  # shoulder far beyond its 1.6 rad limit, unrecoverable in one step
    cmd = Controller(pb, "weighted").step(x, 0.0)
    assert cmd.status == "stopped"
    assert "state q2 = 3 outside [-1.6, 1.6]" in cmd.message, cmd.message
    ok = Controller(pb, "weighted").step(X0, 0.0)
    assert ok.status == "ok" and ok.message == ""


def test_inconsistent_bounds_are_reported_before_solving():
    with pytest.raises(InfeasibleProblemError, match=r"bounds\.x\.z"):
        Bounds.from_robot(X8, platform_box={"z": (2.0, 1.0)})
    with pytest.raises(ConfigError, match=r"platform_box\.pitch"):
        Bounds.from_robot(X8, platform_box={"pitch": (0.0, 1.0)})


def test_bad_state_is_a_clear_error():
    ctrl = Controller(make_problem(levels=(0, 0)), "weighted")
    with pytest.raises(StateError, match="expected 7 values"):
        ctrl.step(np.zeros(6), 0.0)
    x = X0.copy()
    x[4] = np.nan
    with pytest.raises(StateError, match="q1 is not finite"):
        ctrl.step(x, 0.0)


def test_user_constraint_holds():
    pb = make_problem(levels=(0, 0), target=[0.5, 0.3, 0.4])
    pb.add_constraint(
        UserConstraint("ee_above_floor", lambda s: s.kin.ee_position(s.x)[2], 0.55, np.inf)
    )
    cmd = Controller(pb, "weighted").step(X0, 0.0)
    ee_z = [float(pb.kin.ee_position(x)[2]) for x in cmd.plan_x[1:]]
    assert min(ee_z) >= 0.55 - 1e-6
    assert min(ee_z) == pytest.approx(0.55, abs=1e-4)  # active: the target is below


class JointPosture(Task):
    """A user task written outside the package: joints towards a posture."""

    name = "posture"

    def __init__(self, q_ref):
        self.q_ref = ca.DM(q_ref)

    def residual(self, stage: Stage):
        return stage.x[stage.kin.n_platform :] - self.q_ref


def test_user_task_through_public_api():
    pb = Problem(X8, 10, 0.5)
    pb.add_task(JointPosture([0.2, -0.3, 0.5]), weight=1.0)
    pb.add_task(ControlRate(), weight=0.01, level=None)
    x, _ = closed_loop(Controller(pb, "weighted"), X0, 20)
    np.testing.assert_allclose(x[4:], [0.2, -0.3, 0.5], atol=1e-3)


def test_weights_named_by_dof_push_motion_to_the_arm():
    """Sec. IV-D: a heavy platform control-rate weight makes the arm do the work."""
    shares = {}
    for name, w in {
        "arm": {"x": 100, "y": 100, "z": 100, "yaw": 100, "default": 0.01},
        "platform": {"q1": 100, "q2": 100, "q3": 100, "default": 0.01},
    }.items():
        pb = Problem(X8, 10, 0.5)
        pb.add_task(EndEffectorTracking(Constant([0.1, 0.05, 0.5])), weight=10.0)
        pb.add_task(ControlRate(), weight=w, level=None)
        cmd = Controller(pb, "weighted").step(X0, 0.0)
        shares[name] = np.abs(cmd.plan_u[:, :3]).sum() / np.abs(cmd.plan_u).sum()
    assert shares["arm"] < 0.2 < 0.8 < shares["platform"]


def test_a_weight_mapping_names_dofs_and_the_others_take_its_default_or_zero():
    pb = Problem(X8, 10, 0.5)
    e = pb.add_task(ControlRate(), weight={"x": 2.0, "default": 0.5})
    np.testing.assert_array_equal(e.weight, [2.0, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5])
    e = pb.add_task(ControlRate(), weight={"q1": 3.0}, name="rate_q1")
    np.testing.assert_array_equal(e.weight, [0, 0, 0, 0, 3.0, 0, 0])
    for bad in (-1.0, np.inf, MAX_WEIGHT * 1.01, [1.0, 2.0, -0.1, 0, 0, 0, 0]):
        with pytest.raises(ConfigError, match=r"^tasks\.bad\.weight: weights must be in \[0, "):
            pb.add_task(ControlRate(), weight=bad, name="bad")
    assert pb.add_task(ControlRate(), weight=MAX_WEIGHT, name="heavy").weight[0] == MAX_WEIGHT


def test_a_task_added_without_options_has_weight_one_at_level_zero():
    e = Problem(X8, 10, 0.5).add_task(CogAlignment())
    assert e.level == 0 and e.name == "cog"
    np.testing.assert_array_equal(e.weight, [1.0, 1.0])
    np.testing.assert_array_equal(e.terminal_weight, [1.0, 1.0])


def test_bad_task_declarations_are_clear_errors():
    pb = Problem(X8, 10, 0.5)
    with pytest.raises(ConfigError, match=r"tasks\.control_rate\.weight\.pitch"):
        pb.add_task(ControlRate(), weight={"pitch": 1.0})
    with pytest.raises(ConfigError, match=r"tasks\.cog\.weight: expected 1 or 2 values"):
        pb.add_task(CogAlignment(), weight=[1.0, 2.0, 3.0])
    with pytest.raises(ConfigError, match=r"^tasks\.cog\.terminal_weight: expected 1 or 2 "):
        pb.add_task(CogAlignment(), terminal_weight=[1.0, 2.0, 3.0])
    odd = type("Odd", (ControlRate,), {"time_scaling": "sum"})()
    with pytest.raises(ConfigError, match=r"^tasks\.odd: time_scaling 'sum' is not 'integral'"):
        Problem(X8, 10, 0.5, weights_dt=0.1).add_task(odd, name="odd")
    for level in (-1, 1.0, True):
        with pytest.raises(ConfigError, match=r"^tasks\.cog\.level: must be an integer >= 0"):
            pb.add_task(CogAlignment(), level=level)
    for horizon in (0, 2.0, True):
        with pytest.raises(ConfigError, match=r"^horizon: must be an integer >= 1, got "):
            Problem(X8, horizon, 0.5)
    for dt in (0.0, -0.1, np.inf, np.nan):
        with pytest.raises(ConfigError, match=r"^dt: must be a finite number > 0, got "):
            Problem(X8, 10, dt)
        with pytest.raises(ConfigError, match=r"^weights_dt: must be a finite number > 0, got"):
            Problem(X8, 10, 0.5, weights_dt=dt)
    assert Problem(X8, 1, 0.5).horizon == 1  # one step is a horizon
    with pytest.raises(ConfigError, match="strategy"):
        Controller(make_problem(), "lexicographic")


def test_orientation_tracking_reaches_the_desired_pose():
    """h1 with orientation (Sec. IV-A): position and a yawed, pitched EE frame together."""
    c, s = np.cos(0.6), np.sin(0.6)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    R0 = np.asarray(make_problem().kin.ee_rotation(X0))
    target_R = Rz @ R0  # the start orientation yawed by 0.6 rad about world z
    pb = Problem(X8, 10, 0.5)
    pb.add_task(EndEffectorTracking(Constant(TARGET), orientation=target_R), weight=10.0)
    pb.add_task(ControlRate(), weight=0.01, level=None)
    x, cmds = closed_loop(Controller(pb, "weighted"), X0, 30)
    assert cmds[-1].status == "ok"
    np.testing.assert_allclose(np.asarray(pb.kin.ee_position(x)).ravel(), TARGET, atol=1e-3)
    np.testing.assert_allclose(np.asarray(pb.kin.ee_rotation(x)), target_R, atol=1e-3)


def test_out_of_iterations_retry_goes_on_from_the_last_iterate():
    """A warm-started solve that runs out of iterations is retried without multipliers
    from where it stopped (not from the start again); another failure restarts."""
    from aeromanip.nmpc.backends.base import NlpResult
    from aeromanip.nmpc.strategies import Weighted

    st = Weighted(make_problem(levels=(0, 0))).solvers[0]
    n, m = st.tr.w.numel(), st.tr.g.numel()
    seen = []

    class Spy:
        bounded_iterations = False  # a solve out of iterations is retried (``Backend``'s)

        def __init__(self, first_status):
            self.first_status = first_status

        def solve(self, r):
            w0 = r.w0
            seen.append((w0.copy(), not r.cold))
            ok = len(seen) % 2 == 0
            return NlpResult(
                w0 + 1.0,
                np.zeros(m),
                np.zeros(n),
                0.0,
                ok,
                "ok" if ok else self.first_status,
                3,
                0.0,
            )

    from aeromanip.nmpc.strategies import _solve_level

    w0, p = np.zeros(n), np.zeros(st.tr.p.numel())
    for status, restart in (("Maximum_Iterations_Exceeded", w0 + 1.0), ("Infeasible", w0)):
        seen.clear()
        st.backend = Spy(status)
        st.warm = NlpResult(w0, np.zeros(m), np.zeros(n), 0.0, True, "ok", 1, 0.0)
        res = _solve_level(st, p, w0, st.tr.ubg)
        assert res.success and res.iterations == 6
        assert seen[0][1] and not seen[1][1]  # warm multipliers first, then none
        np.testing.assert_array_equal(seen[1][0], restart)


def test_solver_options_can_be_set_from_the_command_line():
    from aeromanip.experiment.scenario import load_scenarios

    sc = load_scenarios(
        "flight", ["controller.backend='sqp'", "controller.solver_options.max_iter=7"]
    )[""]
    assert sc.backend == "sqp" and sc.solver_options == {"max_iter": 7}
    with pytest.raises(ConfigError, match=r"solver_options\.max_itr: unknown sqp option"):
        Controller(sc.problem, "weighted", "sqp", {"max_itr": 7})


class NanNearStart(Task):
    """A user task whose residual is NaN around the start (log of a negative number)."""

    name = "nan_task"

    def residual(self, stage: Stage) -> ca.SX:
        return ca.log(stage.x[0] - 5.0)


@pytest.mark.parametrize("backend", ["ipopt", "fatrop", "sqp"])
def test_a_task_that_is_nan_stops_the_robot_with_a_status(backend):
    pb = Problem(X8, 10, 0.5)
    pb.add_task(NanNearStart(), weight=1.0)
    pb.add_task(ControlRate(), weight=0.1, level=None)
    options = {"codegen": False} if backend == "sqp" else None
    cmd = Controller(pb, "weighted", backend, options).step(X0, 0.0)
    assert cmd.status == "stopped" and np.all(cmd.u == 0.0)
    assert cmd.message.startswith("Invalid_Number_Detected"), cmd.message
    # only fatrop, which would spin on it, has the guess checked before it starts
    assert ("at the initial guess" in cmd.message) == (backend == "fatrop"), cmd.message


def test_strategies_are_registered_by_name_or_loaded_as_package_module_class():
    """``STRATEGIES`` holds the built-ins; ``"package.module:Class"`` loads a ``Strategy``
    subclass (here the built-in ``Weighted`` by its path: the same answer as by name);
    hierarchy options for a strategy that is not ``by_level`` and unknown names are one
    ``ConfigError`` naming the key."""
    from aeromanip.nmpc.strategies import STRATEGIES, Hierarchical, Strategy, Weighted

    assert STRATEGIES.names() == ("hierarchical", "weighted")
    assert issubclass(Weighted, Strategy) and issubclass(Hierarchical, Strategy)
    assert (Weighted.by_level, Hierarchical.by_level) == (False, True)
    pb = make_problem(levels=(0, 0))
    x0 = np.array([0.0, 0.0, 1.0, 0.0, 0.3, 0.4, -0.8])
    by_name = Controller(pb, "weighted").step(x0, 0.0)
    by_path = Controller(pb, "aeromanip.nmpc.strategies:Weighted").step(x0, 0.0)
    np.testing.assert_allclose(by_path.u, by_name.u, atol=1e-9)
    with pytest.raises(ConfigError, match=r"^hierarchy: options given but strategy is 'weighted'"):
        Controller(pb, "weighted", hierarchy={"mode": "strict"})
    with pytest.raises(ConfigError, match=r"^strategy: 'nested' is not one of"):
        Controller(pb, "nested")
