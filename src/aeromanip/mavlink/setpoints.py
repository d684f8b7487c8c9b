"""Offboard setpoints as PX4 reads them, and how the SITL flies them.

``from_local_ned`` follows PX4's ``MavlinkReceiver::handle_message_set_position_target_
local_ned`` (``src/modules/mavlink/mavlink_receiver.cpp`` L1029-1146 at PX4 commit
161b530): a field whose ``type_mask`` bit is set is NaN, NaN means "not set"; only
``MAV_FRAME_LOCAL_NED`` and ``MAV_FRAME_BODY_NED`` are taken (in BODY_NED the position is
never used, the velocity turns with the heading and the acceleration with the attitude,
each all or nothing, and the yaw stays absolute); a ``FORCE_SET`` acceleration, another
frame, or no position, velocity or acceleration at all are refused with PX4's critical
messages. What PX4's position controller would then reject (``PositionControl::
_inputValid``: an infinite value, an axis with nothing set, x without y) is refused here
too, as this SITL has no later stage.

``velocity_and_yaw_rate`` stands in for PX4's position controller (``PositionControl``):
per axis a position P loop with the velocity as feed-forward, else the velocity, else
the acceleration through the velocity loop; the yaw by a P loop with the yaw rate as
feed-forward (no yaw: the heading held). Vectors and angles are NED (north, east, down;
yaw clockwise from north), as MAVLink's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from aeromanip.mavlink.frames import rotation_zyx
from aeromanip.mavlink.protocol import (
    AX_IGNORE,
    AY_IGNORE,
    AZ_IGNORE,
    MAV_FRAME_LOCAL_NED,
    VX_IGNORE,
    VY_IGNORE,
    VZ_IGNORE,
    X_IGNORE,
    Y_IGNORE,
    YAW_IGNORE,
    YAW_RATE_IGNORE,
    Z_IGNORE,
)
from aeromanip.sim.flight_controller import FlightGains

FORCE_SET = 512  # POSITION_TARGET_TYPEMASK_FORCE_SET: the acceleration is a force
MAV_FRAME_BODY_NED = 8
NAN3 = (math.nan, math.nan, math.nan)
PREFIX = "SET_POSITION_TARGET_LOCAL_NED"
#: the controller-stage refusal (PX4 says "invalid setpoints" on its console only)
INVALID = f"{PREFIX}: invalid setpoints"

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Setpoint:
    """PX4's ``trajectory_setpoint`` in local NED: NaN where not set."""

    position: Vec3 = NAN3  # [m]
    velocity: Vec3 = NAN3  # [m/s]
    acceleration: Vec3 = NAN3  # [m/s^2]
    yaw: float = math.nan  # [rad]
    yaw_rate: float = math.nan  # [rad/s]


def _masked(values: tuple[float, ...], mask: int, bits: tuple[int, ...]) -> Vec3:
    """``values`` with NaN where their ``bits`` are set in ``mask``."""
    a, b, c = (math.nan if mask & bit else float(v) for v, bit in zip(values, bits, strict=True))
    return a, b, c


def _turned(v: Vec3, R: np.ndarray) -> Vec3:
    a, b, c = (R @ np.asarray(v, dtype=float)).tolist()
    return a, b, c


def _finite_any(v: Vec3) -> bool:
    return not all(math.isnan(x) for x in v)


def _vectors(msg: Any, mask: int, attitude: Vec3) -> tuple[Vec3, Vec3, Vec3]:
    """Position, velocity and acceleration in local NED (PX4 L1043-1100)."""
    vel_bits, acc_bits = (VX_IGNORE, VY_IGNORE, VZ_IGNORE), (AX_IGNORE, AY_IGNORE, AZ_IGNORE)
    vel = _masked((msg.vx, msg.vy, msg.vz), mask, vel_bits)
    acc = _masked((msg.afx, msg.afy, msg.afz), mask, acc_bits)
    if int(msg.coordinate_frame) == MAV_FRAME_LOCAL_NED:
        return _masked((msg.x, msg.y, msg.z), mask, (X_IGNORE, Y_IGNORE, Z_IGNORE)), vel, acc
    roll, pitch, yaw = attitude  # BODY_NED: each vector all or nothing, no position
    vel = NAN3 if mask & sum(vel_bits) else _turned(vel, rotation_zyx(0.0, 0.0, yaw))
    acc = NAN3 if mask & sum(acc_bits) else _turned(acc, rotation_zyx(roll, pitch, yaw))
    return NAN3, vel, acc


def _controller_refuses(pos: Vec3, vel: Vec3, acc: Vec3, yaw: float, rate: float) -> bool:
    """What PX4's ``PositionControl::_inputValid`` rejects: an infinite value, an axis with
    no finite position, velocity or acceleration, or x set without y (or y without x)."""
    values = (*pos, *vel, *acc, yaw, rate)
    if any(math.isinf(v) for v in values):
        return True
    if not all(any(math.isfinite(v[i]) for v in (pos, vel, acc)) for i in range(3)):
        return True
    return any(math.isfinite(v[0]) != math.isfinite(v[1]) for v in (pos, vel, acc))


def from_local_ned(msg: Any, attitude: Vec3) -> Setpoint | str:
    """The setpoint of a ``SET_POSITION_TARGET_LOCAL_NED`` for a vehicle at ``attitude``
    (roll, pitch, yaw [rad], NED), or why it is refused (module docstring)."""
    mask, frame = int(msg.type_mask), int(msg.coordinate_frame)
    if frame not in (MAV_FRAME_LOCAL_NED, MAV_FRAME_BODY_NED):
        return f"{PREFIX} coordinate frame {frame} unsupported"
    pos, vel, acc = _vectors(msg, mask, attitude)
    yaw = math.nan if mask & YAW_IGNORE else float(msg.yaw)
    rate = math.nan if mask & YAW_RATE_IGNORE else float(msg.yaw_rate)
    if _finite_any(acc) and mask & FORCE_SET:
        return f"{PREFIX} force not supported"
    if not (_finite_any(pos) or _finite_any(vel) or _finite_any(acc)):
        return f"{PREFIX} invalid"
    if _controller_refuses(pos, vel, acc, yaw, rate):
        return INVALID
    return Setpoint(pos, vel, acc, yaw, rate)


def velocity_and_yaw_rate(
    sp: Setpoint,
    position: Vec3,
    velocity: Vec3,
    yaw: float,
    dt: float,
    gains: FlightGains | None = None,
) -> tuple[Vec3, float]:
    """The velocity [m/s, NED] and yaw rate [rad/s, NED] that fly ``sp`` from the
    vehicle's ``position``, ``velocity`` and ``yaw`` over the next ``dt`` [s]."""
    g = gains or FlightGains()
    p_gain = (g.pos_p_xy, g.pos_p_xy, g.pos_p_z)
    out = []
    for i in range(3):
        p, v, a = sp.position[i], sp.velocity[i], sp.acceleration[i]
        if math.isfinite(p):
            out.append(p_gain[i] * (p - position[i]) + (v if math.isfinite(v) else 0.0))
        elif math.isfinite(v):
            out.append(v)
        elif math.isfinite(a):
            out.append(velocity[i] + a * dt)
        else:  # not flown: from_local_ned refuses such setpoints
            out.append(0.0)
    rate = sp.yaw_rate if math.isfinite(sp.yaw_rate) else 0.0
    if math.isfinite(sp.yaw):
        rate += g.att_p_yaw * math.remainder(sp.yaw - yaw, 2.0 * math.pi)
    return (out[0], out[1], out[2]), rate
