"""Kinematics against finite differences, physical invariants and NumPy's eigensolver."""

import casadi as ca
import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.robot.kinematics import Kinematics
from aeromanip.robot.loader import load_robot
from aeromanip.robot.spectral import extreme_eigenvalues

ROBOTS = ["planar-2dof", "x8-3dof"]
TRACKED = {"planar-2dof": "yz", "x8-3dof": "xyz"}


def random_states(spec, n, seed=0):
    rng = np.random.default_rng(seed)
    lo = np.array([-2.0] * spec.n_platform + [j.lower for j in spec.joints])
    hi = np.array([2.0] * spec.n_platform + [j.upper for j in spec.joints])
    return rng.uniform(lo, hi, size=(n, spec.nx))


def num(f, x):
    return np.asarray(f(x), dtype=float)


def fd_jacobian(f, x, h=1e-6):
    cols = []
    for i in range(len(x)):
        e = np.zeros_like(x)
        e[i] = h
        cols.append((num(f, x + e) - num(f, x - e)).ravel() / (2 * h))
    return np.array(cols).T


@pytest.fixture(scope="module", params=ROBOTS)
def kin(request):
    return Kinematics(load_robot(request.param))


def test_ee_jacobian_matches_finite_differences(kin):
    for x in random_states(kin.spec, 20):
        np.testing.assert_allclose(
            num(kin.ee_jacobian, x), fd_jacobian(kin.ee_position, x), atol=1e-8
        )


def test_cog_jacobian_matches_finite_differences(kin):
    npf = kin.n_platform
    for x in random_states(kin.spec, 20, seed=1):
        fd = fd_jacobian(kin.cog_body, x)[:, npf:]
        np.testing.assert_allclose(num(kin.cog_jacobian, x), fd, atol=1e-8)


def test_cog_in_body_frame_does_not_depend_on_platform_pose(kin):
    rng = np.random.default_rng(2)
    for x in random_states(kin.spec, 10, seed=3):
        y = x.copy()
        y[: kin.n_platform] = rng.uniform(-5, 5, kin.n_platform)
        np.testing.assert_allclose(num(kin.cog_body, x), num(kin.cog_body, y), atol=1e-14)


def test_cog_is_mass_weighted_mean_of_link_coms():
    """A second, NumPy-only evaluation: the CoG of a straight hanging arm lies on its axis."""
    spec = load_robot("x8-3dof")
    kin = Kinematics(spec)
    x = np.zeros(spec.nx)
    depths = [0.0, 0.04, 0.22]  # joint origins below the mount
    coms = [d + abs(j.link.com[2]) for d, j in zip(depths, spec.joints, strict=True)]
    masses = [j.link.mass for j in spec.joints]
    expected_z = spec.mount_xyz[2] - np.dot(masses, coms) / sum(masses)
    np.testing.assert_allclose(num(kin.cog_body, x).ravel(), [0, 0, expected_z], atol=1e-15)


def test_yaw_rotates_end_effector_about_platform_z_axis():
    spec = load_robot("x8-3dof")
    kin = Kinematics(spec)
    for x in random_states(spec, 10, seed=4):
        psi = 0.7
        y = x.copy()
        y[3] += psi
        c, s = np.cos(psi), np.sin(psi)
        Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        rel = num(kin.ee_position, x).ravel() - x[:3]
        np.testing.assert_allclose(num(kin.ee_position, y).ravel() - y[:3], Rz @ rel, atol=1e-14)


def test_platform_translation_moves_end_effector_rigidly(kin):
    for x in random_states(kin.spec, 5, seed=5):
        J = num(kin.ee_jacobian, x)
        # every translational platform DoF moves the EE one-to-one along its axis
        for i, dof in enumerate(kin.spec.platform.dofs):
            if dof in "xyz":
                expected = np.zeros(3)
                expected["xyz".index(dof)] = 1.0
                np.testing.assert_allclose(J[:, i], expected, atol=1e-14)


def test_condition_number_and_manipulability_match_numpy(kin):
    tracked = TRACKED[kin.spec.name]
    jeq, rho = kin.jeq(tracked), kin.condition_number(tracked, delta=0.0)
    D = kin.manipulability(tracked)
    for x in random_states(kin.spec, 50, seed=6):
        J = num(jeq, x)
        A = J @ J.T
        ev = np.linalg.eigvalsh(A)
        assert float(rho(x)) >= 1.0
        np.testing.assert_allclose(float(rho(x)), ev[-1] / ev[0], rtol=1e-7)
        np.testing.assert_allclose(float(D(x)), np.linalg.det(A), rtol=1e-9, atol=1e-15)


def test_condition_number_is_finite_and_smooth_at_singular_configuration():
    spec = load_robot("planar-2dof")
    kin = Kinematics(spec)
    rho = kin.condition_number("yz")  # default regularisation
    x = np.zeros(spec.nx)  # arm fully stretched: J_eq has rank 1
    value = float(rho(x))
    assert np.isfinite(value) and value > 1e6
    grad = ca.Function(
        "g", [kin.symbols()[0]], [ca.jacobian(rho(kin.symbols()[0]), kin.symbols()[0])]
    )
    assert np.all(np.isfinite(np.asarray(grad(x))))


@pytest.mark.parametrize("n", [2, 3])
def test_closed_form_eigenvalues_match_numpy_on_random_spd(n):
    A = ca.SX.sym("A", n, n)
    f = ca.Function("f", [A], list(extreme_eigenvalues(A)))
    rng = np.random.default_rng(7)
    for _ in range(200):
        M = rng.normal(size=(n, n))
        S = M @ M.T + 1e-3 * np.eye(n)
        ev = np.linalg.eigvalsh(S)
        lo, hi = (float(v) for v in f(S))
        # eigenvalue errors scale with ||A|| (Weyl): absolute tolerance relative to lambda_max
        np.testing.assert_allclose([lo, hi], [ev[0], ev[-1]], rtol=1e-9, atol=1e-10 * ev[-1])


def test_isotropic_matrix_has_condition_number_one_and_finite_gradient():
    A = ca.SX.sym("A", 3, 3)
    lo, hi = extreme_eigenvalues(A)
    grad = ca.Function("g", [A], [ca.gradient(hi / lo, A)])
    lam = ca.Function("l", [A], [lo, hi])
    S = 0.2 * np.eye(3)
    # at coalescence the documented error bound is sqrt(kink) = 1e-6, relative
    np.testing.assert_allclose([float(v) for v in lam(S)], [0.2, 0.2], rtol=2e-6)
    assert np.all(np.isfinite(np.asarray(grad(S))))


def test_clearance_is_depth_below_base(kin):
    f = kin.clearance()
    for x in random_states(kin.spec, 10, seed=8):
        P = num(kin.joint_positions_body, x)
        ee = num(kin.ee_position_body, x).ravel()
        expected = np.concatenate([-P[2, 1:], [-ee[2]]])
        np.testing.assert_allclose(num(f, x).ravel(), expected, atol=1e-15)


def test_bad_tracked_coordinates_and_points_are_clear_errors(kin):
    with pytest.raises(ConfigError, match="unknown coordinate 'w'"):
        kin.jeq("w")
    with pytest.raises(ConfigError, match="unknown point 'elbow'"):
        kin.clearance(["elbow"])
    if kin.n_joints < 3:
        with pytest.raises(ConfigError, match="always singular"):
            kin.manipulability("xyz")


def test_kink_smoothing_error_is_small_and_bounded():
    """The task's kink smoothing (1e-4) changes rho by a few percent at most, and less
    away from repeated eigenvalues: measured on random arm configurations."""
    kin = Kinematics(load_robot("x8-3dof"))
    exact, smooth = kin.condition_number("xyz", kink=1e-12), kin.condition_number("xyz", kink=1e-4)
    rel = []
    for x in random_states(kin.spec, 300, seed=9):
        a, b = float(exact(x)), float(smooth(x))
        assert b >= 1.0
        rel.append(abs(b - a) / a)
    assert np.median(rel) < 1e-3  # ~kink/2 away from coalescence
    assert max(rel) < 0.03  # ~sqrt(kink) at coalescence (measured: 1.6% over 1000 states)
