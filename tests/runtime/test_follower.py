"""The runtime's plan follower and the SITL autopilot's rules, without any link: hand
computed setpoints along a plan, and PX4's offboard entry and failsafe timings."""

import math

import numpy as np
import pytest

from aeromanip import load_robot
from aeromanip.mavlink.vehicle import ACCEPTED, DENIED, TEMPORARILY_REJECTED, Vehicle
from aeromanip.runtime.follower import Plan, PlanFollower
from aeromanip.runtime.measure import Measurement

ROBOT = load_robot("x8-3dof")  # x, y, z, yaw, q1..q3
X0 = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.6, -1.2])


def plan(t0=0.0):
    X = np.array([X0, X0 + 0.5 * np.array([0.1, 0, 0, 0.2, 0.1, 0, 0]), X0])
    U = np.array([[0.1, 0, 0, 0.2, 0.1, 0, 0], [0.0, 0.0, 0.1, 0.0, 0.0, 0.0, -0.1]])
    return Plan(t0, X, U, 0.5)


def test_follows_the_plan_ramp_with_position_feedback():
    f = PlanFollower(ROBOT, gain=2.0)
    f.follow(plan())
    x = X0.copy()
    x[0] = 0.01  # 1 cm ahead in x; at t = 0.25 the plan's x is 0.025
    v, yaw_rate, q = f.setpoint(0.25, x)
    assert v == pytest.approx((0.1 + 2.0 * (0.025 - 0.01), 0.0, 0.0))
    assert yaw_rate == pytest.approx(0.2 + 2.0 * 0.05)  # yaw ref 0.05, measured 0
    np.testing.assert_allclose(q, [0.025, 0.6, -1.2])
    # the second plan step (t in [0.5, 1.0)): from X[1] along U[1]
    v, yaw_rate, q = f.setpoint(0.75, plan().X[1])
    assert v == pytest.approx((0.0, 0.0, 0.1 + 2.0 * 0.025))
    np.testing.assert_allclose(q, [0.05, 0.6, -1.2 - 0.025])


def test_a_new_plan_waits_for_its_start_and_past_the_end_it_rests():
    f = PlanFollower(ROBOT, gain=0.0)
    f.follow(plan(0.0))
    f.follow(plan(1.0))  # decided now, takes effect at t = 1 (latency)
    v, _, _ = f.setpoint(0.25, X0)
    assert v[0] == pytest.approx(0.1)  # the previous plan still flies
    v, _, _ = f.setpoint(5.0, X0)  # after its horizon: at rest at its end
    assert v == (0.0, 0.0, 0.0)


def test_hold_and_velocity_limits():
    f = PlanFollower(ROBOT, gain=1.5)
    assert f.setpoint(0.0, X0) is None  # nothing set: no setpoint
    f.hold(X0)
    x = X0.copy()
    x[:3] += (0.02, -10.0, 0.0)  # 10 m off in y: clipped to the robot's 1 m/s
    v, yaw_rate, q = f.setpoint(3.0, x)
    assert v == pytest.approx((-0.03, 1.0, 0.0)) and yaw_rate == 0.0
    np.testing.assert_allclose(q, X0[4:])


def test_measurement_predicts_along_its_rates():
    m = Measurement(np.array([1.0, 2.0]), np.array([0.5, -1.0]), stamp=10.0)
    np.testing.assert_allclose(m.predicted(10.1), [1.05, 1.9])


def test_offboard_needs_a_recent_setpoint_and_fails_safe_after_half_a_second():
    """PX4 161b530 (offboardCheck.cpp L38-66): one setpoint younger than COM_OF_LOSS_T
    (0.5 s here) is the offboard signal; older, the switch is refused."""
    v = Vehicle(ROBOT, X0)
    assert v.set_mode(0.0, "offboard", X0) == TEMPORARILY_REJECTED  # no setpoint
    assert v.arm(0.0, True, X0) == ACCEPTED and v.mode == "hold"
    v.on_setpoint(0.2, (0.1, 0.0, 0.0), 0.0, 0)
    assert v.set_mode(0.71, "offboard", X0) == TEMPORARILY_REJECTED  # 0.51 s old
    v.on_setpoint(1.0, (0.1, 0.0, 0.0), 0.0, 0)
    assert v.set_mode(1.0, "offboard", X0) == ACCEPTED and v.mode == "offboard"
    u, _ = v.command(1.49, X0)
    assert u[0] == 0.1  # flying the setpoint
    x = X0 + np.array([0.05, 0, 0, 0, 0, 0, 0])
    u, _ = v.command(1.51, x, speed=0.1)  # 0.51 s without a setpoint: hold
    assert v.mode == "hold" and "failsafe" in v.events[-1].text
    np.testing.assert_allclose(u, 0.0, atol=1e-12)  # brake first ...
    u, _ = v.command(1.6, x, speed=0.01)  # ... stopped at x: hold there
    np.testing.assert_allclose(u, 0.0, atol=1e-12)
    u, _ = v.command(1.7, X0, speed=0.01)  # pulled back to the hold point
    assert u[0] == pytest.approx(1.5 * 0.05)
    assert v.arm(2.0, False, X0) == DENIED  # no disarming in the air


def test_joint_targets_ramp_at_their_rate_then_stop():
    v = Vehicle(ROBOT, X0)
    v.arm(0.0, True, X0)
    for k in range(26):
        v.on_setpoint(0.04 * k, (0.0, 0.0, 0.0), 0.0, 0)
    v.set_mode(1.0, "offboard", X0)
    q = X0[4:].copy()
    v.on_joints(1.00, q)
    v.on_joints(1.02, q + np.array([0.002, 0.0, 0.0]))  # 0.1 rad/s on q1
    u, start = v.command(1.03, X0)
    assert u[4] == pytest.approx(0.1) and start[4] == pytest.approx(0.002 + 0.001)
    u, start = v.command(1.5, X0)  # targets stopped: the ramp ends EXTRAPOLATE_S later
    assert u[4] == 0.0 and start[4] == pytest.approx(0.002 + 0.1 * 0.1)
    assert math.isfinite(v.mission_t(1.5))
