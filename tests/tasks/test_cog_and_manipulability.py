"""Secondary tasks: h3 CoG velocity (eq. 11-12) and h4 manipulability (eq. 13-14)."""

import casadi as ca
import numpy as np
import pytest

from aeromanip.errors import AeromanipError, ConfigError
from aeromanip.nmpc.controller import Controller
from aeromanip.nmpc.problem import Problem
from aeromanip.references import Constant
from aeromanip.robot.kinematics import Kinematics
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import (
    CogVelocity,
    ControlRate,
    EndEffectorTracking,
    Manipulability,
    Stage,
)

TRACKED = {"x8-3dof": "xyz", "planar-2dof": "yz"}


@pytest.fixture(scope="module", params=sorted(TRACKED))
def kin(request):
    return Kinematics(load_robot(request.param))


def residual_function(task, kin, dt=0.1):
    """The task's stage residual as a Function of (x, u)."""
    x, u, u_prev = (ca.SX.sym(n, kin.nx) for n in ("x", "u", "u_prev"))
    stage = Stage(kin, x, u, u_prev, ca.SX.sym("p", task.param_size), dt)
    return ca.Function("r", [x, u], [task.residual(stage)])


def random_states(spec, n, seed):
    """States with the joints inside their limits and the platform near the origin."""
    rng = np.random.default_rng(seed)
    lo = np.array([j.lower for j in spec.joints])
    hi = np.array([j.upper for j in spec.joints])
    for _ in range(n):
        platform = rng.uniform(-1.0, 1.0, spec.n_platform)
        yield np.concatenate([platform, rng.uniform(lo, hi)])


def fd_ee_jacobian(kin, x, h=1e-6):
    """EE position Jacobian (3 x nx) by central differences of the FK, in NumPy."""
    cols = []
    for i in range(kin.nx):
        e = np.zeros(kin.nx)
        e[i] = h
        plus = np.asarray(kin.ee_position(x + e)).ravel()
        minus = np.asarray(kin.ee_position(x - e)).ravel()
        cols.append((plus - minus) / (2 * h))
    return np.column_stack(cols)


def numpy_manipulability(kin, x, tracked):
    """``D = det(J_eq J_eq^T)`` from the finite-difference EE Jacobian."""
    rows = ["xyz".index(c) for c in tracked]
    J_eq = fd_ee_jacobian(kin, x)[rows, kin.n_platform :]
    return float(np.linalg.det(J_eq @ J_eq.T))


# --- h3: arm CoG velocity ------------------------------------------------------------


def test_cog_velocity_is_cog_jacobian_times_joint_rates(kin):
    r = residual_function(CogVelocity(), kin)
    rng = np.random.default_rng(1)
    for x in random_states(kin.spec, 20, seed=2):
        u = rng.uniform(-1.0, 1.0, kin.nx)
        qdot = u[kin.n_platform :]
        expected = (np.asarray(kin.cog_jacobian(x)) @ qdot)[:2]
        np.testing.assert_allclose(np.asarray(r(x, u)).ravel(), expected, atol=1e-14)


def test_cog_velocity_matches_finite_difference_of_cog_along_command(kin):
    """``r(x, u)`` is the body-frame xy CoG velocity when the state moves by ``dt u``.

    The whole command moves the state, platform DoFs included: these must not move the
    arm CoG in the body frame (the task only uses the joint rates).
    """
    r = residual_function(CogVelocity(), kin)
    rng = np.random.default_rng(3)
    dt = 1e-6
    for x in random_states(kin.spec, 20, seed=4):
        u = rng.uniform(-1.0, 1.0, kin.nx)
        ahead = np.asarray(kin.cog_body(x + dt * u)).ravel()
        behind = np.asarray(kin.cog_body(x - dt * u)).ravel()
        fd = (ahead - behind)[:2] / (2 * dt)
        got = np.asarray(r(x, u)).ravel()
        assert got.shape == (2,)
        np.testing.assert_allclose(got, fd, atol=1e-8)
    # and it is not identically zero: a joint rate does move the CoG
    x = next(random_states(kin.spec, 1, seed=5))
    u = np.zeros(kin.nx)
    u[kin.n_platform] = 1.0
    u[-1] = 1.0
    assert np.linalg.norm(np.asarray(r(x, u))) > 1e-3


def test_cog_velocity_ignores_platform_rates(kin):
    r = residual_function(CogVelocity(), kin)
    x = next(random_states(kin.spec, 1, seed=6))
    u = np.zeros(kin.nx)
    u[: kin.n_platform] = 0.7
    np.testing.assert_array_equal(np.asarray(r(x, u)).ravel(), [0.0, 0.0])


@pytest.mark.parametrize("task", [CogVelocity(), ControlRate()], ids=lambda t: t.name)
def test_command_tasks_without_command_raise_project_error(kin, task):
    x = ca.SX.sym("x", kin.nx)
    stage = Stage(kin, x, None, ca.SX.sym("u_prev", kin.nx), ca.SX.sym("p", 0), 0.1)
    with pytest.raises(ConfigError, match=r"residual: needs the stage command u") as info:
        task.residual(stage)
    assert isinstance(info.value, AeromanipError)
    assert type(task).__name__ in str(info.value)


def test_cog_velocity_has_no_terminal_term(kin):
    x = ca.SX.sym("x", kin.nx)
    stage = Stage(kin, x, None, ca.SX.sym("u_prev", kin.nx), ca.SX.sym("p", 0), 0.1)
    assert CogVelocity().terminal_residual(stage) is None


# --- h4: manipulability ----------------------------------------------------------------


def test_manipulability_cost_is_inverse_square_of_numpy_determinant(kin):
    tracked = TRACKED[kin.spec.name]
    r_exact = residual_function(Manipulability(tracked, eps=0.0), kin)
    r_default = residual_function(Manipulability(tracked), kin)
    u = np.zeros(kin.nx)
    checked = 0
    for x in random_states(kin.spec, 30, seed=7):
        D = numpy_manipulability(kin, x, tracked)
        if D < 1e-8:  # too close to a singularity for a finite-difference reference
            continue
        checked += 1
        r = np.asarray(r_exact(x, u)).ravel()
        assert r.shape == (1,)
        np.testing.assert_allclose(r[0] ** 2, 1.0 / D**2, rtol=1e-6)
        # the default eps only changes the cost by a relative ~2 eps / D
        np.testing.assert_allclose(float(r_default(x, u)) ** 2, 1.0 / D**2, rtol=1e-6 + 4e-9 / D)
    assert checked >= 20


def test_manipulability_stays_finite_at_singularity():
    kin = Kinematics(load_robot("planar-2dof"))
    x = np.array([0.0, 1.0, 0.3, 0.0])  # arm stretched: q2 = 0, J_eq singular
    assert numpy_manipulability(kin, x, "yz") == pytest.approx(0.0, abs=1e-12)
    r = float(residual_function(Manipulability("yz", eps=1e-9), kin)(x, np.zeros(4)))
    assert np.isfinite(r) and r == pytest.approx(1e9, rel=1e-3)


def plan_manipulability(h4_weight):
    """One NMPC solve holding the EE still from a near-singular arm; D along the plan."""
    robot = load_robot("planar-2dof")
    kin = Kinematics(robot)
    x0 = np.array([0.0, 1.0, 0.2, -0.4])  # arm nearly stretched: small D
    hold = np.asarray(kin.ee_position(x0)).ravel()
    pb = Problem(robot, horizon=10, dt=0.1)
    pb.add_task(EndEffectorTracking(Constant(hold), tracked="yz"), weight=100.0)
    pb.add_task(Manipulability("yz"), weight=h4_weight)
    pb.add_task(ControlRate(), weight=0.01, level=None)
    cmd = Controller(pb, "weighted").step(x0, 0.0)
    assert cmd.status == "ok", cmd.message
    D = kin.manipulability("yz")
    tracking_err = np.linalg.norm(np.asarray(kin.ee_position(cmd.plan_x[-1])).ravel() - hold)
    return float(D(x0)), float(D(cmd.plan_x[-1])), tracking_err


def test_raising_manipulability_weight_increases_D():
    D0, D_off, _ = plan_manipulability(0.0)
    _, D_low, _ = plan_manipulability(1e-9)
    _, D_high, err_high = plan_manipulability(1e-7)
    # without h4 nothing drives the arm away from its start
    assert D_off == pytest.approx(D0, rel=1e-3)
    # a larger weight gives a larger D at the end of the plan, i.e. a smaller 1/D^2
    assert D_off < D_low < D_high
    assert D_high > 2.0 * D0
    # and the redundancy is used: the EE still holds its position
    assert err_high < 1e-4
