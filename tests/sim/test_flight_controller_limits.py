"""Flight controller edges the main test file leaves open, each against an independent truth.

Truths: hover equilibrium (``T = m g`` shared evenly by a symmetric quad, zero torque, level
set-point), ``tau = J alpha`` at zero rate with the rate set-point clipped at its limit,
``T = F . b3`` (docstring), a first-order low-pass re-implemented in NumPy, and the
documented outer-loop period (every ``outer_every``-th tick).
"""

import math
import re

import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.sim.flight_controller import FlightController, FlightGains, Mixer, rotor_layout

G = 9.81
MASS = 2.0
J_DIAG = (0.02, 0.03, 0.05)
DT = 0.01
EYE = np.eye(3).ravel().tolist()
Z = (0.0, 0.0, 0.0)


def rot(axis, angle):
    """Rodrigues: rotation by ``angle`` about the unit ``axis``."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def controller(gains=None, outer_every=1):
    pos, spins = rotor_layout(4, 0.1 * math.sqrt(2.0))
    return FlightController(MASS, J_DIAG, Mixer(pos, spins, 0.02, 10.0), DT, gains, outer_every)


@pytest.mark.parametrize(
    ("rotors", "coaxial", "rule"),
    [(6, True, "a multiple of 4, >= 8, for coaxial pairs"), (5, False, "an even integer >= 4")],
)
def test_rotor_count_errors_state_the_rule(rotors, coaxial, rule):
    with pytest.raises(ConfigError, match=re.escape(f"must be {rule}")):
        rotor_layout(rotors, 0.3, coaxial)


@pytest.mark.parametrize("outer_every", [2.0, 0, True])
def test_outer_every_must_be_a_positive_integer(outer_every):
    with pytest.raises(ConfigError, match="outer_every"):
        controller(outer_every=outer_every)


def test_reset_is_a_level_hover():
    """After reset: level set-point, T = m g, zero torque, each of 4 rotors m g / 4."""
    fc = controller()
    fc.reset()
    np.testing.assert_array_equal(fc.R_sp, np.eye(3))
    assert fc.thrust == pytest.approx(MASS * G, abs=1e-12)
    assert fc.torque == (0.0, 0.0, 0.0)
    np.testing.assert_allclose(fc.motors, [MASS * G / 4] * 4, atol=1e-12)


def test_inner_alone_after_reset_holds_the_level_hover():
    """The inner loop before any outer tick uses ``F = m g e_z``: b3 = e_z, R_sp = I."""
    fc = controller()
    fc.inner(EYE, Z, 0.0, 0.0)
    np.testing.assert_allclose(fc.R_sp, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(fc.torque, Z, atol=1e-12)
    np.testing.assert_allclose(fc.motors, [MASS * G / 4] * 4, atol=1e-12)


def test_roll_and_pitch_rate_set_points_clip_on_the_other_side_too():
    """Roll -1 rad: -8 sin(-1) = +6.7 rad/s -> +3.8; pitch +1 rad: -6.7 -> -3.8."""
    fc = controller()
    fc.inner(rot((1, 0, 0), -1.0).ravel().tolist(), Z, 0.0, 0.0)
    np.testing.assert_allclose(fc.torque, [0.02 * 25.0 * 3.8, 0.0, 0.0], atol=1e-12)
    fc.reset()
    fc.inner(rot((0, 1, 0), 1.0).ravel().tolist(), Z, 0.0, 0.0)
    np.testing.assert_allclose(fc.torque, [0.0, 0.03 * 25.0 * -3.8, 0.0], atol=1e-12)


def test_yaw_rate_integrator_is_clamped_both_ways():
    """Yaw increment ``k_i e dt`` = 1000 * 1 * 0.01 = 10 per tick, clamped to +-2."""
    fc = controller(FlightGains(rate_i_yaw=1000.0, rate_i_max=2.0))
    fc.inner(EYE, (0.0, 0.0, -1.0), 0.0, 0.0)
    assert fc.i_rate[2] == pytest.approx(2.0, abs=1e-12)
    fc.inner(EYE, (0.0, 0.0, 1.0), 0.0, 0.0)
    assert fc.i_rate[2] == pytest.approx(-2.0, abs=1e-12)


def test_small_positive_collective_thrust_is_kept():
    """Tilted so that ``F . b3`` = 0.5 N: the thrust is 0.5 N, not cut to zero."""
    fc = controller()
    fc.inner(rot((1, 0, 0), math.acos(0.5 / (MASS * G))).ravel().tolist(), Z, 0.0, 0.0)
    assert fc.thrust == pytest.approx(0.5, abs=1e-9)


def test_outer_loop_runs_every_outer_every_th_tick():
    fc = controller(outer_every=4)
    due = []
    for _ in range(9):
        due.append(fc.outer_due)
        fc.update(np.zeros(3), np.zeros(3), np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3), 0.0)
    assert due == [True, False, False, False] * 2 + [True]


def test_velocity_derivative_filter_over_three_outer_ticks():
    """On the reference (position error 0, v_ref = v): ``a = -k_d d``, ``d`` the low-passed
    acceleration, ``d_k = d_{k-1} + c (dv/dt - d_{k-1})``, re-implemented here."""
    kd = np.array([0.1, 0.1, 0.2])
    fc = controller(FlightGains(vel_d_xy=0.1, vel_d_z=0.2, d_cutoff_hz=5.0))
    c = DT / (DT + 1.0 / (2.0 * math.pi * 5.0))
    vs = [np.array([0.1, 0.2, -0.1]), np.array([0.3, -0.2, 0.1]), np.array([0.2, -0.5, 0.4])]
    d = np.zeros(3)
    for k, v in enumerate(vs):
        vt = tuple(v.tolist())
        fc.outer(Z, vt, Z, vt)
        if k:
            d = d + c * ((v - vs[k - 1]) / DT - d)
        np.testing.assert_allclose(fc.F, MASS * (-kd * d + [0.0, 0.0, G]), atol=1e-12)
