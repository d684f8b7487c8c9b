"""The bounded approach speed near a surface: its expression against NumPy (the EE
velocity from finite differences of the forward kinematics), the band where it binds,
and the closed loop of an NMPC that slows down for it."""

import casadi as ca
import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.nmpc.approach import ApproachSpeed
from aeromanip.nmpc.controller import Controller
from aeromanip.nmpc.problem import Problem
from aeromanip.references import Constant
from aeromanip.robot.kinematics import Kinematics
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import ControlRate, EndEffectorTracking
from aeromanip.tasks.base import Stage

ROBOT = load_robot("x8-3dof")
KIN = Kinematics(ROBOT)
X0 = np.array([0.0113, 0.0, 1.0206, 0.0, 0.0, 0.6, -1.2])  # EE at (0, 0, 0.6)
WALL = ((0.3, 0.0, 0.6), (-1.0, 0.0, 0.0))


def _row(c: ApproachSpeed) -> ca.Function:
    x, v = ca.SX.sym("x", KIN.nx), ca.SX.sym("v", KIN.nx)
    rows = c.expression(Stage(KIN, x, None, v, ca.SX.zeros(0), 0.1))
    assert rows.upper.tolist() == [0.0] and rows.lower.tolist() == [-np.inf]
    return ca.Function("g", [x, v], [rows.expr])


def _allowed(gap: float, speed=0.03, distance=0.03, release=0.005, gain=2.0, w=0.005):
    """The documented allowed speed, in NumPy."""
    centre, half = (distance - release) / 2, (distance + release) / 2
    beyond = np.hypot(gap - centre, w) - half
    return speed + gain * w * np.logaddexp(0.0, beyond / w)


def test_the_bound_is_the_speed_towards_the_surface_minus_the_allowed_one():
    c = ApproachSpeed(*WALL, speed=0.03, distance=0.03, gain=2.0, probe_radius=0.01)
    g = _row(c)
    u = np.array([0.05, 0.02, -0.01, 0.1, 0.0, 0.5, -0.4])
    ee = lambda x: np.asarray(KIN.ee_position(x)).ravel()  # noqa: E731
    for gap in (0.2, 0.015, 0.0, -0.05):  # far, in the band, touching, well past the face
        x = X0.copy()
        x[0] += 0.29 - gap - ee(X0)[0]  # the probe's surface `gap` before the face
        v_in = (ee(x) - ee(x - 0.1 * u))[0] / 0.1  # towards the wall (+x), over the step
        assert float(g(x, u)) == pytest.approx(v_in - _allowed(gap), abs=1e-12)
        assert float(g(x, np.zeros(KIN.nx))) < 0  # at rest: never binding
    assert _allowed(0.2) == pytest.approx(0.03 + 2.0 * (0.2 - 0.03), rel=1e-3)  # far: more
    assert _allowed(0.01) == pytest.approx(0.03, abs=1e-3)  # in the band: the speed


def test_bad_options_are_one_line_naming_the_key():
    with pytest.raises(ConfigError, match=r"^approach\.speed: must be in \(0, 10\]"):
        ApproachSpeed(*WALL, speed=0.0, distance=0.03)
    with pytest.raises(ConfigError, match=r"^approach\.normal: "):
        ApproachSpeed((0, 0, 0), (0, 0, 0), speed=0.1, distance=0.03)


def test_an_nmpc_closes_in_no_faster_than_the_bound():
    """Ideal loop (x += dt u), the EE 5 cm before the wall, its target 2 cm past it:
    unbounded it rushes in; bounded, its EE closes in at most 3 cm/s within the band."""

    def fly(bounded: bool) -> np.ndarray:
        pb = Problem(ROBOT, 10, 0.1)
        pb.add_task(EndEffectorTracking(Constant([0.31, 0.0, 0.6])), weight=10.0)
        pb.add_task(ControlRate(), weight={"default": 0.01}, level=None)
        if bounded:
            pb.add_constraint(ApproachSpeed(*WALL, 0.03, 0.03, probe_radius=0.01))
        ctrl, x, xs = Controller(pb), X0.copy(), []
        x[0] += 0.24
        for k in range(20):
            x = x + 0.1 * ctrl.step(x, 0.1 * k).u
            xs.append(np.asarray(KIN.ee_position(x)).ravel()[0])
        return np.array(xs)

    free, bounded = fly(False), fly(True)
    speed = np.diff(bounded) / 0.1  # each step's, towards the wall
    gap_after = 0.29 - bounded[1:]
    np.testing.assert_array_less(speed, _allowed(gap_after) + 1e-6)  # every step
    in_band = (gap_after > 0.0) & (gap_after < 0.03)
    assert in_band.sum() >= 5 and np.all(speed[in_band] < 0.036)  # 3 cm/s, rounded
    assert np.max(np.diff(free) / 0.1) > 0.1  # unbounded it closes in 3x faster
    assert bounded[-1] > 0.3  # and it still gets there
