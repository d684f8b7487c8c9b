"""Offboard setpoints as PX4 reads them, and how the SITL flies them.

``from_local_ned`` follows PX4's ``MavlinkReceiver::handle_message_set_position_target_
local_ned`` (``src/modules/mavlink/mavlink_receiver.cpp``): every field whose
``type_mask`` bit is set is NaN (not set), and so is every non-finite value (PX4 decides
which controls are on by ``PX4_ISFINITE``); the frame turns the rest into PX4's local
NED ``trajectory_setpoint`` (position, velocity, acceleration, yaw, yaw rate);
``FORCE_SET`` with an acceleration, an unknown frame, or nothing finite left are refused
with the reason (PX4 logs the first two as critical messages and drops the third).

``velocity_and_yaw_rate`` is the SITL's stand-in for PX4's position controller: per axis
a position P loop (the inner loop's own gains) with the velocity as feed-forward, else the
velocity, else the acceleration through the velocity loop, else zero; the yaw by a P loop
with the yaw rate as feed-forward, else the yaw rate, else zero. Angles and vectors here
are NED (north, east, down; yaw clockwise from north), as MAVLink's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from aeromanip.mavlink.protocol import (
    AX_IGNORE,
    AY_IGNORE,
    AZ_IGNORE,
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
MAV_FRAME_LOCAL_NED, MAV_FRAME_LOCAL_OFFSET_NED = 1, 7
MAV_FRAME_BODY_NED, MAV_FRAME_BODY_OFFSET_NED, MAV_FRAME_BODY_FRD = 8, 9, 12
#: frames whose vectors turn with the vehicle's heading; their yaw is relative to it
BODY_FRAMES = (MAV_FRAME_BODY_NED, MAV_FRAME_BODY_OFFSET_NED, MAV_FRAME_BODY_FRD)
#: frames whose position is an offset from the vehicle's
OFFSET_FRAMES = (MAV_FRAME_LOCAL_OFFSET_NED, MAV_FRAME_BODY_OFFSET_NED, MAV_FRAME_BODY_FRD)
FRAMES = (MAV_FRAME_LOCAL_NED, *OFFSET_FRAMES, MAV_FRAME_BODY_NED)
NAN3 = (math.nan, math.nan, math.nan)

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
    """``values`` with NaN where their ``bits`` are set in ``mask`` or they are not finite."""
    a, b, c = (
        math.nan if mask & bit or not math.isfinite(v) else float(v)
        for v, bit in zip(values, bits, strict=True)
    )
    return a, b, c


def _turned(v: Vec3, yaw: float) -> Vec3:
    """``v`` from a heading-aligned frame to local NED (a rotation by ``yaw`` about down)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return (c * v[0] - s * v[1], s * v[0] + c * v[1], v[2])


def from_local_ned(msg: Any, position: Vec3, yaw: float) -> Setpoint | str:
    """The setpoint of a ``SET_POSITION_TARGET_LOCAL_NED`` for a vehicle at ``position``
    [m, NED] heading ``yaw`` [rad, NED], or why it is refused (module docstring)."""
    mask, frame = int(msg.type_mask), int(msg.coordinate_frame)
    if frame not in FRAMES:
        return f"SET_POSITION_TARGET_LOCAL_NED coordinate frame {frame} unsupported"
    pos = _masked((msg.x, msg.y, msg.z), mask, (X_IGNORE, Y_IGNORE, Z_IGNORE))
    vel = _masked((msg.vx, msg.vy, msg.vz), mask, (VX_IGNORE, VY_IGNORE, VZ_IGNORE))
    acc = _masked((msg.afx, msg.afy, msg.afz), mask, (AX_IGNORE, AY_IGNORE, AZ_IGNORE))
    yaw_sp = math.nan if mask & YAW_IGNORE or not math.isfinite(msg.yaw) else float(msg.yaw)
    rate = msg.yaw_rate
    yaw_rate = math.nan if mask & YAW_RATE_IGNORE or not math.isfinite(rate) else float(rate)
    if any(map(math.isfinite, acc)) and mask & FORCE_SET:
        return "SET_POSITION_TARGET_LOCAL_NED force not supported"
    if not any(map(math.isfinite, (*pos, *vel, *acc))):
        return "SET_POSITION_TARGET_LOCAL_NED: no finite position, velocity or acceleration"
    if frame in BODY_FRAMES:
        pos, vel, acc = _turned(pos, yaw), _turned(vel, yaw), _turned(acc, yaw)
        yaw_sp = yaw + yaw_sp  # NaN stays NaN
    if frame in OFFSET_FRAMES:
        pos = (pos[0] + position[0], pos[1] + position[1], pos[2] + position[2])
    return Setpoint(pos, vel, acc, yaw_sp, yaw_rate)


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
        else:
            out.append(0.0)
    feed = sp.yaw_rate if math.isfinite(sp.yaw_rate) else 0.0
    rate = feed
    if math.isfinite(sp.yaw):
        rate = g.att_p_yaw * math.remainder(sp.yaw - yaw, 2.0 * math.pi) + feed
    return (out[0], out[1], out[2]), rate
