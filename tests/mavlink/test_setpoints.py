"""Offboard setpoints read as PX4 reads them (``mavlink.setpoints``).

Truth: the MAVLink definitions as pymavlink generates them (type-mask bits, frames), the
masks MAVSDK's ``Offboard`` sends (velocity NED + yaw: 2503 in LOCAL_NED; body velocity
+ yaw rate: 1479 in BODY_NED, observed on the wire), plane geometry for the frames that
turn with the heading, and PX4's rule that a non-finite value is not set.
"""

import math

import pytest

from aeromanip.mavlink import setpoints
from aeromanip.mavlink.protocol import VELOCITY_YAW_RATE, load_mavutil
from aeromanip.sim.flight_controller import FlightGains

mav = load_mavutil().mavlink
NAN = math.nan
HERE = (1.0, 2.0, -3.0)  # the vehicle: 1 m north, 2 m east, 3 m up


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
    assert setpoints.MAV_FRAME_LOCAL_OFFSET_NED == mav.MAV_FRAME_LOCAL_OFFSET_NED
    assert setpoints.MAV_FRAME_BODY_NED == mav.MAV_FRAME_BODY_NED
    assert setpoints.MAV_FRAME_BODY_OFFSET_NED == mav.MAV_FRAME_BODY_OFFSET_NED
    assert setpoints.MAV_FRAME_BODY_FRD == mav.MAV_FRAME_BODY_FRD


def test_mavsdks_velocity_ned_with_yaw_is_a_velocity_and_a_heading():
    sp = setpoints.from_local_ned(message(2503, vel=(1.0, -0.5, 0.2), yaw=0.7, yaw_rate=9.0),
                                  HERE, 0.1)  # fmt: skip
    assert isinstance(sp, setpoints.Setpoint)
    assert same(sp.position, (NAN,) * 3) and same(sp.acceleration, (NAN,) * 3)
    assert same(sp.velocity, (1.0, -0.5, 0.2))
    assert sp.yaw == pytest.approx(0.7) and math.isnan(sp.yaw_rate)  # yaw rate ignored


def test_the_bridges_velocity_and_yaw_rate_fly_as_before():
    msg = message(VELOCITY_YAW_RATE, vel=(0.3, 0.1, -0.2), yaw=5.0, yaw_rate=0.25)
    sp = setpoints.from_local_ned(msg, HERE, 0.1)
    v, rate = setpoints.velocity_and_yaw_rate(sp, HERE, (0.0, 0.0, 0.0), 0.1, 0.01)
    assert v == pytest.approx((0.3, 0.1, -0.2)) and rate == pytest.approx(0.25)


def test_a_body_velocity_turns_with_the_heading():
    east = math.pi / 2  # NED yaw: facing east
    sp = setpoints.from_local_ned(message(1479, mav.MAV_FRAME_BODY_NED, vel=(1.0, 0.0, 0.0)),
                                  HERE, east)  # fmt: skip
    assert same(sp.velocity, (0.0, 1.0, 0.0))  # forward is east
    sp = setpoints.from_local_ned(message(1479, mav.MAV_FRAME_BODY_FRD, vel=(0.0, 1.0, 0.5)),
                                  HERE, east)  # fmt: skip
    assert same(sp.velocity, (-1.0, 0.0, 0.5))  # right of east is south; down stays down


def test_offsets_are_from_the_vehicle_and_body_yaw_from_its_heading():
    pos_only = 8 | 16 | 32 | 64 | 128 | 256 | 2048  # position + yaw (MAVSDK's position NED)
    sp = setpoints.from_local_ned(message(pos_only, mav.MAV_FRAME_LOCAL_OFFSET_NED,
                                          pos=(1.0, 0.0, -1.0), yaw=0.3), HERE, 0.2)  # fmt: skip
    assert same(sp.position, (2.0, 2.0, -4.0)) and sp.yaw == pytest.approx(0.3)
    sp = setpoints.from_local_ned(message(pos_only, mav.MAV_FRAME_BODY_OFFSET_NED,
                                          pos=(1.0, 0.0, 0.0), yaw=0.3),
                                  HERE, math.pi)  # fmt: skip
    assert same(sp.position, (0.0, 2.0, -3.0))  # 1 m ahead facing south
    assert sp.yaw == pytest.approx(math.pi + 0.3)  # relative to the heading


@pytest.mark.parametrize("bad", [NAN, math.inf, -math.inf])
def test_a_non_finite_value_is_not_set_and_nothing_finite_is_refused(bad):
    sp = setpoints.from_local_ned(message(2503, vel=(bad, 1.0, 0.0), yaw=bad), HERE, 0.0)
    assert same(sp.velocity, (NAN, 1.0, 0.0)) and math.isnan(sp.yaw)
    v, rate = setpoints.velocity_and_yaw_rate(sp, HERE, (0.4, 0.0, 0.0), 0.0, 0.01)
    assert v == (0.0, 1.0, 0.0) and rate == 0.0  # the unset axis holds, the heading too
    refused = setpoints.from_local_ned(message(2503, vel=(bad, bad, bad)), HERE, 0.0)
    assert refused == (
        "SET_POSITION_TARGET_LOCAL_NED: no finite position, velocity or acceleration"
    )


def test_force_and_unknown_frames_are_refused_with_the_reason():
    force = 1 | 2 | 4 | 8 | 16 | 32 | 512 | 1024 | 2048
    assert setpoints.from_local_ned(message(force, acc=(0, 0, 1)), HERE, 0.0) == (
        "SET_POSITION_TARGET_LOCAL_NED force not supported"
    )
    global_frame = message(2503, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT)
    assert setpoints.from_local_ned(global_frame, HERE, 0.0) == (
        "SET_POSITION_TARGET_LOCAL_NED coordinate frame 3 unsupported"
    )


def test_position_acceleration_and_yaw_become_the_inner_loops_velocity_and_rate():
    g = FlightGains()
    sp = setpoints.Setpoint(position=(2.0, NAN, NAN), velocity=(0.1, NAN, NAN),
                            acceleration=(NAN, 2.0, NAN), yaw=math.pi - 0.1)  # fmt: skip
    v, rate = setpoints.velocity_and_yaw_rate(sp, HERE, (0.0, 0.5, 0.3), -math.pi + 0.1, 0.05)
    assert v[0] == pytest.approx(g.pos_p_xy * (2.0 - 1.0) + 0.1)  # P loop + feed-forward
    assert v[1] == pytest.approx(0.5 + 2.0 * 0.05)  # acceleration through the velocity loop
    assert v[2] == 0.0  # nothing set: hold
    assert rate == pytest.approx(g.att_p_yaw * -0.2)  # the short way across +-pi
