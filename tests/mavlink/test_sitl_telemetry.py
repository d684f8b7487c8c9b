"""``sitl_telemetry``'s conversions against independent ones: the quaternion against the
rotation matrix of the same Euler angles (``frames.rotation_zyx``), the global position
against the great-circle (haversine) distance and bearing from the origin."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from aeromanip.mavlink.frames import rotation_zyx
from aeromanip.mavlink.sitl_telemetry import (
    EARTH_RADIUS_M,
    HOME_ALT_M,
    HOME_LAT_DEG,
    HOME_LON_DEG,
    global_position,
    quaternion,
)

angle = st.floats(-math.pi, math.pi)


def matrix(q) -> np.ndarray:
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip


@given(roll=angle, pitch=st.floats(-1.5, 1.5), yaw=angle)
def test_the_quaternion_is_the_rotation_of_the_euler_angles(roll, pitch, yaw):
    q = quaternion(roll, pitch, yaw)
    assert math.fsum(c * c for c in q) == pytest.approx(1.0)
    assert np.allclose(matrix(q), rotation_zyx(roll, pitch, yaw), atol=1e-12)


@pytest.mark.parametrize(("north", "east", "down"), [(0, 0, 0), (100, 0, -5), (-30, 70, 2)])
def test_the_global_position_is_the_local_offset_on_the_sphere(north, east, down):
    lat, lon, alt = global_position((north, east, down))
    p0 = (math.radians(HOME_LAT_DEG), math.radians(HOME_LON_DEG))
    p1 = (math.radians(lat * 1e-7), math.radians(lon * 1e-7))
    h = math.sin((p1[0] - p0[0]) / 2) ** 2 + math.cos(p0[0]) * math.cos(p1[0]) * math.sin(
        (p1[1] - p0[1]) / 2) ** 2  # fmt: skip
    distance = 2 * EARTH_RADIUS_M * math.asin(math.sqrt(h))
    assert distance == pytest.approx(math.hypot(north, east), abs=0.015)  # degE7: 1.1 cm
    assert alt == round(1e3 * (HOME_ALT_M - down))
    if north or east:
        bearing = math.atan2(
            math.sin(p1[1] - p0[1]) * math.cos(p1[0]),
            math.cos(p0[0]) * math.sin(p1[0])
            - math.sin(p0[0]) * math.cos(p1[0]) * math.cos(p1[1] - p0[1]),
        )
        assert bearing == pytest.approx(math.atan2(east, north), abs=2e-4)
