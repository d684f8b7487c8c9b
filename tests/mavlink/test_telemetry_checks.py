"""The bridge's telemetry checks (``aeromanip.mavlink.telemetry``): every attitude a
vehicle can have passes (its ZYX Euler angles from scipy, as PX4's ``matrix::Eulerf``
gives them: roll and yaw in [-pi, pi], pitch in [-pi/2, pi/2]); non-finite and
out-of-range values are named; old timestamps are dropped."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from aeromanip.mavlink.telemetry import (
    MAX_POSITION_M,
    TelemetryClock,
    check_attitude,
    check_position,
)


def attitude(roll=0.0, pitch=0.0, yaw=0.0, p=0.0, q=0.0, r=0.0):
    return SimpleNamespace(roll=roll, pitch=pitch, yaw=yaw, rollspeed=p, pitchspeed=q, yawspeed=r)


def position(x=0.0, y=0.0, z=0.0, vx=0.0, vy=0.0, vz=0.0):
    return SimpleNamespace(x=x, y=y, z=z, vx=vx, vy=vy, vz=vz)


def test_every_attitude_passes():
    rng = np.random.default_rng(0)
    quats = np.vstack([rng.normal(size=(2000, 4)), np.eye(4)])  # incl. the exact poles
    for yaw, pitch, roll in Rotation.from_quat(quats).as_euler("ZYX"):
        # float32 on the wire (the MAVLink ATTITUDE fields)
        msg = attitude(*(float(np.float32(v)) for v in (roll, pitch, yaw)))
        assert check_attitude(msg) is None, msg


@pytest.mark.parametrize(
    "msg, words",
    [
        (attitude(roll=math.nan), "ATTITUDE.roll = nan (not finite)"),
        (attitude(yaw=-math.inf), "ATTITUDE.yaw = -inf (not finite)"),
        (attitude(pitch=2.0), "ATTITUDE.pitch = 2 rad (allowed: [-1.5718, 1.5718] rad)"),
        (attitude(r=100.0), "ATTITUDE.yawspeed = 100 rad/s (allowed: [-35, 35] rad/s)"),
        (position(z=math.nan), "LOCAL_POSITION_NED.z = nan (not finite)"),
        (position(x=2 * MAX_POSITION_M), "LOCAL_POSITION_NED.x = 20000 m (allowed"),
        (position(vy=-150.0), "LOCAL_POSITION_NED.vy = -150 m/s (allowed: [-100, 100] m/s)"),
    ],
)
def test_a_bad_value_is_named_with_what_is_allowed(msg, words):
    check = check_position if hasattr(msg, "vx") else check_attitude
    assert words in check(msg)


def test_positions_and_speeds_of_a_flight_pass():
    assert check_position(position(1.0, -2.0, -1.0, 0.5, 0.0, -0.2)) is None
    assert check_position(position(x=MAX_POSITION_M, vz=100.0)) is None  # the ends


def test_old_timestamps_are_dropped_per_message_kind():
    clock = TelemetryClock()
    assert clock.check("ATTITUDE", 1000, 0.0) and clock.check("ATTITUDE", 1000, 0.01)
    assert clock.check("LOCAL_POSITION_NED", 5, 0.02)  # its own sequence
    assert not clock.check("ATTITUDE", 999, 0.03)  # older: dropped
    assert clock.dropped == 1 and "went back from 1000 to 999 ms" in clock.last_drop
    assert clock.check("ATTITUDE", 2**32 - 1, 0.04)  # an absurd time, once ...
    assert not clock.check("ATTITUDE", 1040, 0.05)  # ... then every true one is old
