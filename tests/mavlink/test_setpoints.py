"""Offboard setpoints read as PX4 reads them (``mavlink.setpoints``).

Truth: the MAVLink definitions as pymavlink generates them (type-mask bits, frames), the
masks MAVSDK's ``Offboard`` sends (``offboard_impl.cpp``: position 2552, velocity + yaw
2503, position + velocity 2496, all three 2048, acceleration 3135 in LOCAL_NED; body
velocity + yaw rate 1479 in BODY_NED), rotation geometry for BODY_NED, and PX4's rules
and words (``mavlink_receiver.cpp`` L1029-1146 and ``PositionControl::_inputValid`` at
PX4 commit 161b530).
"""

import math

import pytest

from aeromanip.mavlink import setpoints
from aeromanip.mavlink.protocol import VELOCITY_YAW_RATE, load_mavutil
from aeromanip.sim.flight_controller import FlightGains

mav = load_mavutil().mavlink
NAN = math.nan
HERE = (1.0, 2.0, -3.0)  # the vehicle: 1 m north, 2 m east, 3 m up
BODY_NED = mav.MAV_FRAME_BODY_NED


def message(mask, frame=mav.MAV_FRAME_LOCAL_NED, pos=(0, 0, 0), vel=(0, 0, 0), acc=(0, 0, 0),
            yaw=0.0, yaw_rate=0.0, target=(1, 1)):  # fmt: skip
    """A SET_POSITION_TARGET_LOCAL_NED as pymavlink builds it."""
    return mav.MAVLink_set_position_target_local_ned_message(
        1234, *target, frame, mask, *pos, *vel, *acc, yaw, yaw_rate
    )


def same(a, b):
    return all(
        (math.isnan(x) and math.isnan(y)) or x == pytest.approx(y)
        for x, y in zip(a, b, strict=True)
    )


def test_the_masks_and_frames_are_mavlinks():
    ignore = {
        "X_IGNORE": 1, "Y_IGNORE": 2, "Z_IGNORE": 4, "VX_IGNORE": 8, "VY_IGNORE": 16,
        "VZ_IGNORE": 32, "AX_IGNORE": 64, "AY_IGNORE": 128, "AZ_IGNORE": 256,
        "FORCE_SET": 512, "YAW_IGNORE": 1024, "YAW_RATE_IGNORE": 2048,
    }  # fmt: skip
    for name, bit in ignore.items():
        assert getattr(mav, f"POSITION_TARGET_TYPEMASK_{name}") == bit
    assert setpoints.FORCE_SET == mav.POSITION_TARGET_TYPEMASK_FORCE_SET
    assert setpoints.MAV_FRAME_BODY_NED == mav.MAV_FRAME_BODY_NED


LEVEL = (0.0, 0.0, 0.1)  # roll, pitch, yaw [rad] NED: level, heading 0.1 rad


def test_mavsdks_velocity_ned_with_yaw_is_a_velocity_and_a_heading():
    sp = setpoints.from_local_ned(message(2503, vel=(1.0, -0.5, 0.2), yaw=0.7, yaw_rate=9.0), LEVEL)
    assert isinstance(sp, setpoints.Setpoint)
    assert same(sp.position, (NAN,) * 3) and same(sp.acceleration, (NAN,) * 3)
    assert same(sp.velocity, (1.0, -0.5, 0.2))
    assert sp.yaw == pytest.approx(0.7) and math.isnan(sp.yaw_rate)  # yaw rate ignored


@pytest.mark.parametrize(
    ("mask", "used"),
    [(2552, "position"), (2496, "position velocity"), (2048, "position velocity acceleration"),
     (3135, "acceleration")],
)  # fmt: skip
def test_mavsdks_other_local_ned_masks_set_what_they_name(mask, used):
    msg = message(mask, pos=(1.0, 2.0, -3.0), vel=(0.1, 0.2, 0.3), acc=(0.5, 0.6, 0.7), yaw=0.2)
    sp = setpoints.from_local_ned(msg, LEVEL)
    for name, value in (("position", (1.0, 2.0, -3.0)), ("velocity", (0.1, 0.2, 0.3)),
                        ("acceleration", (0.5, 0.6, 0.7))):  # fmt: skip
        assert same(getattr(sp, name), value if name in used else (NAN,) * 3), name


def test_the_bridges_velocity_and_yaw_rate_fly_as_before():
    msg = message(VELOCITY_YAW_RATE, vel=(0.3, 0.1, -0.2), yaw=5.0, yaw_rate=0.25)
    sp = setpoints.from_local_ned(msg, LEVEL)
    v, rate = setpoints.velocity_and_yaw_rate(sp, HERE, (0.0, 0.0, 0.0), 0.1, 0.01)
    assert v == pytest.approx((0.3, 0.1, -0.2)) and rate == pytest.approx(0.25)


def test_body_ned_turns_velocity_with_the_heading_and_acceleration_with_the_attitude():
    east = (0.0, 0.0, math.pi / 2)  # level, facing east
    sp = setpoints.from_local_ned(message(1479, BODY_NED, pos=(5, 5, 5), vel=(1.0, 0.0, 0.0),
                                          yaw=0.3, yaw_rate=0.1), east)  # fmt: skip
    assert same(sp.velocity, (0.0, 1.0, 0.0))  # forward is east
    assert same(sp.position, (NAN,) * 3)  # never a position in BODY_NED
    assert math.isnan(sp.yaw) and sp.yaw_rate == pytest.approx(0.1)
    yaw_too = 1479 & ~1024 | 2048  # velocity + yaw: the yaw is absolute, not from the heading
    assert (
        setpoints.from_local_ned(message(yaw_too, BODY_NED, vel=(1, 0, 0), yaw=0.3), east).yaw
        == 0.3
    )
    # rolled 90 deg right (right wing down) facing north, the body's "up" (-z) faces east
    rolled = (math.pi / 2, 0.0, 0.0)
    acc_only = 1 | 2 | 4 | 8 | 16 | 32 | 1024 | 2048
    sp = setpoints.from_local_ned(message(acc_only, BODY_NED, acc=(0.0, 0.0, -1.0)), rolled)
    assert same(sp.acceleration, (0.0, 1.0, 0.0))
    partial = 1479 | 16  # one velocity component ignored: all of it is (PX4)
    assert setpoints.from_local_ned(message(partial, BODY_NED, vel=(1, 0, 0)), east) == (
        "SET_POSITION_TARGET_LOCAL_NED invalid"
    )


@pytest.mark.parametrize("frame", [7, 9, 12, 3, 20])
def test_frames_px4_does_not_take_are_refused_with_its_words(frame):
    assert setpoints.from_local_ned(message(2503, frame), LEVEL) == (
        f"SET_POSITION_TARGET_LOCAL_NED coordinate frame {frame} unsupported"
    )


def test_nan_is_not_set_and_what_px4s_controller_rejects_is_refused():
    sp = setpoints.from_local_ned(message(2503, vel=(1.0, 2.0, 0.0), yaw=NAN), LEVEL)
    assert math.isnan(sp.yaw)  # NaN yaw: not set, the heading held
    _, rate = setpoints.velocity_and_yaw_rate(sp, HERE, (0.0, 0.0, 0.0), 0.4, 0.01)
    assert rate == 0.0
    none = message(2503, vel=(NAN, NAN, NAN))
    assert setpoints.from_local_ned(none, LEVEL) == "SET_POSITION_TARGET_LOCAL_NED invalid"
    for vel in ((NAN, 1.0, 0.0), (1.0, 1.0, NAN), (math.inf, 1.0, 0.0), (1.0, 1.0, -math.inf)):
        assert setpoints.from_local_ned(message(2503, vel=vel), LEVEL) == setpoints.INVALID, vel
    assert setpoints.from_local_ned(message(2503, vel=(1, 1, 0), yaw=math.inf), LEVEL) == (
        setpoints.INVALID
    )


def test_force_is_refused_with_px4s_words():
    force = 1 | 2 | 4 | 8 | 16 | 32 | 512 | 1024 | 2048
    assert setpoints.from_local_ned(message(force, acc=(0, 0, 1)), LEVEL) == (
        "SET_POSITION_TARGET_LOCAL_NED force not supported"
    )


def test_position_acceleration_and_yaw_become_the_inner_loops_velocity_and_rate():
    g = FlightGains()
    sp = setpoints.Setpoint(position=(2.0, 3.0, NAN), velocity=(0.1, NAN, NAN),
                            acceleration=(NAN, NAN, 2.0), yaw=math.pi - 0.1)  # fmt: skip
    v, rate = setpoints.velocity_and_yaw_rate(sp, HERE, (0.0, 0.5, 0.3), -math.pi + 0.1, 0.05)
    assert v[0] == pytest.approx(g.pos_p_xy * (2.0 - 1.0) + 0.1)  # P loop + feed-forward
    assert v[1] == pytest.approx(g.pos_p_xy * (3.0 - 2.0))
    assert v[2] == pytest.approx(0.3 + 2.0 * 0.05)  # acceleration through the velocity loop
    assert rate == pytest.approx(g.att_p_yaw * -0.2)  # the short way across +-pi
