"""The SITL autopilot's commands: ``COMMAND_LONG`` and ``COMMAND_INT`` read alike and
answered as PX4 answers them (``src/modules/mavlink/mavlink_receiver.cpp`` and
``src/modules/commander/Commander.cpp`` at PX4 commit 161b530).

- Target: ``target_system`` this vehicle (0 too for 519/520), ``target_component`` 1 or
  0; anything else is not for us and gets no ACK (``evaluate_target_ok`` L438-459).
- A malformed command (COMMAND_LONG with param5 = param6 = INT32_MAX, COMMAND_INT with
  x = y = 0x7ff80000) is DENIED (L474-482, L512-518).
- ``COMPONENT_ARM_DISARM`` (``Commander.cpp`` L981-1018): param1 must round to 0 or 1
  (else UNSUPPORTED); disarming in the air is TEMPORARILY_REJECTED, "Disarming denied:
  not landed" (this vehicle is always in the air once armed).
- ``DO_SET_MODE`` (L833-959) and the ``SET_MODE`` message: Hold and Offboard are flown;
  another PX4 mode is TEMPORARILY_REJECTED, "Switching to <mode> is currently not
  available"; an unknown one too ("Unsupported mode"; PX4 ACKs an unknown main mode
  ACCEPTED and does nothing, which no client can tell from a switch).
- ``NAV_LAND``, ``NAV_TAKEOFF``, ``NAV_RETURN_TO_LAUNCH``: modes this SITL cannot fly:
  TEMPORARILY_REJECTED with the same words.
- ``DO_SET_ACTUATOR``: the arm's joints (``arm.py``), each value clamped to [-1, 1] (an
  actuator output's range); a non-finite one keeps its joint.
- ``REQUEST_MESSAGE`` (and the older ``REQUEST_AUTOPILOT_CAPABILITIES``,
  ``GET_HOME_POSITION``): the message, then ACCEPTED; one the SITL cannot send: DENIED
  (``handle_request_message_command`` L757-790). ``SET_MESSAGE_INTERVAL``: ACCEPTED, or
  FAILED for HEARTBEAT, a message that is not a stream, params 3, 4, 7 set
  (L2239-2285); ``GET_MESSAGE_INTERVAL``: a ``MESSAGE_INTERVAL``, no ACK.
- Anything else: UNSUPPORTED (Commander's ``default:`` L1600-1604).

Each ACK is addressed to the sender's system and component (``answer_command``
L2670-2709).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

from aeromanip.mavlink.arm import MAV_CMD_DO_SET_ACTUATOR, actuator_to_joint
from aeromanip.mavlink.protocol import MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, MODES
from aeromanip.mavlink.sitl_telemetry import Telemetry
from aeromanip.mavlink.vehicle import ACCEPTED, DENIED, TEMPORARILY_REJECTED, Vehicle

UNSUPPORTED, FAILED = 3, 4  # MAV_RESULT
MAV_CMD_NAV_RETURN_TO_LAUNCH, MAV_CMD_NAV_LAND, MAV_CMD_NAV_TAKEOFF = 20, 21, 22
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_GET_HOME_POSITION = 410
MAV_CMD_GET_MESSAGE_INTERVAL, MAV_CMD_SET_MESSAGE_INTERVAL = 510, 511
MAV_CMD_REQUEST_MESSAGE = 512
MAV_CMD_REQUEST_PROTOCOL_VERSION, MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES = 519, 520
MESSAGE_INTERVAL_ID = 244
BROADCAST_OK = (MAV_CMD_REQUEST_PROTOCOL_VERSION, MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES)
INT32_MAX = 2**31 - 1
#: the float32 neighbours of INT32_MAX: a COMMAND_LONG param5, param6 in here is an
#: integer sent as a float (PX4 L472-482)
INT32_MAX_AS_FLOAT = (2.0**31 - 128.0, 2.0**31 + 256.0)
NAN_AS_INT = 0x7FF80000  # COMMAND_INT x, y: a NaN sent as an integer
#: PX4's main modes and AUTO sub modes (px4_custom_mode.h L45-76), for the refusals
MAIN_MODES = {1: "Manual", 2: "Altitude", 3: "Position", 4: "Auto", 5: "Acro",
              6: "Offboard", 7: "Stabilized", 8: "Rattitude", 9: "Simple",
              10: "Termination", 11: "Altitude Cruise"}  # fmt: skip
AUTO_MODES = {1: "Ready", 2: "Takeoff", 3: "Hold", 4: "Mission", 5: "Return", 6: "Land",
              7: "Return to ground station", 8: "Follow Me", 9: "Precision Land"}  # fmt: skip
NAV_MODES = {MAV_CMD_NAV_RETURN_TO_LAUNCH: "Return", MAV_CMD_NAV_LAND: "Land",
             MAV_CMD_NAV_TAKEOFF: "Takeoff"}  # fmt: skip
SEVERITY_CRITICAL, SEVERITY_WARNING, SEVERITY_INFO = 2, 4, 6


@dataclass(frozen=True)
class Request:
    """A command as PX4's ``vehicle_command``: 7 params (NaN where unset)."""

    command: int
    params: tuple[float, ...]  # 7
    sender: tuple[int, int]  # system, component
    target: tuple[int, int]
    malformed: bool = False


def from_long(msg: Any) -> Request:
    """A ``COMMAND_LONG`` as a ``Request``."""
    p = tuple(float(getattr(msg, f"param{i}")) for i in range(1, 8))
    low, high = INT32_MAX_AS_FLOAT
    malformed = low <= p[4] <= high and low <= p[5] <= high
    return Request(int(msg.command), p, _sender(msg), _target(msg), malformed)


def from_int(msg: Any) -> Request:
    """A ``COMMAND_INT`` as a ``Request``: x, y [degE7] as param5, param6 [deg], z param7."""
    x, y = int(msg.x), int(msg.y)
    p5, p6 = (math.nan, math.nan) if x == y == INT32_MAX else (x / 1e7, y / 1e7)
    p = (float(msg.param1), float(msg.param2), float(msg.param3), float(msg.param4), p5, p6,
         float(msg.z))  # fmt: skip
    return Request(int(msg.command), p, _sender(msg), _target(msg), x == y == NAN_AS_INT)


def _sender(msg: Any) -> tuple[int, int]:
    return int(msg.get_srcSystem()), int(msg.get_srcComponent())


def _target(msg: Any) -> tuple[int, int]:
    return int(msg.target_system), int(msg.target_component)


def _int(value: float) -> int | None:
    """``value`` as an int if it is a finite whole-ish number (PX4 rounds), else None."""
    return round(value) if math.isfinite(value) and abs(value) < 2**31 else None


class Autopilot(Protocol):
    """What the commands act on (``SitlAutopilot``)."""

    system_id: int
    t: float  # [s] SITL time
    vehicle: Vehicle
    sim: Any  # the physics (its true state)
    sc: Any  # the scenario (its robot's joints)
    telemetry: Telemetry
    conn: Any  # the pymavlink connection

    def say(self, text: str, severity: int) -> None: ...

    def send_now(self, name: str) -> None: ...


class Commands:
    """The command handling of ``sitl`` (module docstring)."""

    def __init__(self, sitl: Autopilot) -> None:
        self.sitl = sitl
        self._table = {
            MAV_CMD_COMPONENT_ARM_DISARM: self._arm,
            MAV_CMD_DO_SET_MODE: lambda r: self.set_mode(r.params[0], r.params[1], r.params[2]),
            MAV_CMD_DO_SET_ACTUATOR: self._actuators,
            MAV_CMD_REQUEST_MESSAGE: lambda r: self._request(r.params[0], r.params[1]),
            MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: lambda r: self._request(148, math.nan),
            MAV_CMD_GET_HOME_POSITION: lambda r: self._request(242, math.nan),
            MAV_CMD_SET_MESSAGE_INTERVAL: self._set_interval,
        }

    def handle(self, req: Request) -> int | None:
        """Answer ``req`` (an ACK to its sender); the result, None if it is not for us."""
        own = self.sitl.system_id
        broadcast_ok = req.command in BROADCAST_OK and req.target[0] == 0
        if not (req.target[0] == own or broadcast_ok) or req.target[1] not in (0, 1):
            return None
        if req.command == MAV_CMD_GET_MESSAGE_INTERVAL and not req.malformed:
            name = self.sitl.telemetry.name(req.params[0])
            msgid = _int(req.params[0])
            self.sitl.conn.mav.message_interval_send(
                (msgid or 0) & 0xFFFF, self.sitl.telemetry.interval_us(name)
            )
            return None
        if req.malformed:
            result = DENIED
        elif req.command in NAV_MODES:
            result = self._not_available(NAV_MODES[req.command])
        else:
            result = self._table.get(req.command, lambda r: UNSUPPORTED)(req)
        self.sitl.conn.mav.command_ack_send(req.command & 0xFFFF, result, 0, 0, *req.sender)
        return result

    def _arm(self, req: Request) -> int:
        sitl, v = self.sitl, self.sitl.vehicle
        wanted = _int(req.params[0])
        if wanted not in (0, 1):
            sitl.say(f"Unsupported ARM_DISARM param: {req.params[0]:.3f}", SEVERITY_CRITICAL)
            return UNSUPPORTED
        if wanted == 0 and v.armed:
            sitl.say("Disarming denied: not landed", SEVERITY_CRITICAL)
            return TEMPORARILY_REJECTED
        return v.arm(sitl.t, wanted == 1, sitl.sim.true_state())

    def set_mode(self, base_mode: float, main: float, sub: float) -> int:
        """``DO_SET_MODE`` (base mode, PX4 main and sub mode): the ``MAV_RESULT``."""
        base, main_mode, sub_mode = _int(base_mode), _int(main), _int(sub) or 0
        if base is None or not base & MAV_MODE_FLAG_CUSTOM_MODE_ENABLED or main_mode is None:
            return self._unsupported_mode()
        if main_mode == 4 and sub_mode == 0:
            sub_mode = 4  # AUTO without a sub mode is Mission (Commander.cpp L907-910)
        for name, (m, s) in MODES.items():
            if main_mode == m and (s == 0 or sub_mode == s):
                return self.sitl.vehicle.set_mode(self.sitl.t, name, self.sitl.sim.true_state())
        if main_mode == 4 and sub_mode in AUTO_MODES:
            return self._not_available(AUTO_MODES[sub_mode])
        if main_mode in MAIN_MODES and main_mode != 4:
            return self._not_available(MAIN_MODES[main_mode])
        return self._unsupported_mode()

    def _unsupported_mode(self) -> int:
        self.sitl.say("Unsupported mode", SEVERITY_CRITICAL)
        return TEMPORARILY_REJECTED

    def _not_available(self, mode: str) -> int:
        self.sitl.say(f"Switching to {mode} is currently not available", SEVERITY_CRITICAL)
        return TEMPORARILY_REJECTED

    def _actuators(self, req: Request) -> int:
        """Joint targets from a ``DO_SET_ACTUATOR`` (``arm.py``); NaN keeps a joint's."""
        sitl = self.sitl
        group = _int(req.params[6])
        if group is None or group < 0:
            return DENIED
        q = sitl.vehicle.q_target.copy()
        joints = sitl.sc.robot.joints
        for j, value in enumerate(req.params[:6]):
            i = 6 * group + j
            if i < len(q) and math.isfinite(value):  # an output is within [-1, 1]
                value = min(max(value, -1.0), 1.0)
                q[i] = actuator_to_joint(value, joints[i].lower, joints[i].upper)
        sitl.vehicle.on_joints(sitl.t, q)
        return ACCEPTED

    def _request(self, msgid: float, param2: float) -> int:
        """``REQUEST_MESSAGE``: send it, ACCEPTED; DENIED if the SITL cannot."""
        telemetry = self.sitl.telemetry
        if _int(msgid) == MESSAGE_INTERVAL_ID:
            asked = _int(param2)
            if asked is None:
                return DENIED
            name = telemetry.name(float(asked))
            self.sitl.conn.mav.message_interval_send(asked & 0xFFFF, telemetry.interval_us(name))
            return ACCEPTED
        name = telemetry.name(msgid)
        if name is None:
            return DENIED
        self.sitl.send_now(name)
        return ACCEPTED

    def _set_interval(self, req: Request) -> int:
        p = req.params
        if any(math.isfinite(v) and v != 0.0 for v in (p[2], p[3], p[6])):
            return FAILED
        name = self.sitl.telemetry.name(p[0])
        if name is None or not self.sitl.telemetry.set_interval(name, p[1]):
            return FAILED
        return ACCEPTED
