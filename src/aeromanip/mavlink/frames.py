"""The one place where aeromanip's frames meet MAVLink's (every conversion of the bridge
and the SITL autopilot goes through here).

aeromanip (DESIGN.md, ROS REP 103): world ENU (x east, y north, z up), body FLU (x
forward, y left, z up), yaw about world z from east, counter-clockwise. MAVLink / PX4:
local NED (x north, y east, z down), body FRD (x forward, y right, z down), yaw about
down from north, clockwise. Both swaps are their own inverse::

    ENU <-> NED: (a, b, c) -> (b, a, -c)        FLU <-> FRD: (a, b, c) -> (a, -b, -c)

so ``R_ned_frd = P R_enu_flu F`` with ``P`` the ENU/NED permutation and ``F =
diag(1, -1, -1)``: roll keeps its sign, pitch and the yaw rate change theirs, and
``yaw_ned = pi/2 - yaw_enu``. Angles in rad, Euler angles ZYX (yaw, pitch, roll).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

Vec3 = tuple[float, float, float]

_P = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # ENU <-> NED
_F = np.diag([1.0, -1.0, -1.0])  # FLU <-> FRD


def enu_to_ned(v: Sequence[float]) -> Vec3:
    """A world vector (position [m], velocity [m/s]) from ENU to NED."""
    return (float(v[1]), float(v[0]), -float(v[2]))


def ned_to_enu(v: Sequence[float]) -> Vec3:
    """A world vector from NED to ENU (the same swap: it is its own inverse)."""
    return (float(v[1]), float(v[0]), -float(v[2]))


def flu_to_frd(v: Sequence[float]) -> Vec3:
    """A body vector (e.g. body rates [rad/s]) from FLU to FRD."""
    return (float(v[0]), -float(v[1]), -float(v[2]))


def frd_to_flu(v: Sequence[float]) -> Vec3:
    """A body vector from FRD to FLU (its own inverse)."""
    return (float(v[0]), -float(v[1]), -float(v[2]))


def wrap(angle: float) -> float:
    """``angle`` [rad] in ``[-pi, pi]``."""
    return math.remainder(float(angle), 2.0 * math.pi)


def yaw_enu_to_ned(yaw: float) -> float:
    """Heading [rad]: from east counter-clockwise -> from north clockwise, in [-pi, pi]."""
    return wrap(0.5 * math.pi - float(yaw))


def yaw_ned_to_enu(yaw: float) -> float:
    """Heading [rad]: from north clockwise -> from east counter-clockwise, in [-pi, pi]."""
    return wrap(0.5 * math.pi - float(yaw))


def yaw_rate_enu_to_ned(rate: float) -> float:
    """Yaw rate [rad/s] about world up -> about world down (the sign flips)."""
    return -float(rate)


def yaw_rate_ned_to_enu(rate: float) -> float:
    """Yaw rate [rad/s] about world down -> about world up."""
    return -float(rate)


def rotation_zyx(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Body-to-world rotation ``Rz(yaw) Ry(pitch) Rx(roll)`` (3x3)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def euler_zyx(R: np.ndarray) -> Vec3:
    """(roll, pitch, yaw) [rad] of a body-to-world rotation (ZYX; pitch in [-pi/2, pi/2])."""
    R = np.asarray(R, dtype=float)
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    return (math.atan2(R[2, 1], R[2, 2]), pitch, math.atan2(R[1, 0], R[0, 0]))


def attitude_enu_to_ned(roll: float, pitch: float, yaw: float) -> Vec3:
    """Euler angles of FLU in ENU -> Euler angles of FRD in NED [rad]."""
    return euler_zyx(_P @ rotation_zyx(roll, pitch, yaw) @ _F)


def attitude_ned_to_enu(roll: float, pitch: float, yaw: float) -> Vec3:
    """Euler angles of FRD in NED -> Euler angles of FLU in ENU [rad]."""
    return euler_zyx(_P @ rotation_zyx(roll, pitch, yaw) @ _F)


def euler_yaw_rate(roll: float, pitch: float, wy: float, wz: float) -> float:
    """The ZYX yaw angle's rate [rad/s] from the body rates about body y and z [rad/s]
    (same-handed body and world frames, both FLU/ENU or both FRD/NED)."""
    return (wy * math.sin(roll) + wz * math.cos(roll)) / math.cos(pitch)
