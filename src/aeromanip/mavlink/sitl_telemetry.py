"""What the SITL autopilot streams to a ground station or an offboard app, as PX4 does
(``src/modules/mavlink/streams/*.hpp`` and ``mavlink_main.cpp`` at PX4 commit 161b530).

Each stream has a period in SITL ticks (``DEFAULT_HZ``; the state messages at the SITL's
``state_hz``); ``SET_MESSAGE_INTERVAL`` changes it, ``REQUEST_MESSAGE`` sends one now.

- ``HEARTBEAT`` (PX4 ``HEARTBEAT.hpp`` L66-136): ``base_mode`` = CUSTOM_MODE_ENABLED, +
  SAFETY_ARMED when armed, + AUTO | GUIDED | STABILIZE in Hold (29 / 157), + STABILIZE in
  Offboard (17 / 145); ``custom_mode`` PX4's ``main << 16 | sub << 24``.
- ``SYS_STATUS`` (``SYS_STATUS.hpp`` L106-187): the sensors a PX4 SITL without RC has,
  present, enabled and healthy, with ``PREARM_CHECK`` (the SITL can always arm); ``load``
  the share of each tick spent working; no battery (UINT16_MAX, -1, -1).
- ``EXTENDED_SYS_STATE``: landed ON_GROUND while disarmed (the vehicle is pinned at its
  start), IN_AIR while armed (it always flies: there is no take-off or landing).
- ``HOME_POSITION`` and ``GLOBAL_POSITION_INT``: the local origin sits at a fixed place,
  PX4's own SITL default (``HOME_LAT_DEG``, ``HOME_LON_DEG``, ``HOME_ALT_M``: Zurich); home
  is the vehicle's start point; latitude and longitude from the local NED position on a
  sphere of radius ``EARTH_RADIUS_M`` (flat earth: PX4's projection agrees within 1 mm
  over 100 m).
- ``SYSTEM_TIME``: wall clock [us] and SITL time [ms]; ``AUTOPILOT_VERSION`` on request.
- ``LOCAL_POSITION_NED``, ``ATTITUDE`` and the joints (``NAMED_VALUE_FLOAT``) from the
  measured state (the physics' measurement noise), with a surface the wrist sensor's
  reading beside the joints (``arm.WRENCH_NAMES``, with its noise); ``ODOMETRY`` (the
  same, stamped with the SITL time) when asked for, as on PX4's ground-station link.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

from aeromanip.mavlink.arm import WRENCH_NAMES, joint_name
from aeromanip.mavlink.protocol import (
    MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
    MAV_MODE_FLAG_SAFETY_ARMED,
    custom_mode,
)

HOME_LAT_DEG = 47.397742  # [deg] the local origin: PX4 SITL's default home
HOME_LON_DEG = 8.545594  # [deg]
HOME_ALT_M = 488.0  # [m] above mean sea level
EARTH_RADIUS_M = 6371000.0  # [m]
DEFAULT_HZ = {  # [Hz] PX4's rates on a ground-station link (mavlink_main.cpp L1422-1489)
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 1.0,
    "EXTENDED_SYS_STATE": 1.0,
    "HOME_POSITION": 0.5,
    "GLOBAL_POSITION_INT": 5.0,
    "SYSTEM_TIME": 1.0,
}
STATE_MESSAGES = ("LOCAL_POSITION_NED", "ATTITUDE", "NAMED_VALUE_FLOAT")
#: streams PX4 sends on an onboard link only: off here until SET_MESSAGE_INTERVAL asks
#: (its "default", interval 0, is then this rate [Hz], to the nearest whole number of
#: ticks; mavlink_main.cpp L1491-1563)
ONBOARD_HZ = {"ODOMETRY": 30.0}
ON_REQUEST = ("AUTOPILOT_VERSION",)
MAV_MODE_FLAG_STABILIZE, MAV_MODE_FLAG_GUIDED, MAV_MODE_FLAG_AUTO = 16, 8, 4
MODE_FLAGS = {  # what PX4 adds to base_mode in each mode (HEARTBEAT.hpp L86-100)
    "hold": MAV_MODE_FLAG_AUTO | MAV_MODE_FLAG_GUIDED | MAV_MODE_FLAG_STABILIZE,
    "offboard": MAV_MODE_FLAG_STABILIZE,
}
#: AUTOPILOT_VERSION.capabilities: only what the SITL does (MAVLINK2 | COMMAND_INT |
#: PARAM_FLOAT | PARAM_ENCODE_BYTEWISE | MISSION_INT | SET_POSITION_TARGET_LOCAL_NED = 8350)
CAPABILITIES = 8192 | 8 | 2 | 16 | 4 | 128
FLIGHT_SW_VERSION = (0 << 24) | (1 << 16)  # aeromanip 0.1.0, FIRMWARE_VERSION_TYPE_DEV
AUTOPILOT_UID = 0x61656D616E6970  # "aemanip": one SITL vehicle
MAV_LANDED_STATE_ON_GROUND, MAV_LANDED_STATE_IN_AIR = 1, 2
NO_BATTERY = (0xFFFF, -1, -1)  # voltage [mV], current [cA], remaining [%]

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Measurement:
    """What the autopilot's estimator says at SITL time ``t`` [s] (NED, FRD)."""

    t: float
    position: Vec3  # [m]
    velocity: Vec3  # [m/s]
    attitude: Vec3  # roll, pitch, yaw [rad]
    rates: Vec3  # body rates [rad/s]
    joints: tuple[float, ...]  # [rad]
    wrench: tuple[float, ...] | None = None  # the wrist sensor's [f, tau] [N, N m], ENU


@dataclass(frozen=True)
class Status:
    """The autopilot's state for the status messages: ``load`` is the share [0, 1] of
    a tick spent working."""

    armed: bool
    mode: str
    load: float = 0.0


def sensors(m: Any) -> int:
    """``SYS_STATUS`` sensor bits of a PX4 SITL without RC (present = enabled = healthy)."""
    names = ("3D_GYRO", "3D_ACCEL", "3D_MAG", "ABSOLUTE_PRESSURE", "GPS",
             "ATTITUDE_STABILIZATION", "XY_POSITION_CONTROL", "MOTOR_OUTPUTS")  # fmt: skip
    bits = m.MAV_SYS_STATUS_AHRS
    for name in names:
        bits |= getattr(m, f"MAV_SYS_STATUS_SENSOR_{name}")
    return bits


def global_position(position: Vec3) -> tuple[int, int, int]:
    """Latitude, longitude [degE7] and altitude [mm AMSL] of a local NED ``position`` [m]."""
    north, east, down = position
    lat = HOME_LAT_DEG + math.degrees(north / EARTH_RADIUS_M)
    lon = HOME_LON_DEG + math.degrees(east / (EARTH_RADIUS_M * math.cos(math.radians(lat))))
    return round(lat * 1e7), round(lon * 1e7), round((HOME_ALT_M - down) * 1e3)


class Telemetry:
    """The SITL's streams on ``conn`` (pymavlink connection, dialect module ``m``):
    periods in ticks of ``tick`` [s]; home at the NED point ``home`` [m]."""

    def __init__(
        self, conn: Any, m: Any, tick: float, state_hz: float, mav_type: int, home: Vec3
    ) -> None:
        self.conn, self.m, self.tick, self.mav_type, self.home = conn, m, tick, mav_type, home
        rates = DEFAULT_HZ | dict.fromkeys(STATE_MESSAGES, state_hz) | ONBOARD_HZ
        self.default_every: dict[str, int] = {
            name: max(1, round(1.0 / (hz * tick))) for name, hz in rates.items()
        }
        self.every: dict[str, int | None] = dict(self.default_every) | dict.fromkeys(ONBOARD_HZ)
        self.sent: dict[str, int] = {}  # message name -> how many were sent
        self._senders = {
            "HEARTBEAT": self._heartbeat,
            "SYS_STATUS": self._sys_status,
            "EXTENDED_SYS_STATE": self._extended_sys_state,
            "HOME_POSITION": self._home_position,
            "GLOBAL_POSITION_INT": self._global_position,
            "SYSTEM_TIME": self._system_time,
            "LOCAL_POSITION_NED": self._local_position,
            "ATTITUDE": self._attitude,
            "NAMED_VALUE_FLOAT": self._joints,
            "ODOMETRY": self._odometry,
            "AUTOPILOT_VERSION": self._autopilot_version,
        }

    def stream(self, k: int, meas: Measurement, status: Status) -> None:
        """Send what is due at tick ``k``."""
        for name, every in self.every.items():
            if every is not None and k % every == 0:
                self.send(name, meas, status)

    def send(self, name: str, meas: Measurement, status: Status) -> None:
        """Send message ``name`` now (a stream or ``ON_REQUEST``)."""
        self._senders[name](meas, status)
        self.sent[name] = self.sent.get(name, 0) + 1

    def name(self, msgid: float) -> str | None:
        """The name of a message the SITL can send, by id (else ``None``)."""
        if not math.isfinite(msgid) or msgid != int(msgid):
            return None
        entry = self.m.mavlink_map.get(int(msgid))
        name = getattr(entry, "msgname", None)
        return name if name in self._senders else None

    def set_interval(self, name: str, interval_us: float) -> bool:
        """``SET_MESSAGE_INTERVAL``: > 0 that period [us], 0 the default, < 0 stop; False
        for a message that is not a stream, for HEARTBEAT (fixed) or a non-finite interval
        (PX4 ``mavlink_receiver.cpp`` ``set_message_interval`` L2239-2285)."""
        if name not in self.default_every or name == "HEARTBEAT" or not math.isfinite(interval_us):
            return False
        if interval_us < 0:
            self.every[name] = None
        elif interval_us == 0:
            self.every[name] = self.default_every[name]
        else:
            self.every[name] = max(1, round(1e-6 * interval_us / self.tick))
        return True

    def interval_us(self, name: str | None) -> int:
        """A stream's period [us] (``GET_MESSAGE_INTERVAL``), -1 if not streamed."""
        every = self.every.get(name) if name is not None else None
        return -1 if every is None else round(1e6 * every * self.tick)

    def _heartbeat(self, meas: Measurement, status: Status) -> None:
        base = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | MODE_FLAGS.get(status.mode, 0)
        base |= MAV_MODE_FLAG_SAFETY_ARMED if status.armed else 0
        state = self.m.MAV_STATE_ACTIVE if status.armed else self.m.MAV_STATE_STANDBY
        self.conn.mav.heartbeat_send(
            self.mav_type, self.m.MAV_AUTOPILOT_PX4, base, custom_mode(status.mode), state
        )

    def _sys_status(self, meas: Measurement, status: Status) -> None:
        bits = sensors(self.m)
        load = min(1000, max(0, round(1000 * status.load)))
        self.conn.mav.sys_status_send(
            bits, bits, bits | self.m.MAV_SYS_STATUS_PREARM_CHECK, load, *NO_BATTERY,
            0, 0, 0, 0, 0, 0,
        )  # fmt: skip

    def _extended_sys_state(self, meas: Measurement, status: Status) -> None:
        landed = MAV_LANDED_STATE_IN_AIR if status.armed else MAV_LANDED_STATE_ON_GROUND
        self.conn.mav.extended_sys_state_send(0, landed)  # vtol_state UNDEFINED

    def _home_position(self, meas: Measurement, status: Status) -> None:
        lat, lon, alt = global_position(self.home)
        self.conn.mav.home_position_send(
            lat, lon, alt, *self.home, (1.0, 0.0, 0.0, 0.0), 0.0, 0.0, 0.0, _usec(meas.t)
        )

    def _global_position(self, meas: Measurement, status: Status) -> None:
        lat, lon, alt = global_position(meas.position)
        relative = round(1e3 * (self.home[2] - meas.position[2]))
        vn, ve, vd = (_clamp16(100.0 * v) for v in meas.velocity)
        hdg = round(math.degrees(meas.attitude[2] % (2.0 * math.pi)) * 100.0) % 36000
        ms = _ms(meas.t)
        self.conn.mav.global_position_int_send(ms, lat, lon, alt, relative, vn, ve, vd, hdg)

    def _system_time(self, meas: Measurement, status: Status) -> None:
        self.conn.mav.system_time_send(round(1e6 * time.time()), _ms(meas.t))

    def _local_position(self, meas: Measurement, status: Status) -> None:
        self.conn.mav.local_position_ned_send(_ms(meas.t), *meas.position, *meas.velocity)

    def _attitude(self, meas: Measurement, status: Status) -> None:
        self.conn.mav.attitude_send(_ms(meas.t), *meas.attitude, *meas.rates)

    def _joints(self, meas: Measurement, status: Status) -> None:
        ms = _ms(meas.t)
        for i, value in enumerate(meas.joints):
            self.conn.mav.named_value_float_send(ms, joint_name(i).encode(), value)
        for name, value in zip(WRENCH_NAMES, meas.wrench or (), strict=False):
            self.conn.mav.named_value_float_send(ms, name.encode(), value)

    def _odometry(self, meas: Measurement, status: Status) -> None:
        """PX4's ``streams/ODOMETRY.hpp`` L60-130: stamped with the measurement's time,
        position and velocity in local NED, the attitude quaternion, body rates;
        covariances unknown (NaN)."""
        ned = self.m.MAV_FRAME_LOCAL_NED
        unknown = [math.nan] * 21
        self.conn.mav.odometry_send(
            _usec(meas.t), ned, ned, *meas.position, quaternion(*meas.attitude),
            *meas.velocity, *meas.rates, unknown, unknown, 0,
            self.m.MAV_ESTIMATOR_TYPE_AUTOPILOT, 0,
        )  # fmt: skip

    def _autopilot_version(self, meas: Measurement, status: Status) -> None:
        self.conn.mav.autopilot_version_send(
            CAPABILITIES, FLIGHT_SW_VERSION, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0,
            AUTOPILOT_UID,
        )  # fmt: skip


def quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """The attitude (Z-Y-X Euler angles [rad]) as a quaternion (w, x, y, z)."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def _ms(t: float) -> int:
    """SITL time [s] as ``time_boot_ms`` (rounded: ``t`` sums ticks in floating point)."""
    return round(1e3 * t) & 0xFFFFFFFF


def _usec(t: float) -> int:
    return round(1e6 * t)


def _clamp16(v: float) -> int:
    return max(-32768, min(32767, round(v)))


STATUSTEXT_CHARS = 50  # one STATUSTEXT's text; longer ones are chunks with one ``id``
REPEAT_EVERY_S = 1.0  # [s] the same text is said at most this often


class StatusTexts:
    """``STATUSTEXT`` on ``conn`` as PX4 sends them (``STATUSTEXT.hpp`` L69-124): a text
    over 50 characters in chunks sharing an ``id`` (``chunk_seq`` 0, 1, ..); the same
    text at most once per ``REPEAT_EVERY_S`` (a flood of one refusal is said once)."""

    def __init__(self, conn: Any) -> None:
        self.conn = conn
        self._said: dict[str, float] = {}  # text -> when it was last said [s]
        self._id = 0
        self.count = 0  # texts sent

    def say(self, t: float, text: str, severity: int) -> bool:
        """Send ``text`` at SITL time ``t`` [s] (False: said within the last second)."""
        if t - self._said.get(text, -math.inf) < REPEAT_EVERY_S:
            return False
        self._said[text] = t
        data = text.encode(errors="replace")
        chunks = [data[i : i + STATUSTEXT_CHARS] for i in range(0, len(data), STATUSTEXT_CHARS)]
        self._id = self._id % 0xFFFF + 1 if len(chunks) > 1 else 0
        for seq, chunk in enumerate(chunks or [b""]):
            self.conn.mav.statustext_send(severity, chunk, self._id, seq)
        self.count += 1
        return True
