"""``physics.joint_setpoint``: where each servo's ramp starts, checked on the flown joint
angles against the commanded ones (the plan's start, or the integral of the rates)."""

import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.robot.loader import load_robot
from aeromanip.sim.physics import PhysicsSimulator

X8 = load_robot("x8-3dof")
X0 = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.6, -1.2])


def fly(joint_setpoint, starts, rate):
    """Hold the platform, ramp joint 2 at ``rate`` [rad/s] from ``starts`` (one per 0.1 s
    period); the joint angle flown at the end."""
    sim = PhysicsSimulator.from_options(
        X8, {"setpoint": "velocity", "joint_setpoint": joint_setpoint}
    )
    sim.reset(X0)
    u = np.zeros(7)
    u[5] = rate
    for q2 in starts:
        plan_start = X0.copy()
        plan_start[5] = q2
        sim.advance(u, plan_start, 0.1)
    for _ in range(10):  # settle on the last reference, still
        sim.advance(np.zeros(7), plan_start, 0.1)
    return sim.true_state()[5]


def test_ramp_starts_at_the_plan_and_rate_integrates_the_command():
    # the plan's start says 0.6 every period (a measurement that did not move), the rate
    # says +0.2 rad/s for 1 s: "ramp" goes back to 0.6 each period, "rate" reaches 0.8
    starts = [0.6] * 10
    assert fly("ramp", starts, 0.2) == pytest.approx(0.6, abs=0.005)
    assert fly("rate", starts, 0.2) == pytest.approx(0.8, abs=0.005)


def test_rate_reaches_the_integral_of_the_commanded_rate():
    sim = PhysicsSimulator.from_options(X8, {"setpoint": "velocity", "joint_setpoint": "rate"})
    sim.reset(X0)
    u = np.zeros(7)
    u[5] = 0.2
    noisy = X0.copy()
    for k in range(10):  # 1 s at 0.2 rad/s; the plan's start wrong by up to 5 mrad
        noisy[5] = 0.6 + 0.02 * k + 0.005 * (-1) ** k
        sim.advance(u, noisy, 0.1)
    for _ in range(10):
        sim.advance(np.zeros(7), noisy, 0.1)
    assert sim.true_state()[5] == pytest.approx(0.6 + 0.2 * 1.0, abs=0.005)


def test_an_unknown_joint_setpoint_is_one_line():
    with pytest.raises(ConfigError, match=r"physics\.joint_setpoint: 'angle' is not one of"):
        PhysicsSimulator.check_options({"joint_setpoint": "angle"})
