"""The MAVLink 2 offboard bridge (pymavlink): a ``Transport`` to a PX4 autopilot.

PX4's offboard protocol: wait for the autopilot's heartbeat (``connect``); stream
setpoints before asking for offboard (the runtime does, for ``PRE_STREAM_S``); arm and
switch modes with ``COMMAND_LONG`` and check each ``COMMAND_ACK`` (``arm``,
``set_mode``); velocity + yaw-rate setpoints in ``SET_POSITION_TARGET_LOCAL_NED``
(``protocol.VELOCITY_YAW_RATE``); state from ``LOCAL_POSITION_NED`` + ``ATTITUDE``.
Frames are converted in ``frames`` only. A background thread receives (and sends our
own heartbeat at 1 Hz); sends are serialised by a lock, so any thread may send.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from aeromanip.mavlink import frames
from aeromanip.mavlink.protocol import (
    MAV_FRAME_LOCAL_NED,
    MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
    MAV_MODE_FLAG_SAFETY_ARMED,
    MODES,
    VELOCITY_YAW_RATE,
    load_mavutil,
    mode_name,
    open_link,
)
from aeromanip.runtime.transport import LinkError, Setpoint, Transport, VehicleState

MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_DO_SET_MODE = 176
MAV_COMP_ID_ONBOARD_COMPUTER = 191
SYSTEM_ID = 1  # ours; the autopilot's is read from its heartbeat
COMMAND_RETRY_S = 0.5  # [s] a COMMAND_LONG without an answer is sent again this often
HEARTBEAT_S = 1.0  # [s] our heartbeat period
RECV_TIMEOUT_S = 0.02  # [s] longest wait of the receive thread (how fast it notices close)


class MavlinkTransport(Transport):
    """A link to a PX4 (or the SITL autopilot) over ``url`` (``protocol.parse_link``)."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.conn = open_link(url, SYSTEM_ID, MAV_COMP_ID_ONBOARD_COMPUTER)
        self.mavutil = load_mavutil()
        self.m = self.mavutil.mavlink
        self._send_lock = threading.Lock()
        self._cond = threading.Condition()
        self._handlers: dict[str, list[Callable[[Any], None]]] = {}
        self._att: tuple[float, ...] | None = None
        self._state: VehicleState | None = None
        self._acks: dict[int, int] = {}
        self._mode, self.armed = "other", False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.target = (1, 1)  # autopilot system, component (from its heartbeat)

    def add_handler(self, msg_type: str, fn: Callable[[Any], None]) -> None:
        """Call ``fn(msg)`` (on the receive thread) for every ``msg_type`` message."""
        self._handlers.setdefault(msg_type, []).append(fn)

    def connect(self, timeout_s: float) -> None:
        """Wait for an autopilot's heartbeat, then receive in the background."""
        end = time.monotonic() + timeout_s
        ap_invalid = self.m.MAV_AUTOPILOT_INVALID
        while (left := end - time.monotonic()) > 0:
            self._heartbeat()  # lets a udpout/tcp peer learn our address
            msg = self.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=min(left, 0.5))
            if msg is not None and msg.autopilot != ap_invalid:
                self.target = (msg.get_srcSystem(), msg.get_srcComponent())
                self._on_heartbeat(msg)
                self._thread = threading.Thread(target=self._receive, daemon=True)
                self._thread.start()
                return
        raise LinkError(f"no autopilot heartbeat on {self.url} within {timeout_s:g} s")

    def _receive(self) -> None:
        next_beat = 0.0
        while not self._stop.is_set():
            try:
                msg = self.conn.recv_match(blocking=True, timeout=RECV_TIMEOUT_S)
            except (OSError, ValueError):  # the link closed under us
                if self._stop.is_set():
                    return
                time.sleep(RECV_TIMEOUT_S)
                msg = None
            if msg is not None:
                self._dispatch(msg)
            if time.monotonic() >= next_beat:
                self._heartbeat()
                next_beat = time.monotonic() + HEARTBEAT_S

    def _dispatch(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == "LOCAL_POSITION_NED":
            self._on_position(msg)
        elif kind == "ATTITUDE":
            roll, pitch, yaw = frames.attitude_ned_to_enu(msg.roll, msg.pitch, msg.yaw)
            rate = frames.euler_yaw_rate(msg.roll, msg.pitch, msg.pitchspeed, msg.yawspeed)
            self._att = (roll, pitch, yaw, frames.yaw_rate_ned_to_enu(rate))
        elif kind == "HEARTBEAT" and msg.get_srcSystem() == self.target[0]:
            self._on_heartbeat(msg)
        elif kind == "COMMAND_ACK":
            with self._cond:
                self._acks[int(msg.command)] = int(msg.result)
                self._cond.notify_all()
        for fn in self._handlers.get(kind, ()):
            fn(msg)

    def _on_position(self, msg: Any) -> None:
        if self._att is None:
            return
        roll, pitch, yaw, yaw_rate = self._att
        state = VehicleState(
            stamp=time.monotonic(),
            position=frames.ned_to_enu((msg.x, msg.y, msg.z)),
            velocity=frames.ned_to_enu((msg.vx, msg.vy, msg.vz)),
            roll=roll,
            pitch=pitch,
            yaw=yaw,
            yaw_rate=yaw_rate,
        )
        with self._cond:
            self._state = state

    def _on_heartbeat(self, msg: Any) -> None:
        if msg.base_mode & MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            self._mode = mode_name(int(msg.custom_mode))
        self.armed = bool(msg.base_mode & MAV_MODE_FLAG_SAFETY_ARMED)

    def _heartbeat(self) -> None:
        with self._send_lock:
            self.conn.mav.heartbeat_send(
                self.m.MAV_TYPE_ONBOARD_CONTROLLER, self.m.MAV_AUTOPILOT_INVALID, 0, 0, 0
            )

    def state(self) -> VehicleState | None:
        """The latest state (ENU/FLU), or ``None`` before the first."""
        with self._cond:
            return self._state

    def mode(self) -> str:
        """The autopilot's mode from its last heartbeat."""
        return self._mode

    def send(self, setpoint: Setpoint) -> None:
        """One ``SET_POSITION_TARGET_LOCAL_NED``: NED velocity and yaw rate."""
        vx, vy, vz = frames.enu_to_ned(setpoint.velocity)
        rate = frames.yaw_rate_enu_to_ned(setpoint.yaw_rate)
        ms = max(0, round(1e3 * setpoint.mission_t)) & 0xFFFFFFFF
        with self._send_lock:
            self.conn.mav.set_position_target_local_ned_send(
                ms, *self.target, MAV_FRAME_LOCAL_NED, VELOCITY_YAW_RATE,
                0.0, 0.0, 0.0, vx, vy, vz, 0.0, 0.0, 0.0, 0.0, rate,
            )  # fmt: skip

    def command_nowait(self, command: int, params: Sequence[float]) -> None:
        """Send a ``COMMAND_LONG`` (7 params) without waiting for its answer."""
        with self._send_lock:
            self.conn.mav.command_long_send(*self.target, command, 0, *params)

    def command(self, command: int, params: Sequence[float], timeout_s: float) -> int:
        """Send a ``COMMAND_LONG`` (again every ``COMMAND_RETRY_S``) until its
        ``COMMAND_ACK`` arrives; return its ``MAV_RESULT`` (``LinkError`` on timeout)."""
        end = time.monotonic() + timeout_s
        with self._cond:
            self._acks.pop(command, None)
        while time.monotonic() < end:
            self.command_nowait(command, params)
            with self._cond:
                wait = min(COMMAND_RETRY_S, end - time.monotonic())
                if self._cond.wait_for(lambda: command in self._acks, max(wait, 0.0)):
                    return self._acks[command]
        raise LinkError(f"no COMMAND_ACK for command {command} within {timeout_s:g} s")

    def _check(self, what: str, result: int) -> None:
        if result != self.m.MAV_RESULT_ACCEPTED:
            names = self.m.enums["MAV_RESULT"]
            name = names[result].name if result in names else str(result)
            raise LinkError(f"{what}: the autopilot answered {name}")

    def arm(self, timeout_s: float) -> None:
        """``MAV_CMD_COMPONENT_ARM_DISARM`` (arm); the ACK must be ACCEPTED."""
        params = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
        self._check("arm", self.command(MAV_CMD_COMPONENT_ARM_DISARM, params, timeout_s))

    def set_mode(self, mode: str, timeout_s: float) -> None:
        """``MAV_CMD_DO_SET_MODE`` to a PX4 custom mode; the ACK must be ACCEPTED."""
        main, sub = MODES[mode]
        params = [float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(main), float(sub), 0, 0, 0, 0]
        self._check(f"mode {mode}", self.command(MAV_CMD_DO_SET_MODE, params, timeout_s))
        self._mode = mode

    def close(self) -> None:
        """Stop the receive thread and close the link."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)
        self.conn.close()
