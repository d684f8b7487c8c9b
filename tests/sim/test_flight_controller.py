"""Flight controller and mixer at their edges, each checked against an independent source.

Expected values come from hand derivations (small round inertias, masses and gains), a NumPy
re-derivation (allocation matrix from the rotor angles, Rodrigues rotations) or a physical law
(``tau = J alpha + w x J w``). No MuJoCo: every test drives ``Mixer`` / ``FlightController``
directly. Frames: world ENU, body FLU; ``R`` maps body to world.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.sim.flight_controller import FlightController, FlightGains, Mixer, rotor_layout

G = 9.81
TOL = 1e-12
K_M = 0.02  # [m] yaw moment per newton of rotor thrust
ARM = 0.1 * math.sqrt(2.0)  # quad rotors at (+-0.1, +-0.1) m: B entries are round numbers
F_MAX = 5.0  # [N]
MASS = 2.0  # [kg]
J_DIAG = (0.02, 0.03, 0.05)  # [kg m^2]
J_FULL = np.array([[0.02, 0.001, -0.002], [0.001, 0.03, 0.0015], [-0.002, 0.0015, 0.05]])
DT = 0.01  # [s]
E_Z = np.array([0.0, 0.0, 1.0])


def _rot(axis, angle):
    """Rodrigues: rotation by ``angle`` [rad] about the unit vector ``axis``."""
    k = np.asarray(axis, dtype=float)
    k = k / np.linalg.norm(k)
    K = _hat(k)
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def _hat(v):
    """Skew matrix with ``_hat(a) @ b == cross(a, b)``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _allocation(n, arm, k_m, coaxial=False):
    """Allocation matrix rebuilt from the documented layout (rows 1, y_i, -x_i, spin_i k_m)."""
    arms = n // 2 if coaxial else n
    rows = []
    for i in range(n):
        j = i // 2 if coaxial else i
        a = math.pi / arms + 2.0 * math.pi * j / arms  # rotor 1 front-left, counter-clockwise
        spin = 1.0 if j % 2 == 0 else -1.0
        if coaxial and i % 2:
            spin = -spin  # the lower rotor of a pair turns the other way
        rows.append((1.0, arm * math.sin(a), -arm * math.cos(a), spin * k_m))
    return np.array(rows).T


def _quad_mixer(f_max=F_MAX):
    """The round-number quad: B columns 1/4, +-2.5 (roll, pitch), +-12.5 (yaw)."""
    pos, spins = rotor_layout(4, ARM)
    return Mixer(pos, spins, K_M, f_max)


def _controller(gains=None, inertia=J_DIAG, outer_every=1, f_max=10.0):
    """A 2 kg quad controller at 100 Hz, thrust range [0, 40] N unless told otherwise."""
    return FlightController(MASS, inertia, _quad_mixer(f_max), DT, gains, outer_every)


def _level_hover(fc, yaw_ref=0.0):
    """Run one tick at rest on the reference so that F = m g e_z and R_sp = Rz(yaw_ref)."""
    z = (0.0, 0.0, 0.0)
    fc.outer(z, z, z, z)
    fc.inner(np.eye(3).ravel().tolist(), z, yaw_ref, 0.0)
    fc.i_rate = z


# --- rotor layout and allocation ---------------------------------------------------------


def test_rotor_layout_quad_is_front_left_first_counter_clockwise_alternating_spins():
    pos, spins = rotor_layout(4, ARM)
    # front-left, rear-left, rear-right, front-right (FLU body frame)
    np.testing.assert_allclose(pos, [[0.1, 0.1], [-0.1, 0.1], [-0.1, -0.1], [0.1, -0.1]], atol=TOL)
    np.testing.assert_array_equal(spins, [1.0, -1.0, 1.0, -1.0])


@pytest.mark.parametrize("n", [4, 6, 8])
def test_rotor_layout_flat_angles_are_pi_over_n_plus_2pi_i_over_n(n):
    pos, spins = rotor_layout(n, 0.3)
    angles = np.unwrap(np.arctan2(pos[:, 1], pos[:, 0]))
    np.testing.assert_allclose(angles, math.pi / n + 2.0 * math.pi * np.arange(n) / n, atol=TOL)
    np.testing.assert_allclose(np.hypot(pos[:, 0], pos[:, 1]), 0.3, atol=TOL)
    np.testing.assert_array_equal(spins, [(-1.0) ** i for i in range(n)])


def test_rotor_layout_coaxial_pairs_are_stacked_with_opposite_spins():
    pos, spins = rotor_layout(8, ARM, coaxial=True)
    quad_pos, quad_spins = rotor_layout(4, ARM)
    np.testing.assert_array_equal(pos[0::2], quad_pos)  # upper rotors: the flat quad
    np.testing.assert_array_equal(pos[1::2], quad_pos)  # lower rotors right under them
    np.testing.assert_array_equal(spins, [1.0, -1.0, -1.0, 1.0, 1.0, -1.0, -1.0, 1.0])
    np.testing.assert_array_equal(spins[1::2], -quad_spins)


@pytest.mark.parametrize(
    ("rotors", "coaxial"), [(3, False), (5, False), (2, False), (4, True), (6, True), (10, True)]
)
def test_rotor_layout_rejects_bad_counts_naming_the_key(rotors, coaxial):
    with pytest.raises(ConfigError, match=r"physics\.rotors: .*got " + str(rotors)):
        rotor_layout(rotors, 0.2, coaxial)


@pytest.mark.parametrize(("n", "coaxial"), [(4, False), (6, False), (8, False), (8, True)])
def test_allocation_matrix_and_unsaturated_mix_match_an_independent_derivation(n, coaxial):
    pos, spins = rotor_layout(n, 0.25, coaxial)
    mixer = Mixer(pos, spins, K_M, 8.0)
    A = _allocation(n, 0.25, K_M, coaxial)
    np.testing.assert_allclose(mixer.A, A, atol=TOL)
    # the rows of a symmetric layout are orthogonal: pinv(A) = A^T diag(1 / |row|^2)
    np.testing.assert_allclose(mixer.B, A.T / (A * A).sum(axis=1), atol=TOL)
    # with the thrust mid-range and small torques nothing saturates: A f is the demand
    rng = np.random.default_rng(n + coaxial)
    for _ in range(20):
        demand = np.array([n * 4.0, *rng.uniform(-0.3, 0.3, 2), rng.uniform(-0.05, 0.05)])
        f = mixer.mix(demand[0], demand[1:])
        assert np.all(f > 0.0) and np.all(f < 8.0)
        np.testing.assert_allclose(A @ f, demand, atol=TOL)


# --- mixer saturation ----------------------------------------------------------------------


def test_mixer_zero_thrust_and_zero_torque_gives_all_zero_rotors():
    assert _quad_mixer().mix_floats(0.0, 0.0, 0.0, 0.0) == [0.0, 0.0, 0.0, 0.0]


def test_mixer_zero_thrust_roll_pitch_is_kept_by_shifting_the_collective_up():
    mixer = _quad_mixer()
    # f_rp = 2.5 tx (1, 1, -1, -1) + 2.5 ty (-1, 1, 1, -1) = (0.25, 0.75, -0.25, -0.75);
    # shifted up by 0.75 so the lowest rotor sits at 0
    f = mixer.mix(0.0, (0.2, 0.1, 0.0))
    np.testing.assert_allclose(f, [1.0, 1.5, 0.5, 0.0], atol=TOL)
    np.testing.assert_allclose(_allocation(4, ARM, K_M) @ f, [3.0, 0.2, 0.1, 0.0], atol=TOL)


def test_mixer_zero_thrust_yaw_share_depends_on_the_rotor_at_zero():
    mixer = _quad_mixer()
    A = _allocation(4, ARM, K_M)
    # yaw share y = 12.5 tz (1, -1, 1, -1): +0.02 N m would lower rotor 4, already at 0 -> cut
    f = mixer.mix(0.0, (0.2, 0.1, 0.02))
    np.testing.assert_allclose(f, [1.0, 1.5, 0.5, 0.0], atol=TOL)
    np.testing.assert_allclose(A @ f, [3.0, 0.2, 0.1, 0.0], atol=TOL)
    # -0.02 N m raises rotor 4 and lowers rotors 1 and 3 (1.0 and 0.5 N, by 0.25): fits fully
    f = mixer.mix(0.0, (0.2, 0.1, -0.02))
    np.testing.assert_allclose(f, [0.75, 1.75, 0.25, 0.25], atol=TOL)
    np.testing.assert_allclose(A @ f, [3.0, 0.2, 0.1, -0.02], atol=TOL)


def test_mixer_small_thrust_yaw_is_cut_to_the_share_that_fits():
    # 0.1 N per rotor, yaw share +-0.2 N: alpha = min(x / -y) = 0.1 / 0.2 = 0.5
    f = _quad_mixer().mix(0.4, (0.0, 0.0, 0.016))
    np.testing.assert_allclose(f, [0.2, 0.0, 0.2, 0.0], atol=TOL)
    np.testing.assert_allclose(_allocation(4, ARM, K_M) @ f, [0.4, 0.0, 0.0, 0.008], atol=TOL)


def test_mixer_near_f_max_roll_is_kept_by_shifting_the_collective_down():
    # 4.9 N + 2.5 * 0.2 (1, 1, -1, -1) = (5.4, 5.4, 4.4, 4.4): shifted down by 0.4
    f = _quad_mixer().mix(19.6, (0.2, 0.0, 0.0))
    np.testing.assert_allclose(f, [5.0, 5.0, 4.0, 4.0], atol=TOL)
    np.testing.assert_allclose(_allocation(4, ARM, K_M) @ f, [18.0, 0.2, 0.0, 0.0], atol=TOL)


def test_mixer_near_f_max_yaw_is_cut_at_the_upper_bound():
    # 4 N per rotor, yaw share +-2 N: alpha = min((f_max - x) / y) = 1 / 2
    f = _quad_mixer().mix(16.0, (0.0, 0.0, 0.16))
    np.testing.assert_allclose(f, [5.0, 3.0, 5.0, 3.0], atol=TOL)
    np.testing.assert_allclose(_allocation(4, ARM, K_M) @ f, [16.0, 0.0, 0.0, 0.08], atol=TOL)


def test_mixer_thrust_above_the_range_saturates_every_rotor_at_f_max():
    np.testing.assert_allclose(_quad_mixer().mix(100.0, (0.0, 0.0, 0.0)), [5.0] * 4, atol=TOL)
    f = _quad_mixer().mix(100.0, (0.2, 0.0, 0.0))
    np.testing.assert_allclose(f, [5.0, 5.0, 4.0, 4.0], atol=TOL)


def test_mixer_roll_pitch_span_above_f_max_is_scaled_keeping_its_direction():
    mixer = _quad_mixer()
    A = _allocation(4, ARM, K_M)
    # roll only: f_rp = +-6 N, span 12 > 5 -> scale 5/12: rotors exactly at 0 and f_max
    f = mixer.mix(10.0, (2.4, 0.0, 0.0))
    np.testing.assert_allclose(f, [5.0, 5.0, 0.0, 0.0], atol=TOL)
    np.testing.assert_allclose(A @ f, [10.0, 1.0, 0.0, 0.0], atol=TOL)
    # roll and pitch: f_rp = (3, 9, -3, -9), span 18 -> scale 5/18
    f = mixer.mix(10.0, (2.4, 1.2, 0.0))
    np.testing.assert_allclose(f, [2.5 + 15 / 18, 5.0, 2.5 - 15 / 18, 0.0], atol=TOL)
    np.testing.assert_allclose(A @ f, [10.0, 2.4 * 5 / 18, 1.2 * 5 / 18, 0.0], atol=TOL)


@pytest.mark.parametrize(("n", "coaxial"), [(4, False), (6, False), (8, False), (8, True)])
def test_mixer_saturation_obeys_its_documented_priorities(n, coaxial):
    """Random demands: bounds; roll/pitch scaled only past f_max; thrust clipped to what fits
    around them; yaw scaled by alpha in [0, 1], maximal (alpha < 1 only against a bound)."""
    f_max = 5.0
    pos, spins = rotor_layout(n, 0.25, coaxial)
    mixer = Mixer(pos, spins, K_M, f_max)
    A = _allocation(n, 0.25, K_M, coaxial)
    B = A.T / (A * A).sum(axis=1)
    rng = np.random.default_rng(10 * n + coaxial)
    for _ in range(300):
        thrust = rng.uniform(-2.0, n * f_max + 5.0)
        tx, ty = rng.uniform(-0.4, 0.4, 2) * n  # up to about twice the roll/pitch range
        tz = rng.choice([-1.0, 1.0]) * rng.uniform(0.01, 0.15)
        f = mixer.mix(thrust, (tx, ty, tz))
        assert np.all(f >= 0.0) and np.all(f <= f_max)
        f_rp = B[:, 1] * tx + B[:, 2] * ty
        scale = min(1.0, f_max / np.ptp(f_rp))
        f_rp = f_rp * scale
        thrust_out = min(max(thrust, -n * f_rp.min()), n * (f_max - f_rp.max()))
        wrench = A @ f
        np.testing.assert_allclose(wrench[:3], [thrust_out, scale * tx, scale * ty], atol=TOL)
        alpha = wrench[3] / tz  # a quotient: bounds checked to 1e-9
        assert -1e-9 <= alpha <= 1.0 + 1e-9
        y = B[:, 3] * tz
        np.testing.assert_allclose(f, B[:, 0] * thrust_out + f_rp + alpha * y, atol=TOL)
        if alpha < 1.0 - 1e-9:  # some rotor that yaw moves sits on the bound it moves towards
            at_top = (y > 0) & np.isclose(f, f_max, rtol=0.0, atol=TOL)
            at_zero = (y < 0) & np.isclose(f, 0.0, rtol=0.0, atol=TOL)
            assert np.any(at_top | at_zero)


# --- outer loop ----------------------------------------------------------------------------


def test_outer_loop_position_and_velocity_pi_by_hand():
    fc = _controller()
    p, v, p_ref, v_ref = (0.0, 0.0, 0.0), (0.2, 0.1, 0.0), (0.4, -0.2, 0.1), (0.1, 0.0, 0.0)
    # velocity set-point = v_ref + 1.5 (p_ref - p) = (0.7, -0.3, 0.15); error (0.5, -0.4, 0.15)
    # acceleration = (3.5 * 0.5, 3.5 * -0.4, 4.0 * 0.15); integrator still zero
    fc.outer(p, v, p_ref, v_ref)
    np.testing.assert_allclose(fc.F, [2.0 * 1.75, 2.0 * -1.4, 2.0 * (0.6 + G)], atol=TOL)
    i_vel = (0.6 * 0.5 * DT, 0.6 * -0.4 * DT, 2.0 * 0.15 * DT)
    np.testing.assert_allclose(fc.i_vel, i_vel, atol=TOL)
    # second tick: the integrator of the first tick enters the acceleration, then grows
    fc.outer(p, v, p_ref, v_ref)
    a = np.array([1.75, -1.4, 0.6]) + i_vel
    np.testing.assert_allclose(fc.F, 2.0 * (a + G * E_Z), atol=TOL)
    np.testing.assert_allclose(fc.i_vel, 2.0 * np.array(i_vel), atol=TOL)


def test_outer_loop_speed_limits_keep_the_horizontal_direction():
    fc = _controller()
    z = (0.0, 0.0, 0.0)
    # set-point 1.5 (30, 40, 10) = (45, 60, 15): xy cut to 3 m/s along (3, 4) / 5, z to 2 m/s
    fc.outer(z, z, (30.0, 40.0, 10.0), z)
    # acceleration (3.5 * 1.8, 3.5 * 2.4, 4 * 2): tilt 30.5 deg, inside the 35 deg limit
    np.testing.assert_allclose(fc.F, [2.0 * 6.3, 2.0 * 8.4, 2.0 * (8.0 + G)], atol=TOL)
    fc.reset()
    fc.outer(z, z, (0.0, 0.0, -10.0), z)  # downwards: -2 m/s
    np.testing.assert_allclose(fc.F, [0.0, 0.0, 2.0 * (G - 8.0)], atol=TOL)


def test_outer_loop_tilt_limit_scales_horizontal_thrust_and_keeps_vertical():
    fc = _controller()
    z = (0.0, 0.0, 0.0)
    # horizontal force 2 * 3.5 * (1.8, 2.4) = (12.6, 16.8) N, |.| = 21 N > m g tan(35 deg)
    fc.outer(z, z, (30.0, 40.0, 0.0), z)
    fh = 2.0 * G * math.tan(math.radians(35.0))
    np.testing.assert_allclose(fc.F, [0.6 * fh, 0.8 * fh, 2.0 * G], atol=TOL)
    tilt = math.atan2(math.hypot(fc.F[0], fc.F[1]), fc.F[2])
    assert tilt == pytest.approx(math.radians(35.0), abs=TOL)
    # a custom limit: 20 deg, the vertical thrust floor at 0.1 m g also scales the horizontal
    fc = _controller(FlightGains(tilt_max=math.radians(20.0)))
    fc.outer(z, (0.0, 0.0, 5.0), (30.0, -40.0, -10.0), z)  # set-point z -2, error -7
    fz = 0.1 * 2.0 * G
    fh = fz * math.tan(math.radians(20.0))
    np.testing.assert_allclose(fc.F, [0.6 * fh, -0.8 * fh, fz], atol=TOL)


def test_outer_loop_floors_vertical_thrust_at_a_tenth_of_the_weight():
    fc = _controller()
    z = (0.0, 0.0, 0.0)
    fc.outer(z, (0.0, 0.0, 5.0), (0.0, 0.0, -10.0), z)  # acceleration 4 * -7 = -28 < -g
    np.testing.assert_allclose(fc.F, [0.0, 0.0, 0.1 * 2.0 * G], atol=TOL)
    fc.inner(np.eye(3).ravel().tolist(), z, 0.0, 0.0)
    assert fc.thrust == pytest.approx(0.1 * 2.0 * G, abs=TOL)


def test_velocity_integrator_is_clamped_per_axis_with_sign():
    gains = FlightGains(vel_i_xy=50.0, vel_i_z=50.0, vel_i_max=0.3)
    fc = _controller(gains)
    z = (0.0, 0.0, 0.0)
    # set-points (1.8, -2.4, 0.015): increments 50 * e * dt = (0.9, -1.2, 0.0075)
    fc.outer(z, z, (30.0, -40.0, 0.01), z)
    np.testing.assert_allclose(fc.i_vel, [0.3, -0.3, 50.0 * 0.015 * DT], atol=TOL)
    fc.outer(z, z, (-30.0, 40.0, -10.0), z)  # swing the other way: -0.3 + (-0.9), ...
    np.testing.assert_allclose(fc.i_vel, [-0.3, 0.3, -0.3], atol=TOL)


def test_collective_thrust_is_f_dot_current_b3_clipped_to_the_rotor_range():
    fc = _controller()
    z = (0.0, 0.0, 0.0)
    fc.outer(z, z, (0.4, -0.2, 0.1), z)
    F = np.array(fc.F)
    R = _rot((1.0, 2.0, 0.5), 0.4)
    fc.inner(R.ravel().tolist(), z, 0.0, 0.0)
    assert fc.thrust == pytest.approx(float(F @ R[:, 2]), abs=TOL)
    fc.inner(_rot((1.0, 0.0, 0.0), math.pi).ravel().tolist(), z, 0.0, 0.0)  # upside down
    assert fc.thrust == 0.0
    fc = _controller(f_max=4.0)  # 16 N of rotor thrust for a 19.62 N weight
    fc.outer(z, z, z, z)
    fc.inner(np.eye(3).ravel().tolist(), z, 0.0, 0.0)
    assert fc.thrust == 16.0
    np.testing.assert_allclose(fc.motors, [4.0] * 4, atol=TOL)


# --- desired attitude and attitude error ---------------------------------------------------


@pytest.mark.parametrize(
    ("p_ref", "yaw_ref"),
    [((0.0, 0.0, 0.0), 0.7), ((0.3, 0.0, 0.0), 0.0), ((0.0, -0.4, 0.2), 0.0), ((0.3, 0.3, 0), 2.5)],
)
def test_desired_attitude_has_b3_along_f_and_heading_in_the_body_xz_plane(p_ref, yaw_ref):
    fc = _controller()
    z = (0.0, 0.0, 0.0)
    fc.outer(z, z, p_ref, z)
    fc.inner(np.eye(3).ravel().tolist(), z, yaw_ref, 0.0)
    R_sp, F = fc.R_sp, np.array(fc.F)
    np.testing.assert_allclose(R_sp.T @ R_sp, np.eye(3), atol=TOL)
    assert np.linalg.det(R_sp) == pytest.approx(1.0, abs=TOL)
    np.testing.assert_allclose(R_sp[:, 2], F / np.linalg.norm(F), atol=TOL)
    # b1 is the heading h projected on the plane normal to b3 (b2 = b3 x h / |b3 x h|)
    h = np.array([math.cos(yaw_ref), math.sin(yaw_ref), 0.0])
    b1 = h - (h @ R_sp[:, 2]) * R_sp[:, 2]
    np.testing.assert_allclose(R_sp[:, 0], b1 / np.linalg.norm(b1), atol=TOL)


@pytest.mark.parametrize("yaw_ref", [0.0, 0.9, -2.0])
@pytest.mark.parametrize("lean", [(1.0, 0.0), (0.0, 1.0)])  # along and across the heading
def test_desired_heading_is_yaw_ref_when_tilting_along_or_across_it(yaw_ref, lean):
    fc = _controller()
    z = (0.0, 0.0, 0.0)
    c, s = math.cos(yaw_ref), math.sin(yaw_ref)
    d = 0.5 * np.array([c * lean[0] - s * lean[1], s * lean[0] + c * lean[1], 0.0])
    fc.outer(z, z, tuple(d.tolist()), z)
    fc.inner(np.eye(3).ravel().tolist(), z, yaw_ref, 0.0)
    R_sp = fc.R_sp
    assert math.acos(R_sp[2, 2]) > 0.2  # clearly tilted
    assert math.atan2(R_sp[1, 0], R_sp[0, 0]) == pytest.approx(yaw_ref, abs=TOL)


@pytest.mark.parametrize(
    ("axis", "k_att", "k_rate", "inertia"),
    [(0, 8.0, 25.0, 0.02), (1, 8.0, 25.0, 0.03), (2, 3.0, 10.0, 0.05)],
)
@pytest.mark.parametrize("angle", [0.05, 0.3, -0.3])
def test_attitude_error_about_a_body_axis_commands_the_opposite_rate(
    axis, k_att, k_rate, inertia, angle
):
    """e_R = sin(angle) e_axis for R = R_sp Rot(e_axis, angle); rate set-point -k e_R."""
    fc = _controller()
    z = (0.0, 0.0, 0.0)
    fc.outer(z, z, (0.3, -0.2, 0.0), z)  # a tilted R_sp with a heading
    fc.inner(np.eye(3).ravel().tolist(), z, 0.6, 0.0)
    fc.i_rate = z
    e = np.eye(3)[axis]
    R = fc.R_sp @ _rot(e, angle)
    fc.inner(R.ravel().tolist(), z, 0.6, 0.0)
    rate_sp = -k_att * math.sin(angle) * e  # w = 0: no gyroscopic term, alpha = k_p rate_sp
    np.testing.assert_allclose(fc.torque, inertia * k_rate * rate_sp, atol=TOL)
    assert np.sign(fc.torque[axis]) == -np.sign(angle)
    np.testing.assert_allclose(fc.i_rate, (60.0 if axis < 2 else 10.0) * rate_sp * DT, atol=TOL)


def test_attitude_error_about_any_axis_matches_rodrigues_with_full_inertia():
    fc = _controller(inertia=J_FULL)
    z = (0.0, 0.0, 0.0)
    fc.outer(z, z, (-0.2, 0.35, 0.1), z)
    fc.inner(np.eye(3).ravel().tolist(), z, -1.1, 0.0)
    R_sp = fc.R_sp
    k = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    w = np.array([0.2, -0.1, 0.3])
    fc.i_rate = (0.5, -0.25, 0.125)
    R = R_sp @ _rot(k, 0.2)
    fc.inner(R.ravel().tolist(), tuple(w.tolist()), -1.1, 0.0)
    E = R_sp.T @ R  # vee((E - E^T) / 2) = sin(0.2) k
    e_R = 0.5 * np.array([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]])
    np.testing.assert_allclose(e_R, math.sin(0.2) * k, atol=TOL)
    rate_sp = -np.array([8.0, 8.0, 3.0]) * e_R
    alpha = np.array([25.0, 25.0, 10.0]) * (rate_sp - w) + [0.5, -0.25, 0.125]
    np.testing.assert_allclose(fc.torque, J_FULL @ alpha + np.cross(w, J_FULL @ w), atol=TOL)


# --- yaw-rate feed-forward and rate limits -------------------------------------------------


@pytest.mark.parametrize("yaw_rate", [0.5, -0.8])
def test_yaw_rate_feed_forward_is_world_z_rate_in_body_frame_under_tilt(yaw_rate):
    """On R = R_sp with w = R^T (0, 0, r) and no integrator, the rate error is zero: the torque
    is exactly the gyroscopic w x J w (a body-frame (0, 0, r) would leave a rate error)."""
    fc = _controller(inertia=J_FULL)
    z = (0.0, 0.0, 0.0)
    fc.outer(z, z, (0.1, -0.5, 0.0), z)
    fc.inner(np.eye(3).ravel().tolist(), z, 0.7, 0.0)
    fc.i_rate = z
    R = fc.R_sp
    assert abs(R[2, 0]) > 0.1 and abs(R[2, 1]) > 0.1 and R[0, 2] != R[2, 0]
    w = R.T @ np.array([0.0, 0.0, yaw_rate])
    np.testing.assert_allclose(w, yaw_rate * R[2], atol=TOL)
    fc.inner(R.ravel().tolist(), tuple(w.tolist()), 0.7, yaw_rate)
    gyro = np.cross(w, J_FULL @ w)
    np.testing.assert_allclose(fc.torque, gyro, atol=TOL)
    np.testing.assert_allclose(fc.i_rate, z, atol=TOL)
    assert fc.thrust == pytest.approx(np.linalg.norm(fc.F), abs=TOL)  # b3 along F
    wrong = J_FULL @ (np.array([25.0, 25.0, 10.0]) * ([0.0, 0.0, yaw_rate] - w)) + gyro
    assert np.abs(wrong - gyro).max() > 1e-3  # the test tells the two feed-forwards apart


def test_rate_set_points_are_clipped_at_rate_max_rp_and_rate_max_yaw():
    fc = _controller()
    _level_hover(fc)
    z = (0.0, 0.0, 0.0)
    # roll error 1 rad: -8 sin(1) = -6.7 rad/s, clipped to -3.8; yaw feed-forward 5 rad/s:
    # body y 5 sin(1) = 4.2 -> 3.8 (roll/pitch limit), body z 5 cos(1) = 2.7 -> 1.5 (yaw)
    fc.inner(_rot((1.0, 0.0, 0.0), 1.0).ravel().tolist(), z, 0.0, 5.0)
    np.testing.assert_allclose(
        fc.torque, [0.02 * 25.0 * -3.8, 0.03 * 25.0 * 3.8, 0.05 * 10.0 * 1.5], atol=TOL
    )
    # pitch error -1 rad: 8 sin(1) -> 3.8; the reverse ramp: body x -5 sin(1) -> -3.8, z -1.5
    fc.i_rate = z
    fc.inner(_rot((0.0, 1.0, 0.0), -1.0).ravel().tolist(), z, 0.0, -5.0)
    np.testing.assert_allclose(
        fc.torque, [0.02 * 25.0 * -3.8, 0.03 * 25.0 * 3.8, 0.05 * 10.0 * -1.5], atol=TOL
    )
    # a yaw error of 1 rad alone: -3 sin(1) = -2.52 rad/s, clipped to -1.5
    fc.i_rate = z
    fc.inner(_rot((0.0, 0.0, 1.0), 1.0).ravel().tolist(), z, 0.0, 0.0)
    np.testing.assert_allclose(fc.torque, [0.0, 0.0, 0.05 * 10.0 * -1.5], atol=TOL)


def test_custom_rate_limits_apply():
    fc = _controller(FlightGains(rate_max_rp=0.5, rate_max_yaw=0.25))
    _level_hover(fc)
    z = (0.0, 0.0, 0.0)
    fc.inner(_rot((1.0, -1.0, 0.0), 0.3).ravel().tolist(), z, 0.0, 1.0)
    np.testing.assert_allclose(
        fc.torque, [0.02 * 25.0 * -0.5, 0.03 * 25.0 * 0.5, 0.05 * 10.0 * 0.25], atol=TOL
    )


# --- rate integrator, reset trim and derivative terms -------------------------------------


def test_rate_integrator_is_clamped_at_rate_i_max_per_axis_with_sign():
    fc = _controller(FlightGains(rate_i_rp=1000.0, rate_i_yaw=1000.0, rate_i_max=2.0))
    _level_hover(fc)
    w = (1.0, -1.0, 0.01)  # rate errors (-1, 1, -0.01): increments (-10, 10, -0.1)
    fc.inner(np.eye(3).ravel().tolist(), w, 0.0, 0.0)
    np.testing.assert_allclose(fc.i_rate, [-2.0, 2.0, -0.1], atol=TOL)
    # the torque of this tick used the integrator before the update (zero)
    J, wv = np.diag(J_DIAG), np.array(w)
    alpha = np.array([25.0, 25.0, 10.0]) * -wv
    np.testing.assert_allclose(fc.torque, J @ alpha + np.cross(wv, J @ wv), atol=TOL)
    fc.inner(np.eye(3).ravel().tolist(), (-1.0, 1.0, -0.15), 0.0, 0.0)  # swing back
    np.testing.assert_allclose(fc.i_rate, [2.0, -2.0, -0.1 + 1.5], atol=TOL)


def test_reset_trim_sets_rate_integrator_to_j_inverse_trim_clipped():
    fc = _controller(inertia=J_FULL)
    trim = np.array([0.1, -0.2, 0.05])
    fc.reset(trim)
    np.testing.assert_allclose(fc.i_rate, np.linalg.solve(J_FULL, trim), atol=TOL)
    # a trimmed hover is an equilibrium: the rotors produce exactly the trim torque
    fc.inner(np.eye(3).ravel().tolist(), (0.0, 0.0, 0.0), 0.0, 0.0)
    np.testing.assert_allclose(fc.torque, trim, atol=TOL)
    np.testing.assert_allclose(fc.i_rate, np.linalg.solve(J_FULL, trim), atol=TOL)
    np.testing.assert_allclose(_allocation(4, ARM, K_M) @ fc.motors, [2.0 * G, *trim], atol=TOL)
    fc = _controller()  # diagonal: J^-1 trim = (5, -5, 100) -> (5, -5, 60)
    fc.reset((0.1, -0.15, 5.0))
    np.testing.assert_allclose(fc.i_rate, [5.0, -5.0, 60.0], atol=TOL)
    fc.reset((-2.0, 0.0, 0.0))
    np.testing.assert_allclose(fc.i_rate, [-60.0, 0.0, 0.0], atol=TOL)
    fc.reset()
    assert fc.i_rate == (0.0, 0.0, 0.0) and fc.i_vel == (0.0, 0.0, 0.0)
    assert fc.F == (0.0, 0.0, 2.0 * G) and fc.outer_due


def test_rate_d_term_uses_the_low_passed_angular_acceleration():
    gains = FlightGains(rate_d_rp=0.02, rate_d_yaw=0.01, d_cutoff_hz=30.0)
    fc = _controller(gains, inertia=J_FULL)
    _level_hover(fc)  # the D filter is primed on this tick (w = 0)
    tau = 1.0 / (2.0 * math.pi * 30.0)
    c = DT / (DT + tau)
    kp, ki, kd = np.array([25.0, 25.0, 10.0]), np.array([60.0, 60.0, 10.0]), [0.02, 0.02, 0.01]
    w = np.array([0.1, -0.2, 0.3])
    eye = np.eye(3).ravel().tolist()
    fc.inner(eye, tuple(w.tolist()), 0.0, 0.0)
    dw = c * w / DT  # filtered derivative of the step 0 -> w
    alpha = kp * -w - kd * dw
    np.testing.assert_allclose(fc.torque, J_FULL @ alpha + np.cross(w, J_FULL @ w), atol=TOL)
    fc.inner(eye, tuple(w.tolist()), 0.0, 0.0)  # w held: the filter decays by (1 - c)
    dw = (1.0 - c) * dw
    alpha = kp * -w + ki * -w * DT - kd * dw
    np.testing.assert_allclose(fc.torque, J_FULL @ alpha + np.cross(w, J_FULL @ w), atol=TOL)


def test_rate_d_term_is_zero_on_the_first_tick_after_reset():
    fc = _controller(FlightGains(rate_d_rp=0.5, rate_d_yaw=0.5))
    fc.reset()
    w = np.array([0.4, 0.0, 0.0])
    fc.inner(np.eye(3).ravel().tolist(), tuple(w.tolist()), 0.0, 0.0)
    J = np.diag(J_DIAG)
    np.testing.assert_allclose(fc.torque, J @ (np.array([25.0, 25.0, 10.0]) * -w), atol=TOL)


def test_velocity_d_term_uses_the_low_passed_acceleration_at_the_outer_rate():
    gains = FlightGains(vel_d_xy=0.1, vel_d_z=0.2, d_cutoff_hz=5.0)
    fc = _controller(gains, outer_every=2)  # the outer loop period is 2 dt
    outer_dt = 2.0 * DT
    c = outer_dt / (outer_dt + 1.0 / (2.0 * math.pi * 5.0))
    z = (0.0, 0.0, 0.0)
    kp, ki, kd = np.array([3.5, 3.5, 4.0]), np.array([0.6, 0.6, 2.0]), np.array([0.1, 0.1, 0.2])
    v1, v2 = np.array([0.1, 0.0, -0.1]), np.array([0.3, -0.2, 0.1])
    fc.outer(z, tuple(v1.tolist()), z, z)  # first call: no derivative yet
    np.testing.assert_allclose(fc.F, 2.0 * (kp * -v1 + G * E_Z), atol=TOL)
    fc.outer(z, tuple(v2.tolist()), z, z)
    dv = c * (v2 - v1) / outer_dt
    a = kp * -v2 + ki * -v1 * outer_dt - kd * dv
    np.testing.assert_allclose(fc.F, 2.0 * (a + G * E_Z), atol=TOL)


# --- gains from options ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"kp": 1.0}, r"physics\.gains\.kp: unknown key"),
        ({"pos_p_xy": "fast"}, r"physics\.gains\.pos_p_xy: must be a number"),
        ({"vel_p_z": True}, r"physics\.gains\.vel_p_z: must be a number"),
        ({"tilt_max": None}, r"physics\.gains\.tilt_max: must be a number"),
        ({"rate_p_rp": -1.0}, r"physics\.gains\.rate_p_rp: must be a finite number >= 0"),
        ({"att_p_yaw": math.nan}, r"physics\.gains\.att_p_yaw: must be a finite number >= 0"),
        ({"rate_i_max": math.inf}, r"physics\.gains\.rate_i_max: must be a finite number >= 0"),
    ],
)
def test_gains_from_options_errors_name_the_key(options, message):
    with pytest.raises(ConfigError, match=message):
        FlightGains.from_options(options)


def test_gains_from_options_uses_the_given_path_and_keeps_defaults():
    with pytest.raises(ConfigError, match=r"^robot\.gains\.bad: unknown key"):
        FlightGains.from_options({"bad": 1}, path="robot.gains")
    gains = FlightGains.from_options({"pos_p_xy": 2, "rate_d_yaw": 0})
    assert gains.pos_p_xy == 2.0 and isinstance(gains.pos_p_xy, float)
    assert gains.rate_d_yaw == 0.0 and isinstance(gains.rate_d_yaw, float)
    assert gains.pos_p_z == 1.5 and gains.tilt_max == math.radians(35.0)
