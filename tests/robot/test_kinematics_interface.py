"""Kinematics: the Function interface, defaults and the body-frame outputs.

Truth: the class docstring (every Function takes ``x``; its name is the attribute's, so
generated C code has one distinct symbol per Function), the paper's symbols for the
outputs (``D`` eq. 14, ``rho`` eq. 16), and a NumPy forward kinematics written from
the URDF convention (origin xyz/rpy in the parent frame, Rodrigues about the axis).
"""

import math

import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.robot.kinematics import Kinematics
from aeromanip.robot.loader import load_robot, robot_from_table


def rpy_matrix(r, p, y):
    """URDF fixed-axis roll-pitch-yaw, ``Rz(y) Ry(p) Rx(r)``."""
    cr, cp, cy = math.cos(r), math.cos(p), math.cos(y)
    sr, sp, sy = math.sin(r), math.sin(p), math.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def axis_angle(axis, a):
    k = np.asarray(axis, float)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K


def numpy_fk(spec, q):
    """Joint origins (3 x n) and EE position in the body frame, EE rotation."""
    R = rpy_matrix(*spec.mount_rpy)
    p = np.array(spec.mount_xyz, float)
    origins = []
    for j, qi in zip(spec.joints, q, strict=True):
        p = p + R @ np.array(j.xyz)
        R = R @ rpy_matrix(*j.rpy)
        origins.append(p.copy())
        R = R @ axis_angle(j.axis, qi)
    ee = p + R @ np.array(spec.ee_xyz)
    return np.array(origins).T, ee, R @ rpy_matrix(*spec.ee_rpy)


def table(**over):
    """A small 3-joint robot whose frames all have non-zero offsets and rotations."""
    data = {
        "name": "t",
        "platform": {"dofs": ["x", "y", "z"]},  # yaw inactive, not in `fixed`: default 0
        "mount": {"xyz": [0.1, 0.02, -0.05], "rpy": [0.1, -0.2, 0.3]},
        "end_effector": {"xyz": [0.01, 0.0, -0.1], "rpy": [0.2, 0.1, -0.4], "name": "tool"},
        "joints": [
            {
                "name": n,
                "xyz": xyz,
                "rpy": rpy,
                "axis": ax,
                "limits": [-2.0, 2.0],
                "velocity": 1.0,
                "link": {"mass": m, "com": [0.0, 0.01, -0.05]},
            }
            for n, xyz, rpy, ax, m in [
                ("a", [0, 0, 0], [0, 0, 0.2], [0, 0, 1], 0.1),
                ("b", [0.02, 0, -0.04], [0.1, 0, 0], [0, 1, 0], 0.2),
                ("c", [0, 0.01, -0.15], [0, 0.3, 0], [1, 0, 0], 0.3),
            ]
        ],
    }
    data.update(over)
    return data


@pytest.fixture(scope="module")
def kin():
    return Kinematics(robot_from_table(table()))


FUNCTIONS = {  # attribute -> output name (paper symbol or documented meaning)
    "ee_position": "p",
    "ee_rotation": "R",
    "ee_position_body": "p",
    "joint_positions": "P",
    "joint_positions_body": "P",
    "cog_body": "c",
    "cog_jacobian": "J",
    "ee_jacobian": "J",
}
METHODS = {"jeq": "J", "manipulability": "D", "condition_number": "rho", "clearance": "d"}


@pytest.mark.parametrize("attr", sorted(FUNCTIONS))
def test_function_attributes_are_named_after_themselves(kin, attr):
    f = getattr(kin, attr)
    assert (f.name(), f.name_in(), f.name_out()) == (attr, ["x"], [FUNCTIONS[attr]])


@pytest.mark.parametrize("meth", sorted(METHODS))
def test_function_methods_are_named_after_themselves(kin, meth):
    f = getattr(kin, meth)()
    assert (f.name(), f.name_in(), f.name_out()) == (meth, ["x"], [METHODS[meth]])


def test_defaults_track_xyz(kin):
    """``tracked`` defaults to all three coordinates: the same Functions as ``"xyz"``."""
    x = np.array([0.3, -0.2, 1.0, 0.4, -0.7, 0.9])
    for meth in ("jeq", "manipulability", "condition_number"):
        a, b = getattr(kin, meth)(), getattr(kin, meth)("xyz")
        np.testing.assert_array_equal(np.asarray(a(x)), np.asarray(b(x)))


def test_body_frame_outputs_match_numpy_fk(kin):
    rng = np.random.default_rng(0)
    for _ in range(5):
        x = rng.uniform(-1.5, 1.5, kin.nx)
        origins, ee, R_ee = numpy_fk(kin.spec, x[3:])
        np.testing.assert_allclose(np.asarray(kin.joint_positions_body(x)), origins, atol=1e-12)
        np.testing.assert_allclose(np.asarray(kin.ee_position_body(x)).ravel(), ee, atol=1e-12)
        # inactive yaw (not in `fixed`) is 0: the world frame is the body frame shifted
        np.testing.assert_allclose(np.asarray(kin.ee_position(x)).ravel(), ee + x[:3], atol=1e-12)
        np.testing.assert_allclose(
            np.asarray(kin.joint_positions(x)), origins + x[:3, None], atol=1e-12
        )
        np.testing.assert_allclose(np.asarray(kin.ee_rotation(x)), R_ee, atol=1e-12)


def test_fixed_values_place_inactive_dofs():
    """``platform.fixed`` gives inactive DoFs their value (here a yaw of 0.5 rad)."""
    plat = {"dofs": ["x", "y", "z"], "fixed": {"yaw": 0.5}}
    spec = robot_from_table(table(platform=plat))
    assert dict(spec.platform.fixed) == {"yaw": 0.5}
    kin = Kinematics(spec)
    x = np.array([0.0, 0.0, 0.0, 0.1, 0.2, 0.3])
    _, ee, _ = numpy_fk(spec, x[3:])
    c, s = math.cos(0.5), math.sin(0.5)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    np.testing.assert_allclose(np.asarray(kin.ee_position(x)).ravel(), Rz @ ee, atol=1e-12)


def test_symbols_are_the_state_and_its_joint_part(kin):
    x, q = kin.symbols()
    assert (x.shape, q.shape) == ((kin.nx, 1), (kin.n_joints, 1))
    assert [str(q[i]) for i in range(3)] == [str(x[3 + i]) for i in range(3)]


def test_point_names_and_clearance_are_the_joint_depths(kin):
    """Points are ``joint1..jointN`` then ``ee``; clearance is ``-z_body`` (eq. 17)."""
    assert kin.point_names() == ["joint1", "joint2", "joint3", "ee"]
    x = np.array([0.0, 0.0, 0.0, 0.4, 0.5, -0.6])
    origins, ee, _ = numpy_fk(kin.spec, x[3:])
    d = np.asarray(kin.clearance(["joint1", "joint3", "ee"])(x)).ravel()
    np.testing.assert_allclose(d, [-origins[2, 0], -origins[2, 2], -ee[2]], atol=1e-12)
    with pytest.raises(ConfigError, match="joint0"):
        kin.clearance(["joint0"])


def test_planar_robot_rejects_three_tracked_coordinates():
    kin = Kinematics(load_robot("planar-2dof"))
    with pytest.raises(ConfigError, match="track fewer"):
        kin.manipulability()
