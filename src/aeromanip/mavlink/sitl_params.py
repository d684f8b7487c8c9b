"""The SITL's parameters (PX4's names, each one changing what the SITL does) and the
parameter and mission protocols as PX4 speaks them (PX4 commit 161b530).

Parameters (``PARAMS``; PX4's defaults and ranges from its ``*_params.c`` unless said):

- ``COM_OF_LOSS_T`` [s]: no setpoint for this long in offboard -> the offboard-loss
  action (``commander_params.c`` L318-329; the SITL's default 0.5 s, PX4's 1.0 s).
- ``COM_OBL_RC_ACT``: that action; 5 (Hold) is the only one this SITL flies, so it is the
  default and the only value taken (PX4's default 0 falls back to Return without RC,
  L341-358).
- ``MPC_XY_VEL_MAX``, ``MPC_Z_VEL_MAX_UP``, ``MPC_Z_VEL_MAX_DN`` [m/s]: the velocity
  setpoint's limits (``multicopter_position_control_limits_params.c`` L47, L64, L81;
  applied as ``PositionControl.cpp`` L133-137).
- ``MC_YAWRATE_MAX`` [deg/s]: the yaw-rate setpoint's limit (``mc_att_control_params.c``
  L147).

Protocol (``mavlink_parameters.cpp``): requests for this system and component 1 or 0;
``PARAM_REQUEST_LIST`` -> every ``PARAM_VALUE``; ``PARAM_REQUEST_READ`` by name
(``param_index`` -1) or index, an unknown one -> ``PARAM_ERROR`` DOES_NOT_EXIST (L192-239);
``PARAM_SET`` -> the stored ``PARAM_VALUE`` echoed (L144-147), or ``PARAM_ERROR``:
DOES_NOT_EXIST, TYPE_UNSUPPORTED (not INT32 / REAL32), TYPE_MISMATCH (L130-141), or
VALUE_OUT_OF_RANGE (not finite, outside the range: PX4 stores any value; the SITL cannot
fly one outside), with a STATUSTEXT. INT32 values travel bytewise in the float field
(L517-526).

Missions (``mavlink_mission.cpp``): the SITL flies none. ``MISSION_REQUEST_LIST`` ->
``MISSION_COUNT`` 0 of the type asked (L724-782); an upload (``MISSION_COUNT`` > 0) ->
``MISSION_ACK`` NO_SPACE (L921-926), of 0 or ``MISSION_CLEAR_ALL`` -> ACCEPTED (L1379).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any

from aeromanip.mavlink.vehicle import LOSS_S

INT32, REAL32 = 6, 9  # MAV_PARAM_TYPE
#: MAV_PARAM_ERROR (MAVLink common.xml; 6 and 7 are newer than pymavlink's copy)
DOES_NOT_EXIST, VALUE_OUT_OF_RANGE, TYPE_UNSUPPORTED, TYPE_MISMATCH = 1, 2, 6, 7
MAV_MISSION_ACCEPTED, MAV_MISSION_NO_SPACE = 0, 4
MISSION_COMPONENTS = (0, 1, 190)  # the autopilot, broadcast, MAV_COMP_ID_MISSIONPLANNER
SEVERITY_CRITICAL = 2


@dataclass(frozen=True)
class Param:
    """One parameter: PX4's ``name``, ``kind`` (INT32 / REAL32), default and range."""

    name: str
    kind: int
    default: float
    low: float
    high: float
    meaning: str


PARAMS = (
    Param("COM_OF_LOSS_T", REAL32, LOSS_S, 0.0, 60.0,
          "[s] offboard: no setpoint for this long -> COM_OBL_RC_ACT"),
    Param("COM_OBL_RC_ACT", INT32, 5, 5, 5, "offboard-loss action: 5 Hold (the only one)"),
    Param("MPC_XY_VEL_MAX", REAL32, 12.0, 0.0, 20.0, "[m/s] horizontal velocity limit"),
    Param("MPC_Z_VEL_MAX_UP", REAL32, 3.0, 0.5, 8.0, "[m/s] climb rate limit"),
    Param("MPC_Z_VEL_MAX_DN", REAL32, 1.5, 0.5, 4.0, "[m/s] descent rate limit"),
    Param("MC_YAWRATE_MAX", REAL32, 200.0, 0.0, 1800.0, "[deg/s] yaw rate limit"),
)  # fmt: skip


def to_wire(value: float, kind: int) -> float:
    """A value as PARAM_VALUE / PARAM_SET carry it: INT32 bytewise in the float."""
    if kind == INT32:
        return struct.unpack("<f", struct.pack("<i", int(value)))[0]
    return value


def from_wire(value: float, kind: int) -> float:
    """The value a PARAM_SET of ``kind`` means (INT32: the float's bytes)."""
    if kind == INT32:
        return float(struct.unpack("<i", struct.pack("<f", value))[0])
    return float(struct.unpack("<f", struct.pack("<f", value))[0])  # as float32


def _name(raw: Any) -> str:
    """A ``param_id`` (16 characters, NUL-padded) as text."""
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", errors="replace")
    return str(raw).split("\x00", 1)[0]


class Parameters:
    """The SITL's parameter values and its parameter and mission protocols on ``conn``
    for system ``system_id`` (module docstring); ``say(text, severity)`` sends a
    STATUSTEXT."""

    def __init__(self, conn: Any, system_id: int, say: Any) -> None:
        self.conn, self.system_id, self.say = conn, system_id, say
        self.specs = {p.name: p for p in PARAMS}
        self.values = {p.name: float(p.default) for p in PARAMS}
        self.names = [p.name for p in PARAMS]

    def __getitem__(self, name: str) -> float:
        return self.values[name]

    def _for_us(self, msg: Any, components: tuple[int, ...] = (0, 1)) -> bool:
        return msg.target_system == self.system_id and msg.target_component in components

    def _sender(self, msg: Any) -> tuple[int, int]:
        return int(msg.get_srcSystem()), int(msg.get_srcComponent())

    def send_value(self, name: str) -> None:
        """One ``PARAM_VALUE``."""
        spec = self.specs[name]
        self.conn.mav.param_value_send(
            name.encode(), to_wire(self.values[name], spec.kind), spec.kind,
            len(self.names), self.names.index(name),
        )  # fmt: skip

    def _error(self, msg: Any, name: str, index: int, error: int) -> None:
        self.conn.mav.param_error_send(*self._sender(msg), name.encode()[:16], index, error)

    def on_request_list(self, msg: Any) -> None:
        """``PARAM_REQUEST_LIST``: every parameter."""
        if self._for_us(msg):
            for name in self.names:
                self.send_value(name)

    def on_request_read(self, msg: Any) -> None:
        """``PARAM_REQUEST_READ`` by name (``param_index`` < 0) or by index."""
        if not self._for_us(msg):
            return
        index = int(msg.param_index)
        if index < 0:
            name = _name(msg.param_id)
            if name in self.specs:
                self.send_value(name)
            else:
                self._error(msg, name, -1, DOES_NOT_EXIST)
        elif index < len(self.names):
            self.send_value(self.names[index])
        else:
            self._error(msg, "", index, DOES_NOT_EXIST)

    def on_set(self, msg: Any) -> None:
        """``PARAM_SET``: the value stored and echoed, or a ``PARAM_ERROR``."""
        if not self._for_us(msg):
            return
        name, kind = _name(msg.param_id), int(msg.param_type)
        spec = self.specs.get(name)
        if spec is None:
            self._error(msg, name, -1, DOES_NOT_EXIST)
        elif kind not in (INT32, REAL32):
            self._error(msg, name, -1, TYPE_UNSUPPORTED)
        elif kind != spec.kind:
            self._error(msg, name, -1, TYPE_MISMATCH)
        else:
            value = from_wire(float(msg.param_value), kind)
            if not (math.isfinite(value) and spec.low <= value <= spec.high):
                self._error(msg, name, -1, VALUE_OUT_OF_RANGE)
                self.say(f"{name}: {value:g} refused: allowed {spec.low:g} to {spec.high:g}",
                         SEVERITY_CRITICAL)  # fmt: skip
                return
            self.values[name] = value
            self.send_value(name)

    def on_mission_request_list(self, msg: Any) -> None:
        """``MISSION_REQUEST_LIST``: an empty mission (fence, rally) of the type asked."""
        if self._for_us(msg, MISSION_COMPONENTS):
            self.conn.mav.mission_count_send(*self._sender(msg), 0, int(msg.mission_type))

    def on_mission_count(self, msg: Any) -> None:
        """``MISSION_COUNT`` (an upload): no room for any item; 0 items clears."""
        if self._for_us(msg, MISSION_COMPONENTS):
            result = MAV_MISSION_NO_SPACE if int(msg.count) > 0 else MAV_MISSION_ACCEPTED
            self.conn.mav.mission_ack_send(*self._sender(msg), result, int(msg.mission_type))

    def on_mission_clear_all(self, msg: Any) -> None:
        """``MISSION_CLEAR_ALL``: there is nothing to clear; ACCEPTED."""
        if self._for_us(msg, MISSION_COMPONENTS):
            self.conn.mav.mission_ack_send(
                *self._sender(msg), MAV_MISSION_ACCEPTED, int(msg.mission_type)
            )

    def handlers(self) -> dict[str, Any]:
        """Message type -> handler, for the SITL's receive loop."""
        return {
            "PARAM_REQUEST_LIST": self.on_request_list,
            "PARAM_REQUEST_READ": self.on_request_read,
            "PARAM_SET": self.on_set,
            "MISSION_REQUEST_LIST": self.on_mission_request_list,
            "MISSION_COUNT": self.on_mission_count,
            "MISSION_CLEAR_ALL": self.on_mission_clear_all,
        }
