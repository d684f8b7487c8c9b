"""Task residuals (paper eq. 4, 8-16) pinned against an independent NumPy model.

Each residual is built by the task on CasADi symbols (as the OCP builds it) and evaluated
at known and random states; the expected value is the paper's formula computed from a
small NumPy forward kinematics written here from the ``RobotSpec`` fields alone (it never
calls ``Kinematics``). Its Jacobians use the geometric form ``axis x (p - origin)``,
checked against central finite differences of the NumPy FK, so the residual comparisons
can be tight (exact formulas to ~1e-12). Three robots: the two built-in ones and
``tilted-4dof`` (non-zero mount/joint/end-effector rpy, oblique axes, off-axis CoMs,
non-zero fixed platform DoFs, four joints) so that every frame convention is exercised.
"""

import math
from dataclasses import dataclass
from functools import cache

import casadi as ca
import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.references import Waypoints
from aeromanip.robot.kinematics import Kinematics
from aeromanip.robot.loader import load_robot, robot_from_table
from aeromanip.robot.spectral import condition_number
from aeromanip.tasks import (
    CogAlignment,
    CogVelocity,
    ConditionNumber,
    ControlRate,
    EndEffectorTracking,
    Manipulability,
    Stage,
)


def _joint(i, xyz, rpy, axis, mass, com):
    """One ``[[joints]]`` table of the tilted test robot."""
    link = {"name": f"link{i}", "mass": mass, "com": com}
    return {"name": f"j{i}", "xyz": xyz, "rpy": rpy, "axis": axis, "limits": [-2.0, 2.0],
            "velocity": 1.0, "link": link}  # fmt: skip


TILTED = {
    "name": "tilted-4dof",
    "platform": {"dofs": ["x", "z"], "fixed": {"y": -0.3, "yaw": 0.6}},
    "mount": {"xyz": [0.05, -0.02, -0.08], "rpy": [0.2, -0.15, 0.4]},
    "joints": [
        _joint(1, [0.0, 0.0, 0.0], [0.0, 0.0, 0.3], [0.0, 0.0, 1.0], 0.05, [0.01, 0.005, -0.02]),
        _joint(2, [0.02, 0.0, -0.05], [0.4, 0.1, -0.2], [0.0, 0.6, 0.8], 0.10, [0.0, 0.01, -0.08]),
        _joint(
            3, [0.0, 0.01, -0.15], [-0.3, 0.2, 0.1], [0.6, 0.0, -0.8], 0.07, [0.005, 0.0, -0.07]
        ),
        _joint(4, [0.0, 0.0, -0.12], [0.1, -0.4, 0.25], [0.0, 1.0, 0.0], 0.03, [0.0, 0.01, -0.03]),
    ],
    "end_effector": {"xyz": [0.01, 0.0, -0.06], "rpy": [0.3, 0.5, -0.2]},
}
"""An arm with every frame offset non-trivial (URDF-style table, as in a robot TOML)."""

HAND = {
    "name": "hand-1dof",
    "platform": {"dofs": ["x", "y", "z", "yaw"]},
    "mount": {"xyz": [0.0, 0.0, -0.1], "rpy": [math.pi / 2, 0.0, math.pi / 2]},
    "joints": [_joint(1, [0.2, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0], 1.0, [0.1, 0.0, 0.0])],
    "end_effector": {"xyz": [0.3, 0.0, 0.0]},
}
"""One joint behind a mount rotated by rpy (90, 0, 90) deg: small enough to solve by hand."""

ROBOTS = ["x8-3dof", "planar-2dof", "tilted-4dof"]
TRACKINGS = ["xyz", "yz", "zx", "x"]
# tracked coordinates with J_eq J_eq^T non-singular in general: m <= n joints, and the
# planar arm's x row is identically zero
JEQ_CASES = [
    ("x8-3dof", "xyz"),
    ("x8-3dof", "yz"),
    ("x8-3dof", "xz"),
    ("x8-3dof", "zx"),
    ("x8-3dof", "x"),
    ("planar-2dof", "yz"),
    ("planar-2dof", "zy"),
    ("planar-2dof", "z"),
    ("tilted-4dof", "xyz"),
    ("tilted-4dof", "zy"),
    ("tilted-4dof", "y"),
]


@cache
def robot(name):
    """``(spec, Kinematics)`` of a built-in robot or of a test table above."""
    tables = {"tilted-4dof": TILTED, "hand-1dof": HAND}
    spec = robot_from_table(tables[name]) if name in tables else load_robot(name)
    return spec, Kinematics(spec)


# --- independent NumPy model -----------------------------------------------------------


def rot_about(axis, angle):
    """Rotation by ``angle`` [rad] about the unit ``axis``, via the unit quaternion."""
    x, y, z = np.asarray(axis, dtype=float) * math.sin(angle / 2)
    w = math.cos(angle / 2)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def rpy_matrix(rpy):
    """URDF fixed-axis roll-pitch-yaw: ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    roll, pitch, yaw = rpy
    return rot_about((0, 0, 1), yaw) @ rot_about((0, 1, 0), pitch) @ rot_about((1, 0, 0), roll)


def transform(xyz=(0.0, 0.0, 0.0), R=None):
    """4x4 homogeneous transform."""
    T = np.eye(4)
    T[:3, :3] = np.eye(3) if R is None else R
    T[:3, 3] = xyz
    return T


@dataclass
class Fk:
    """NumPy forward kinematics at one state (body frame unless named world).

    Attributes:
        R_wb, p_wb: platform rotation and position (world from body).
        ee_world, R_ee_world: end-effector position and orientation, world frame.
        ee_body: end-effector position, body frame.
        origins, axes: joint origins and joint axes (3 x n), body frame.
        coms: link CoMs (3 x n), body frame.
        masses: link masses (n,).
        cog: arm CoG, body frame (3,).
    """

    R_wb: np.ndarray
    p_wb: np.ndarray
    ee_world: np.ndarray
    R_ee_world: np.ndarray
    ee_body: np.ndarray
    origins: np.ndarray
    axes: np.ndarray
    coms: np.ndarray
    masses: np.ndarray
    cog: np.ndarray


def platform_transform(spec, x):
    """``Trans(x, y, z) Rz(yaw)``, inactive DoFs at ``spec.platform.fixed`` (default 0)."""
    pose = {dof: float(spec.platform.fixed.get(dof, 0.0)) for dof in ("x", "y", "z", "yaw")}
    for i, dof in enumerate(spec.platform.dofs):
        pose[dof] = float(x[i])
    return transform((pose["x"], pose["y"], pose["z"]), rot_about((0, 0, 1), pose["yaw"]))


def numpy_fk(spec, x):
    """Forward kinematics of ``spec`` at state ``x`` from its fields alone."""
    x = np.asarray(x, dtype=float)
    T_wb = platform_transform(spec, x)
    T = transform(spec.mount_xyz, rpy_matrix(spec.mount_rpy))
    origins, axes, coms = [], [], []
    for j, qi in zip(spec.joints, x[spec.n_platform :], strict=True):
        T = T @ transform(j.xyz, rpy_matrix(j.rpy))
        origins.append(T[:3, 3].copy())
        axes.append(T[:3, :3] @ np.asarray(j.axis))
        T = T @ transform(R=rot_about(j.axis, qi))
        coms.append((T @ np.append(j.link.com, 1.0))[:3])
    T_ee = T @ transform(spec.ee_xyz, rpy_matrix(spec.ee_rpy))
    T_we = T_wb @ T_ee
    masses = np.array([j.link.mass for j in spec.joints])
    coms = np.array(coms).T
    return Fk(
        R_wb=T_wb[:3, :3],
        p_wb=T_wb[:3, 3],
        ee_world=T_we[:3, 3],
        R_ee_world=T_we[:3, :3],
        ee_body=T_ee[:3, 3],
        origins=np.array(origins).T,
        axes=np.array(axes).T,
        coms=coms,
        masses=masses,
        cog=coms @ masses / masses.sum(),
    )


def ee_arm_jacobian(spec, x):
    """World-frame EE position Jacobian w.r.t. the arm joints: ``R_wb a_i x (p_e - o_i)``."""
    fk = numpy_fk(spec, x)
    cols = [np.cross(fk.axes[:, i], fk.ee_body - fk.origins[:, i]) for i in range(spec.n_joints)]
    return fk.R_wb @ np.array(cols).T


def cog_jacobian(spec, x):
    """Body-frame arm CoG Jacobian: joint ``i`` moves links ``k >= i`` about its axis."""
    fk = numpy_fk(spec, x)
    n = spec.n_joints
    J = np.zeros((3, n))
    for i in range(n):
        for k in range(i, n):
            J[:, i] += fk.masses[k] * np.cross(fk.axes[:, i], fk.coms[:, k] - fk.origins[:, i])
    return J / fk.masses.sum()


def fd_jacobian(f, x, h=1e-6):
    """Central finite differences of a vector function ``f`` at ``x``."""
    cols = []
    for i in range(len(x)):
        e = np.zeros(len(x))
        e[i] = h
        cols.append((f(x + e) - f(x - e)) / (2 * h))
    return np.array(cols).T


def jeq_gram(spec, x, tracked):
    """``J_eq J_eq^T`` for the ``tracked`` coordinates (rows in that order)."""
    J = ee_arm_jacobian(spec, x)[["xyz".index(c) for c in tracked]]
    return J @ J.T


def random_states(spec, n, seed):
    """States with the joints inside their limits and the platform within 1 of the origin."""
    rng = np.random.default_rng(seed)
    lo = np.array([-1.0] * spec.n_platform + [j.lower for j in spec.joints])
    hi = np.array([1.0] * spec.n_platform + [j.upper for j in spec.joints])
    return rng.uniform(lo, hi, size=(n, spec.nx))


def residual_of(task, kin, terminal=False):
    """``task``'s stage (or terminal, ``u = None``) residual as ``f(x, u, u_prev, p)``."""
    x, u, u_prev = (ca.SX.sym(n, kin.nx) for n in ("x", "u", "u_prev"))
    p = ca.SX.sym("p", task.param_size)
    stage = Stage(kin, x, None if terminal else u, u_prev, p, 0.1)
    r = task.terminal_residual(stage) if terminal else task.residual(stage)
    f = ca.Function("r", [x, u, u_prev, p], [r])

    def evaluate(x, u=None, u_prev=None, p=None):
        zeros = np.zeros(kin.nx)
        args = [zeros if v is None else v for v in (u, u_prev)]
        return np.asarray(f(x, *args, np.zeros(task.param_size) if p is None else p)).ravel()

    return evaluate


# --- the NumPy model itself ------------------------------------------------------------


def test_numpy_rpy_is_fixed_axis_roll_pitch_yaw():
    R = rpy_matrix((math.pi / 2, 0.0, math.pi / 2))  # roll first, about fixed axes
    np.testing.assert_allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(R @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(
        rot_about((0, 1, 0), math.pi / 2) @ [0, 0, -1], [-1, 0, 0], atol=1e-15
    )


# (robot, state, ee body, ee world, cog body): worked out by hand from the robot files
HAND_CASES = {
    "x8 straight, yawed": (
        "x8-3dof", [1, 2, 3, 0.7, 0, 0, 0], [0, 0, -0.48], [1, 2, 2.52],
        [0, 0, -(0.06 * 0.12 + 0.10 * 0.23 + 0.08 * 0.40) / 0.24]
    ),
    "x8 pan and shoulder 90 deg": (
        "x8-3dof", [1, 2, 3, math.pi / 2, math.pi / 2, math.pi / 2, 0], [0, -0.34, -0.14],
        [1.34, 2, 2.86],
        [0, -(0.10 * 0.09 + 0.08 * 0.26) / 0.24, -(0.06 * 0.12 + (0.10 + 0.08) * 0.14) / 0.24]
    ),
    "planar shoulder 90 deg": (
        "planar-2dof", [2, 1, math.pi / 2, 0], [0, 0.5, -0.05], [0, 2.5, 0.95], [0, 0.225, -0.05]
    ),
    "planar straight": ("planar-2dof", [2, 1, 0, 0], [0, 0, -0.55], [0, 2, 0.45], [0, 0, -0.275]),
    "mount rpy, q = 0": (
        "hand-1dof", [0, 0, 0, 0, 0], [0, 0.5, -0.1], [0, 0.5, -0.1], [0, 0.3, -0.1]
    ),
    "mount rpy, q = 90 deg": (
        "hand-1dof", [1, 0, 0, math.pi / 2, math.pi / 2], [0, 0.2, 0.2], [0.8, 0, 0.2],
        [0, 0.2, 0.0]
    ),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(HAND_CASES))
def test_numpy_fk_and_kinematics_match_hand_derived_values(case):
    name, x, ee_body, ee_world, cog = HAND_CASES[case]
    spec, kin = robot(name)
    fk = numpy_fk(spec, x)
    np.testing.assert_allclose(fk.ee_body, ee_body, atol=1e-15)
    np.testing.assert_allclose(fk.ee_world, ee_world, atol=1e-15)
    np.testing.assert_allclose(fk.cog, cog, atol=1e-15)
    np.testing.assert_allclose(np.asarray(kin.ee_position(x)).ravel(), ee_world, atol=1e-15)
    np.testing.assert_allclose(np.asarray(kin.cog_body(x)).ravel(), cog, atol=1e-15)


@pytest.mark.parametrize("name", ROBOTS)
def test_geometric_jacobians_match_finite_differences_of_numpy_fk(name):
    spec, _ = robot(name)
    npf = spec.n_platform
    for x in random_states(spec, 5, seed=1):
        fd_ee = fd_jacobian(lambda y: numpy_fk(spec, y).ee_world, x)
        fd_cog = fd_jacobian(lambda y: numpy_fk(spec, y).cog, x)
        # FD error: truncation h^2 |f'''| / 6 ~ 1e-13, rounding ~ 1e-16 / h ~ 1e-10
        np.testing.assert_allclose(ee_arm_jacobian(spec, x), fd_ee[:, npf:], atol=1e-9)
        np.testing.assert_allclose(cog_jacobian(spec, x), fd_cog[:, npf:], atol=1e-9)
        np.testing.assert_allclose(fd_cog[:, :npf], 0.0, atol=1e-9)  # body frame


@pytest.mark.parametrize("name", ROBOTS)
def test_kinematics_functions_match_numpy_fk(name):
    spec, kin = robot(name)
    npf = spec.n_platform
    for x in random_states(spec, 10, seed=2):
        fk = numpy_fk(spec, x)
        got = {
            k: np.asarray(getattr(kin, k)(x))
            for k in ("ee_position", "ee_rotation", "ee_position_body", "joint_positions_body",
                      "joint_positions", "cog_body", "cog_jacobian", "ee_jacobian")
        }  # fmt: skip
        np.testing.assert_allclose(got["ee_position"].ravel(), fk.ee_world, atol=1e-14)
        np.testing.assert_allclose(got["ee_rotation"], fk.R_ee_world, atol=1e-14)
        np.testing.assert_allclose(got["ee_position_body"].ravel(), fk.ee_body, atol=1e-14)
        np.testing.assert_allclose(got["joint_positions_body"], fk.origins, atol=1e-14)
        world = fk.R_wb @ fk.origins + fk.p_wb[:, None]
        np.testing.assert_allclose(got["joint_positions"], world, atol=1e-14)
        np.testing.assert_allclose(got["cog_body"].ravel(), fk.cog, atol=1e-14)
        np.testing.assert_allclose(got["cog_jacobian"], cog_jacobian(spec, x), atol=1e-14)
        np.testing.assert_allclose(
            got["ee_jacobian"][:, npf:], ee_arm_jacobian(spec, x), atol=1e-14
        )
        depths = -np.append(fk.origins[2, 1:], fk.ee_body[2])
        np.testing.assert_allclose(np.asarray(kin.clearance()(x)).ravel(), depths, atol=1e-14)


# --- h1: end-effector tracking (eq. 8-9) -----------------------------------------------


@pytest.mark.parametrize("tracked", TRACKINGS)
@pytest.mark.parametrize("name", ROBOTS)
def test_tracking_residual_is_ee_minus_reference_for_tracked_coordinates_in_order(name, tracked):
    spec, kin = robot(name)
    task = EndEffectorTracking(Waypoints([[0, 0, 0]], [0.0]), tracked=tracked)
    assert task.param_size == 3
    assert task.residual_size(kin) == len(tracked)
    stage, terminal = residual_of(task, kin), residual_of(task, kin, terminal=True)
    rows = ["xyz".index(c) for c in tracked]
    rng = np.random.default_rng(3)
    for x in random_states(spec, 10, seed=4):
        ref = rng.uniform(-1.0, 1.0, 3)
        expected = (numpy_fk(spec, x).ee_world - ref)[rows]
        u, u_prev = rng.normal(size=(2, spec.nx))
        np.testing.assert_allclose(stage(x, u, u_prev, ref), expected, atol=1e-14)
        np.testing.assert_allclose(terminal(x, None, u_prev, ref), expected, atol=1e-14)


def orientation_task(R_d):
    """Full-pose tracking with desired EE orientation ``R_d``."""
    return EndEffectorTracking(Waypoints([[0, 0, 0]], [0.0]), "xyz", orientation=R_d)


@pytest.mark.parametrize("name", ROBOTS)
def test_tracking_orientation_rows_are_sin_angle_times_axis_of_error_rotation(name):
    """With ``R_d = R rot(k, a)^T`` (so ``R_d^T R = rot(k, a)``) the rows are ``sin(a) k``."""
    spec, kin = robot(name)
    rng = np.random.default_rng(5)
    for x in random_states(spec, 4, seed=6):
        fk = numpy_fk(spec, x)
        k = rng.normal(size=3)
        k /= np.linalg.norm(k)
        angle = rng.uniform(0.1, 3.0)
        task = orientation_task(fk.R_ee_world @ rot_about(k, angle).T)
        assert task.residual_size(kin) == 6
        ref = rng.uniform(-1.0, 1.0, 3)
        expected = np.concatenate([fk.ee_world - ref, math.sin(angle) * k])
        np.testing.assert_allclose(residual_of(task, kin)(x, p=ref), expected, atol=1e-13)
        terminal = residual_of(task, kin, terminal=True)(x, p=ref)
        np.testing.assert_allclose(terminal, expected, atol=1e-13)


def test_tracking_orientation_rows_follow_the_state_for_a_fixed_desired_rotation():
    spec, kin = robot("tilted-4dof")
    R_d = rpy_matrix((0.4, -0.7, 1.1))
    r = residual_of(orientation_task(R_d), kin)
    for x in random_states(spec, 10, seed=7):
        R = numpy_fk(spec, x).R_ee_world
        E = R_d.T @ R - R.T @ R_d
        expected = 0.5 * np.array([E[2, 1], E[0, 2], E[1, 0]])
        np.testing.assert_allclose(r(x)[3:], expected, atol=1e-14)


def test_tracking_rejects_an_orientation_that_is_not_a_rotation():
    with pytest.raises(ConfigError, match="3x3 rotation matrix"):
        orientation_task(2.0 * np.eye(3))
    with pytest.raises(ConfigError, match="3x3 rotation matrix"):
        orientation_task(np.eye(2))


def test_tracking_param_values_are_the_reference_samples():
    points = [[0.1, -0.2, 1.0], [0.5, 0.3, 1.2], [-0.4, 0.0, 0.8]]
    task = EndEffectorTracking(Waypoints(points, [1.0, 2.0, 4.0]), tracked="yz")
    values = task.param_values(np.array([0.0, 1.0, 2.0, 4.0, 9.0]))
    # the first point is held before its time, the waypoints are passed exactly, the last held
    expected = [points[0], points[0], points[1], points[2], points[2]]
    np.testing.assert_allclose(values, expected, atol=1e-15)
    assert task.tracked == "yz"
    assert EndEffectorTracking(Waypoints(points, [1.0, 2.0, 4.0]), ["z", "x"]).tracked == "zx"


# --- h2, h3: arm CoG alignment and velocity (eq. 10-12) --------------------------------


@pytest.mark.parametrize("target", [(0.0, 0.0), (0.03, -0.02)])
@pytest.mark.parametrize("name", ROBOTS)
def test_cog_alignment_residual_is_body_cog_xy_minus_target(name, target):
    spec, kin = robot(name)
    task = CogAlignment(target_xy=target)
    assert (task.param_size, task.residual_size(kin)) == (0, 2)
    stage, terminal = residual_of(task, kin), residual_of(task, kin, terminal=True)
    rng = np.random.default_rng(8)
    for x in random_states(spec, 10, seed=9):
        expected = numpy_fk(spec, x).cog[:2] - np.array(target)
        u, u_prev = rng.normal(size=(2, spec.nx))
        np.testing.assert_allclose(stage(x, u, u_prev), expected, atol=1e-14)
        np.testing.assert_allclose(terminal(x, None, u_prev), expected, atol=1e-14)


@pytest.mark.parametrize("name", ROBOTS)
def test_cog_velocity_residual_is_cog_jacobian_xy_times_joint_rates(name):
    spec, kin = robot(name)
    task = CogVelocity()
    assert (task.param_size, task.residual_size(kin)) == (0, 2)
    r = residual_of(task, kin)
    rng = np.random.default_rng(10)
    for x in random_states(spec, 10, seed=11):
        u, u_prev = rng.normal(size=(2, spec.nx))  # platform rates must not count
        expected = (cog_jacobian(spec, x) @ u[spec.n_platform :])[:2]
        assert np.linalg.norm(expected) > 1e-3
        np.testing.assert_allclose(r(x, u, u_prev), expected, atol=1e-14)


# --- h4, h5: manipulability and condition number of J_eq J_eq^T (eq. 13-16) -------------


def well_conditioned_states(spec, tracked, n, seed):
    """Random states whose ``J_eq J_eq^T`` has a condition number below 1e3."""
    states = []
    for x in random_states(spec, 4 * n, seed):
        ev = np.linalg.eigvalsh(jeq_gram(spec, x, tracked))
        if ev[0] > 1e-3 * ev[-1]:
            states.append(x)
    assert len(states) >= n
    return states[:n]


@pytest.mark.parametrize("eps", [None, 0.0, 1e-3])
@pytest.mark.parametrize(("name", "tracked"), JEQ_CASES)
def test_manipulability_residual_is_inverse_of_det_plus_eps(name, tracked, eps):
    """``r = 1 / (D + eps)``, ``D = det(J_eq J_eq^T)`` (m x m for m tracked coordinates)."""
    spec, kin = robot(name)
    task = Manipulability(tracked) if eps is None else Manipulability(tracked, eps=eps)
    eps = 1e-9 if eps is None else eps  # the documented default
    assert (task.param_size, task.residual_size(kin)) == (0, 1)
    stage, terminal = residual_of(task, kin), residual_of(task, kin, terminal=True)
    for x in well_conditioned_states(spec, tracked, 8, seed=12):
        A = jeq_gram(spec, x, tracked)
        assert A.shape == (len(tracked), len(tracked))
        expected = 1.0 / (np.linalg.det(A) + eps)
        np.testing.assert_allclose(stage(x), [expected], rtol=1e-11)
        np.testing.assert_allclose(terminal(x), [expected], rtol=1e-11)


def exact_rho(spec, x, tracked, delta):
    """``(lambda_max + delta) / (lambda_min + delta)`` of ``J_eq J_eq^T`` by ``eigvalsh``."""
    ev = np.linalg.eigvalsh(jeq_gram(spec, x, tracked))
    return (ev[-1] + delta) / (max(ev[0], 0.0) + delta)


@pytest.mark.parametrize("delta", [0.0, 1e-3])
@pytest.mark.parametrize(("name", "tracked"), JEQ_CASES)
def test_condition_number_residual_is_one_minus_rho(name, tracked, delta):
    spec, kin = robot(name)
    task = ConditionNumber(tracked, delta=delta, kink=1e-12)
    assert (task.param_size, task.residual_size(kin)) == (0, 1)
    stage, terminal = residual_of(task, kin), residual_of(task, kin, terminal=True)
    for x in well_conditioned_states(spec, tracked, 8, seed=13):
        rho = exact_rho(spec, x, tracked, delta)
        if len(tracked) == 1:
            assert rho == 1.0
        # rho > 1 (r < 0) here except for the 1x1 case where rho = 1 exactly
        np.testing.assert_allclose(stage(x), [1.0 - rho], rtol=1e-9, atol=1e-13)
        np.testing.assert_allclose(terminal(x), [1.0 - rho], rtol=1e-9, atol=1e-13)


@pytest.mark.parametrize(("name", "tracked"), JEQ_CASES)
def test_condition_number_default_kink_rounds_rho_by_about_one_percent_at_most(name, tracked):
    """Default ``kink = 1e-4`` (3x3 only): ~kink/2 relative away from coalescence, a few
    percent at most at it (spectral module doc); exact for 1x1 and 2x2 matrices."""
    spec, kin = robot(name)
    r = residual_of(ConditionNumber(tracked), kin)
    rel = []
    for x in well_conditioned_states(spec, tracked, 20, seed=14):
        rho = exact_rho(spec, x, tracked, 1e-9)
        rel.append(abs(1.0 - r(x)[0] - rho) / rho)
    if len(tracked) < 3:
        assert max(rel) < 1e-9
    else:
        assert 1e-5 < np.median(rel) < 5e-4  # the rounding is applied: ~kink / 2 = 5e-5
        assert max(rel) < 0.03


@pytest.mark.parametrize("eigenvalues", [(2.0, 2.0, 1.0), (2.0, 1.0, 1.0)], ids=["max", "min"])
def test_kink_rounds_rho_where_two_extreme_eigenvalues_coincide(eigenvalues):
    """At a repeated largest (``acos`` scaling) or smallest (``kink s^2`` under the root)
    eigenvalue, ``kink = 1e-4`` rounds rho by well over its ~kink/2 rounding elsewhere but
    at most ~sqrt(kink) = 1e-2; ``kink = 1e-12`` is exact there to ~sqrt(1e-12)."""
    A = ca.SX.sym("A", 3, 3)
    Q = rot_about(np.array([1.0, 2.0, 2.0]) / 3.0, 0.7)
    S = Q @ np.diag(eigenvalues) @ Q.T
    rel = {}
    for kink in (1e-12, 1e-4):
        rho = float(ca.Function("rho", [A], [condition_number(A, 0.0, kink)])(S))
        rel[kink] = abs(rho - 2.0) / 2.0
    assert rel[1e-12] < 3e-6
    assert 5e-4 < rel[1e-4] < 3e-2  # measured: 1.5e-3 (max pair), 1.0e-2 (min pair)


def test_condition_number_at_singular_configuration_is_regularised_by_delta():
    spec, kin = robot("planar-2dof")
    x = np.array([0.3, 1.0, 0.0, 0.0])  # arm stretched: J_eq J_eq^T has rank 1
    lam = np.linalg.eigvalsh(jeq_gram(spec, x, "yz"))
    np.testing.assert_allclose(lam, [0.0, 0.5**2 + 0.25**2], atol=1e-15)
    for delta in (1e-9, 1e-4):
        r = residual_of(ConditionNumber("yz", delta=delta), kin)(x)
        np.testing.assert_allclose(r, [1.0 - (lam[-1] + delta) / delta], rtol=1e-9)
    D = residual_of(Manipulability("yz", eps=1e-6), kin)(x)
    np.testing.assert_allclose(D, [1e6], rtol=1e-9)


@pytest.mark.parametrize("name", ["x8-3dof", "tilted-4dof"])
def test_square_or_wide_jeq_is_accepted(name):
    _, kin = robot(name)
    for task in (Manipulability("xyz"), ConditionNumber("xyz")):
        assert task.residual_size(kin) == 1


def test_more_tracked_coordinates_than_arm_joints_is_config_error():
    _, kin = robot("planar-2dof")
    for build in (
        lambda: kin.manipulability("xyz"),
        lambda: kin.condition_number("xyz"),
        lambda: Manipulability("xyz").residual_size(kin),
        lambda: ConditionNumber("xyz").residual_size(kin),
    ):
        with pytest.raises(ConfigError, match="3 tracked coordinates but only 2 arm joints"):
            build()


@pytest.mark.parametrize("tracked", ["xx", "", "xw"])
def test_tracked_coordinates_must_be_distinct_known_and_non_empty(tracked):
    with pytest.raises(ConfigError, match="tracked"):
        Kinematics.tracked_rows(tracked)
    with pytest.raises(ConfigError, match="tracked"):
        EndEffectorTracking(Waypoints([[0, 0, 0]], [0.0]), tracked=tracked)


# --- control rate (eq. 4) --------------------------------------------------------------


@pytest.mark.parametrize("name", ROBOTS)
def test_control_rate_is_command_minus_previous_and_terminal_is_last_command(name):
    spec, kin = robot(name)
    task = ControlRate()
    assert (task.param_size, task.residual_size(kin)) == (0, spec.nx)
    stage, terminal = residual_of(task, kin), residual_of(task, kin, terminal=True)
    rng = np.random.default_rng(15)
    for x in random_states(spec, 5, seed=16):
        u, u_prev = rng.normal(size=(2, spec.nx))
        np.testing.assert_array_equal(stage(x, u, u_prev), u - u_prev)
        np.testing.assert_array_equal(terminal(x, None, u_prev), u_prev)
