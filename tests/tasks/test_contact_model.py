"""The NMPC's contact spring: its formula, and its force against MuJoCo's static contact
force (the physics simulator, the UAM's probe pressed on a floor and on a wall)."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.robot.loader import load_robot
from aeromanip.sim.physics import PhysicsSimulator
from aeromanip.tasks.contact import ContactSpring

# the spring identified against MuJoCo's default soft contact for the x8-3dof's probe
STIFFNESS, REST_OFFSET, SMOOTHING = 2900.0, 1.5e-4, 7e-5  # N/m, m, m
PUSHES = (0.005, 0.01, 0.02, 0.03, 0.05, 0.08, 0.12, 0.2, 0.3)  # [m] setpoint into the surface


def test_spring_is_a_smoothed_linear_spring():
    spring = ContactSpring((1.0, 0.0, 1.0), (-2.0, 0.0, 0.0), 1000.0, 0.01, 0.0, 1e-4)
    assert spring.normal == (-1.0, 0.0, 0.0)
    rest = spring.rest_point()
    np.testing.assert_allclose(rest, [0.99, 0.0, 1.0])
    # 3 mm past the rest point (30 widths): k d to 1e-12 N; at d = 0: k s log 2; 3 mm off: 0
    assert spring.normal_force(rest + np.array([0.003, 0.2, -0.1])) == pytest.approx(3.0, abs=1e-9)
    assert spring.normal_force(rest) == pytest.approx(1000.0 * 1e-4 * math.log(2.0))
    assert spring.normal_force(rest - np.array([0.003, 0.0, 0.0])) < 1e-9
    far_in = rest + np.array([10.0, 0.0, 0.0])
    assert spring.normal_force(far_in) == pytest.approx(1e4)  # no overflow
    p = ca.SX.sym("p", 3)
    f = ca.Function("f", [p], [spring.normal_force(p)])
    for q in (rest + np.array([0.0002, 0.0, 0.0]), rest - np.array([0.0001, 0.1, 0.0])):
        assert float(f(q)) == pytest.approx(spring.normal_force(q), rel=1e-12)
    moved = spring.with_rest_offset(0.001)  # the rest point 1 mm further in
    expected = 1.0 + 0.1 * math.log1p(math.exp(-10.0))  # k (d + s log(1 + e^(-d/s)))
    two_mm = rest + np.array([0.002, 0.0, 0.0])
    assert moved.normal_force(two_mm) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize(
    "kwargs, key",
    [
        (dict(stiffness=-1.0), "contact.stiffness"),
        (dict(normal=(0.0, 0.0, 0.0)), "contact.normal"),
        (dict(point=(0.0, 1.0)), "contact.point"),
        (dict(smoothing=0.0), "contact.smoothing"),
        (dict(rest_offset=float("nan")), "contact.rest_offset"),
    ],
)
def test_bad_spring_is_one_clear_error(kwargs, key):
    args = dict(point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0), stiffness=100.0) | kwargs
    with pytest.raises(ConfigError, match=f"^{key}: "):
        ContactSpring(**args)


def _pressed(normal: np.ndarray, axis: int) -> tuple[ContactSpring, np.ndarray, np.ndarray]:
    """The UAM hovering with its probe touching a surface of outward ``normal``, its
    position setpoint moved into it by each of ``PUSHES``: the (EE position, MuJoCo's normal
    force) of each control step of the last second of 3 s (quasi-static: the force grows
    by < 2 %/step as the flight controller's integrator winds up)."""
    spec = load_robot("x8-3dof")
    point = PhysicsSimulator(spec).ee_position() - 0.01 * normal  # the probe touching it
    spring = ContactSpring(tuple(point), tuple(normal), STIFFNESS, 0.01, REST_OFFSET, SMOOTHING)
    surface = dict(kind="wall", point=point.tolist(), normal=normal.tolist(), size=[1, 1])
    positions, forces = [], []
    for push in PUSHES:
        sim = PhysicsSimulator(spec, surfaces=[dict(surface, friction=0.5)])
        plan = np.tile(sim.true_state(), (11, 1))
        plan[:, axis] -= push * normal[axis]
        for k in range(30):
            sim.advance(np.zeros(spec.nx), plan, 0.1)
            if k >= 20:
                positions.append(sim.ee_position())
                forces.append(sim.extras()["f_n"])
    return spring, np.array(positions), np.array(forces)


@pytest.mark.parametrize("normal, axis", [([0.0, 0.0, 1.0], 2), ([-1.0, 0.0, 0.0], 0)])
def test_spring_matches_mujoco_static_contact_force(normal, axis):
    """One spring for both surfaces: over 0.05-12 N (floor) and 0.05-6 N (wall) its force
    is MuJoCo's within 0.5 N (0.46, 0.48 measured), RMS 0.2 N (0.17, 0.15), within 15 %
    beyond 1 mm of penetration (9 %, 14 %): MuJoCo's contact stiffens over its first mm
    (solimp's width) and its stiffness follows the probe's effective mass, which is not
    the same along z and x."""
    spring, positions, forces = _pressed(np.array(normal), axis)
    model = np.array([spring.normal_force(p) for p in positions])
    depth = np.array([float(spring.penetration(ca.DM(p))) for p in positions])
    assert forces.min() > 0.04 and forces.max() > 6.0  # in contact, over a wide range
    assert np.max(np.abs(model - forces)) < 0.5
    assert np.sqrt(np.mean((model - forces) ** 2)) < 0.2
    deep = depth > 1e-3
    assert deep.sum() >= 10
    np.testing.assert_allclose(model[deep], forces[deep], rtol=0.15)
