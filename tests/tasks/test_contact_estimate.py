"""The contact's rest point estimated from the measured force, the thrust feed-forward,
and the force task that uses them: against a known true spring (the estimate must make
the NMPC's spring explain it), finite differences and the documented bounds."""

import math

import casadi as ca
import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.robot.kinematics import Kinematics
from aeromanip.robot.loader import load_robot
from aeromanip.tasks.base import Stage
from aeromanip.tasks.contact import ContactSpring
from aeromanip.tasks.contact_estimate import EVENTS, RestPointEstimator
from aeromanip.tasks.contact_feedforward import HOLD_S, LOSS_S, RATE, ThrustFeedforward
from aeromanip.tasks.force import NormalForce

N = np.array([-1.0, 0.0, 0.0])  # a wall facing -x, its face at x = 0.3
MODEL = ContactSpring((0.3, 0.0, 0.6), tuple(N), 125.0, 0.01, 0.0, 1e-3)


def true_force(p: np.ndarray, k: float = 150.0, face: float = 0.3 - 0.01 + 0.012) -> float:
    """A spring the model does not know: stiffer, its rest point 12 mm further in."""
    return k * max(0.0, p[0] - face)


def test_spring_inverse_is_the_penetration_of_a_force():
    for f in (0.05, 0.3, 2.0, 50.0):
        d = MODEL.penetration_of_force(f)
        p = MODEL.rest_point() - d * N
        assert MODEL.normal_force(p) == pytest.approx(f, rel=1e-9)
    p = ca.SX.sym("p", 3)
    off = ca.SX.sym("o")
    f = ca.Function("f", [p, off], [MODEL.normal_force(p, off)])
    q = np.array([0.31, 0.1, 0.6])
    assert float(f(q, 0.004)) == pytest.approx(MODEL.with_rest_offset(0.004).normal_force(q))


def test_in_contact_the_estimate_makes_the_model_explain_the_measured_force():
    est = RestPointEstimator(MODEL, force_limit=5.0, time_constant=0.3)
    p = np.array([0.31, 0.0, 0.6])
    measured = true_force(p)  # 1.2 N
    for _ in range(60):  # 6 s at 10 Hz: 20 time constants
        est.update(p, measured * N, 0.1)
    assert est.event == "contact"
    assert MODEL.normal_force(p, est.offset) == pytest.approx(measured, rel=1e-6)
    # a first-order low-pass: after one step 0.1 / 0.4 of the way
    fresh = RestPointEstimator(MODEL, force_limit=5.0, time_constant=0.3)
    fresh.update(p, measured * N, 0.1)
    assert fresh.offset == pytest.approx(0.25 * est.offset, rel=1e-6)


def test_without_contact_the_rest_point_is_searched_for_at_a_bounded_speed():
    est = RestPointEstimator(MODEL, force_limit=5.0, search_speed=0.02, max_offset=0.03)
    far = np.array([0.2, 0.0, 0.6])  # 9 cm before the face, nothing felt: nothing learnt
    est.update(far, np.zeros(3), 0.1)
    assert est.offset == 0.0 and est.event == ""
    deep = np.array([0.33, 0.0, 0.6])  # the model presses 4 cm in, nothing is felt
    offsets = []
    for _ in range(30):
        est.update(deep, np.zeros(3), 0.1)
        offsets.append(est.offset)
    steps = np.diff([0.0, *offsets])
    assert np.all(steps <= 0.02 * 0.1 + 1e-12)  # at most search_speed
    assert steps[0] == pytest.approx(0.002)
    assert offsets[-1] == pytest.approx(0.03) and est.event == "limit"  # bounded


def test_an_over_force_moves_the_rest_point_at_once():
    est = RestPointEstimator(MODEL, force_limit=5.0, time_constant=10.0)
    p = np.array([0.33, 0.0, 0.6])
    est.update(p, 8.0 * N, 0.1)
    assert est.event == "overforce" and EVENTS.index("overforce") > 0
    assert MODEL.normal_force(p, est.offset) == pytest.approx(8.0, rel=1e-6)


def test_a_surface_felt_far_nearer_than_modelled_bounds_the_estimate_below():
    est = RestPointEstimator(MODEL, force_limit=5.0, max_offset=0.03)
    early = np.array([0.2, 0.0, 0.6])  # 9 cm before the model's face, yet 8 N felt
    unbounded = float(MODEL.penetration(early)) - MODEL.penetration_of_force(8.0)
    assert unbounded < -0.1  # the rule alone would move the rest point 10 cm out
    est.update(early, 8.0 * N, 0.1)
    assert est.offset == pytest.approx(-0.03) and est.event == "limit"


def test_the_feedforward_is_held_through_a_bounce_and_rate_limited():
    ff = ThrustFeedforward(friction=0.3)
    v_ref = np.array([0.0, 0.03, 0.0])  # sliding along +y
    assert np.allclose(ff.thrust(2.0, N, v_ref, 0.0, 0.1), 0.0)  # nothing felt yet
    ff.feel(0.1, True)
    t1 = ff.thrust(2.0, N, v_ref, 0.1, 0.1)
    assert ff.level == pytest.approx(RATE * 0.1)  # 1 N of the 2 in one step
    assert t1[0] == pytest.approx(ff.level)  # pushes into the wall (+x)
    speed = 0.03 / math.hypot(0.03, 0.005)
    assert t1[1] == pytest.approx(0.3 * ff.level * speed)  # friction, along the slide
    ff.feel(0.2, False)  # a bounce: still on
    ff.thrust(2.0, N, v_ref, 0.2, 0.1)
    assert ff.level == pytest.approx(2.0) and not ff.lost(0.2)
    t = 0.1 + HOLD_S + 0.05  # not felt for longer than HOLD_S: ramped out
    ff.thrust(2.0, N, v_ref, t, 0.1)
    assert ff.level == pytest.approx(1.0) and not ff.lost(t)
    assert ff.lost(0.1 + LOSS_S + 0.01)  # not felt for LOSS_S: lost


def test_the_force_task_with_an_estimate_against_finite_differences():
    kin = Kinematics(load_robot("x8-3dof"))
    task = NormalForce(125.0, f_ref=2.0, point=(0.3, 0.0, 0.6), normal=tuple(N), estimate=True)
    assert task.param_size == 2
    x = ca.SX.sym("x", kin.nx)
    p = ca.SX.sym("p", 2)
    r = task.residual(Stage(kin, x, None, ca.SX.zeros(kin.nx), p, 0.1))
    f = ca.Function("r", [x, p], [r, ca.jacobian(r, ca.vertcat(x, p))])
    x0 = np.array([0.311, 0.0, 1.02, 0.0, 0.0, 0.6, -1.2])  # EE 12 mm into the wall
    p0 = np.array([2.0, 0.004])
    value, jac = (np.asarray(v).ravel() for v in f(x0, p0))
    spring = task.spring().with_rest_offset(0.004)
    ee = np.asarray(kin.ee_position(x0)).ravel()
    assert value[0] == pytest.approx(spring.normal_force(ee) - 2.0, rel=1e-9)
    z0, h = np.concatenate([x0, p0]), 1e-7
    fd = [
        (float(f(*np.split(z0 + h * e, [kin.nx])[:2])[0]) - float(f(x0, p0)[0])) / h
        for e in np.eye(len(z0))
    ]
    np.testing.assert_allclose(jac, fd, rtol=1e-4, atol=1e-4)
    assert jac[-1] == pytest.approx(-125.0, rel=1e-3)  # 1 m more offset: k N less


def test_the_force_task_logs_and_checks_its_options():
    task = NormalForce(125.0, schedule=[[0.0, 0.0], [1.0, 2.0]], point=(0.3, 0, 0.6),
                       normal=tuple(N), estimate=True, feedforward=True)  # fmt: skip
    assert task.observations(0.5) == {
        "f_ref": 1.0, "f_ff": 0.0, "contact_lost": 0.0, "rest_offset": 0.0, "contact_event": 0.0
    }  # fmt: skip
    assert task.force_feedforward(np.zeros(3), np.zeros(3), 0.1) is not None
    assert (
        NormalForce(125.0, point=(0.3, 0, 0.6), normal=tuple(N)).force_feedforward(
            np.zeros(3), np.zeros(3), 0.1
        )
        is None
    )
    with pytest.raises(ConfigError, match=r"^force\.time_constant: must be in \(0, 100\]"):
        NormalForce(125.0, time_constant=0.0)
    with pytest.raises(ConfigError, match=r"^force\.friction: "):
        NormalForce(125.0, friction=-0.1)
    with pytest.raises(ConfigError, match=r"^force\.feedforward_rate: must be in \(0, 1000\]"):
        NormalForce(125.0, feedforward_rate=0.0)


def test_the_feedforward_rate_option_bounds_each_step():
    """``feedforward_rate`` [N/s]: a step of ``dt`` changes the feed-forward by at most
    rate * dt, here 1 N/s over 0.5 s steps: 0.5, 1.0, 1.5, 2.0 N for a 2 N set force."""
    task = NormalForce(125.0, f_ref=2.0, point=(0.3, 0, 0.6), normal=tuple(N),
                       estimate=True, feedforward=True, feedforward_rate=1.0)  # fmt: skip
    assert task._thrust.rate == 1.0
    levels = []
    for t in (0.0, 0.5, 1.0, 1.5, 2.0):
        task._thrust.feel(t, True)
        thrust = task._thrust.thrust(2.0, N, np.zeros(3), t, 0.5)
        levels.append(float(-thrust @ N))
    np.testing.assert_allclose(levels, [0.5, 1.0, 1.5, 2.0, 2.0], atol=1e-12)
