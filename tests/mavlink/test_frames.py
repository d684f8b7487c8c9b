"""ENU/FLU <-> NED/FRD conversions (aeromanip.mavlink.frames) against hand-computed cases,
the MAVLink constants against pymavlink's, and the arm's actuator scaling."""

import math

import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.mavlink import frames, protocol
from aeromanip.mavlink.arm import actuator_params, actuator_to_joint, joint_to_actuator

D = math.radians


def test_positions_and_velocities_swap_axes_and_flip_up():
    # 1 m east, 2 m north, 3 m up is 2 m north, 1 m east, 3 m down (z = -3)
    assert frames.enu_to_ned((1.0, 2.0, 3.0)) == (2.0, 1.0, -3.0)
    assert frames.ned_to_enu((2.0, 1.0, -3.0)) == (1.0, 2.0, 3.0)
    # climbing at 0.5 m/s while flying north at 1 m/s
    assert frames.enu_to_ned((0.0, 1.0, 0.5)) == (1.0, 0.0, -0.5)


def test_body_vectors_flip_y_and_z():
    # rolling right (FRD p > 0) is rolling right in FLU too (about x forward, same sign);
    # a pitch-up rate (FRD q > 0) is negative about FLU's y (left); a clockwise turn seen
    # from above (FRD r > 0) is negative about FLU's z (up)
    assert frames.frd_to_flu((0.1, 0.2, 0.3)) == (0.1, -0.2, -0.3)
    assert frames.flu_to_frd((0.1, -0.2, -0.3)) == (0.1, 0.2, 0.3)


@pytest.mark.parametrize(
    "yaw_enu, yaw_ned",
    [
        (0.0, 90.0),  # facing east: 90 deg from north, clockwise
        (90.0, 0.0),  # facing north
        (180.0, -90.0),  # facing west: 270 deg = -90 deg
        (-90.0, 180.0),  # facing south
        (30.0, 60.0),  # 30 deg north of east = 60 deg east of north
    ],
)
def test_headings(yaw_enu, yaw_ned):
    got = frames.yaw_enu_to_ned(D(yaw_enu))
    assert math.isclose(abs(frames.wrap(got - D(yaw_ned))), 0.0, abs_tol=1e-12)
    back = frames.yaw_ned_to_enu(D(yaw_ned))
    assert math.isclose(abs(frames.wrap(back - D(yaw_enu))), 0.0, abs_tol=1e-12)


def test_yaw_rate_flips_sign():
    # turning left (counter-clockwise from above) at 0.2 rad/s: +0.2 about up, -0.2 about down
    assert frames.yaw_rate_enu_to_ned(0.2) == -0.2
    assert frames.yaw_rate_ned_to_enu(-0.2) == 0.2


@pytest.mark.parametrize(
    "enu, ned",
    [
        ((0.0, 0.0, 0.0), (0.0, 0.0, 90.0)),  # level, facing east
        ((0.0, -10.0, 0.0), (0.0, 10.0, 90.0)),  # nose up 10 deg (FLU pitch < 0)
        ((5.0, 0.0, 90.0), (5.0, 0.0, 0.0)),  # right wing down 5 deg, facing north
        ((5.0, -10.0, 30.0), (5.0, 10.0, 60.0)),
    ],
)
def test_attitudes(enu, ned):
    got = frames.attitude_enu_to_ned(*map(D, enu))
    np.testing.assert_allclose(got, [D(a) for a in ned], atol=1e-12)
    back = frames.attitude_ned_to_enu(*map(D, ned))
    np.testing.assert_allclose(back, [D(a) for a in enu], atol=1e-12)


def test_attitude_maps_the_nose_and_the_right_wing():
    """The attitude conversion moves physical directions correctly: with a random
    attitude, the nose (FLU x) in ENU equals the nose (FRD x) in NED after the swap,
    and the right wing (FLU -y, FRD +y) likewise."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        roll, pitch, yaw = rng.uniform(-1.2, 1.2, 3)
        R_enu = frames.rotation_zyx(roll, pitch, yaw)
        R_ned = frames.rotation_zyx(*frames.attitude_enu_to_ned(roll, pitch, yaw))
        nose_enu, right_enu = R_enu[:, 0], -R_enu[:, 1]
        np.testing.assert_allclose(frames.enu_to_ned(nose_enu), R_ned[:, 0], atol=1e-12)
        np.testing.assert_allclose(frames.enu_to_ned(right_enu), R_ned[:, 1], atol=1e-12)


def test_euler_yaw_rate():
    # level: the yaw rate is the body z rate; rolled 90 deg, it is the body y rate
    assert frames.euler_yaw_rate(0.0, 0.0, 0.3, 0.2) == pytest.approx(0.2)
    assert frames.euler_yaw_rate(math.pi / 2, 0.0, 0.3, 0.2) == pytest.approx(0.3)


def test_type_mask_and_constants_match_mavlink():
    from pymavlink.dialects.v20 import common as m

    # velocity + yaw rate: ignore x, y, z (1 + 2 + 4), ax, ay, az (64 + 128 + 256), yaw (1024)
    assert protocol.VELOCITY_YAW_RATE == 1479 == 0b0101_1100_0111
    expected = (
        m.POSITION_TARGET_TYPEMASK_X_IGNORE
        | m.POSITION_TARGET_TYPEMASK_Y_IGNORE
        | m.POSITION_TARGET_TYPEMASK_Z_IGNORE
        | m.POSITION_TARGET_TYPEMASK_AX_IGNORE
        | m.POSITION_TARGET_TYPEMASK_AY_IGNORE
        | m.POSITION_TARGET_TYPEMASK_AZ_IGNORE
        | m.POSITION_TARGET_TYPEMASK_YAW_IGNORE
    )
    mask = protocol.VELOCITY_YAW_RATE
    assert mask == expected
    for used in ("VX", "VY", "VZ", "YAW_RATE"):
        assert not mask & getattr(m, f"POSITION_TARGET_TYPEMASK_{used}_IGNORE")
    assert protocol.MAV_FRAME_LOCAL_NED == m.MAV_FRAME_LOCAL_NED
    assert protocol.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED == m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert protocol.MAV_MODE_FLAG_SAFETY_ARMED == m.MAV_MODE_FLAG_SAFETY_ARMED


def test_px4_custom_modes():
    # PX4: main mode in bits 16-23, sub mode in bits 24-31; OFFBOARD = 6, AUTO.LOITER = 4/3
    assert protocol.custom_mode("offboard") == 6 << 16 == 393216
    assert protocol.custom_mode("hold") == (4 << 16) | (3 << 24) == 50593792
    assert protocol.mode_name(393216) == "offboard"
    assert protocol.mode_name(50593792) == "hold"
    assert protocol.mode_name(3 << 16) == "other"  # POSCTL


def test_actuator_scaling_spans_the_joint_limits():
    assert joint_to_actuator(-1.0, -1.0, 2.0) == -1.0
    assert joint_to_actuator(2.0, -1.0, 2.0) == 1.0
    assert joint_to_actuator(0.5, -1.0, 2.0) == 0.0
    assert joint_to_actuator(5.0, -1.0, 2.0) == 1.0  # clipped
    assert actuator_to_joint(0.5, -1.0, 2.0) == 1.25
    params = actuator_params([0.5] * 7, [(-1.0, 2.0)] * 7)
    assert len(params) == 2 and params[0][:6] == [0.0] * 6 and params[0][6] == 0.0
    assert params[1][0] == 0.0 and all(math.isnan(v) for v in params[1][1:6])
    assert params[1][6] == 1.0  # the second set of six actuators


@pytest.mark.parametrize(
    "url, ok",
    [
        ("udpin:127.0.0.1:14540", True),
        ("udpout:127.0.0.1:14540", True),
        ("tcp:192.168.1.2:5760", True),
        ("serial:/dev/ttyUSB0:921600", True),
        ("udpin:127.0.0.1", False),
        ("udpin:127.0.0.1:99999", False),
        ("serial:/dev/ttyUSB0", False),
        ("http://x", False),
    ],
)
def test_link_urls(url, ok):
    if ok:
        protocol.parse_link(url)
    else:
        with pytest.raises(ConfigError, match="--link"):
            protocol.parse_link(url)
