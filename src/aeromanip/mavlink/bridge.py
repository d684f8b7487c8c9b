"""The MAVLink 2 offboard bridge (pymavlink): a ``Transport`` to a PX4 autopilot.

PX4's offboard protocol (``docs/mavlink/bridge-vs-px4.md`` cites PX4's source for each):
wait for the autopilot's heartbeat and take its system id as ours (``connect``); ask for
``LOCAL_POSITION_NED`` and ``ATTITUDE`` at ``TELEMETRY_HZ`` (``SET_MESSAGE_INTERVAL``);
stream setpoints before asking for offboard (the runtime does, for ``PRE_STREAM_S``); arm
and switch modes with ``COMMAND_LONG``, each checked by its ``COMMAND_ACK`` and then by
the autopilot's heartbeat (``arm``, ``set_mode``); velocity + yaw-rate setpoints in
``SET_POSITION_TARGET_LOCAL_NED`` (``protocol.VELOCITY_YAW_RATE``). Frames are converted
in ``frames`` only. Telemetry is checked (``telemetry``): a bad value is a ``fault()``,
a reordered one is dropped. Only the autopilot's own messages count (its system and
component for heartbeats, acks and state). A background thread receives (and sends our
own heartbeat at 1 Hz); sends are serialised by a lock, so any thread may send.
"""

from __future__ import annotations

import itertools
import math
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
from aeromanip.mavlink.telemetry import TelemetryClock, check_attitude, check_position
from aeromanip.runtime.transport import LinkError, Setpoint, Transport, VehicleState

MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_SET_MESSAGE_INTERVAL = 511
TELEMETRY_IDS = {"LOCAL_POSITION_NED": 32, "ATTITUDE": 30}  # MAVLink message ids
TELEMETRY_HZ = 50.0  # [Hz] the rate asked for each state message
RATE_REQUEST_S = 1.0  # [s] wait for the answer to a rate request (then fly on without)
CONFIRM_S = 2.5  # [s] a mode or arming change must show in a heartbeat (PX4: 1 Hz)
DRAIN_MAX = 100_000  # messages dropped at most before connecting
TEXTS_KEPT = 8  # STATUSTEXTs kept to say why a command was refused
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
        self._stamps = {"LOCAL_POSITION_NED": math.nan, "ATTITUDE": math.nan}
        self._last_rx = math.nan
        self._fault: str | None = None
        self._clock = TelemetryClock()
        self._acks: dict[int, int] = {}
        self._texts: list[tuple[float, str]] = []  # (arrival, text) of warnings and worse
        self._text_id = 0  # the chunk id of the last text
        self._mode, self._armed = "other", False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.target = (1, 1)  # autopilot system, component (from its heartbeat)
        self.rate_answers: dict[str, str] = {}  # SET_MESSAGE_INTERVAL: message -> result

    def add_handler(self, msg_type: str, fn: Callable[[Any], None]) -> None:
        """Call ``fn(msg)`` (on the receive thread) for every ``msg_type`` message."""
        self._handlers.setdefault(msg_type, []).append(fn)

    def connect(self, timeout_s: float) -> None:
        """Wait for an autopilot's heartbeat, receive in the background, ask for the
        telemetry rates."""
        end = time.monotonic() + timeout_s
        ap_invalid = self.m.MAV_AUTOPILOT_INVALID
        self._drain()
        while (left := end - time.monotonic()) > 0:
            self._heartbeat()  # lets a udpout/tcp peer learn our address
            msg = self.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=min(left, 0.5))
            if msg is not None and msg.autopilot != ap_invalid:
                self.target = (msg.get_srcSystem(), msg.get_srcComponent())
                self.conn.mav.srcSystem = self.target[0]  # PX4 counts same-system heartbeats
                self._on_heartbeat(msg)
                self._thread = threading.Thread(target=self._receive, daemon=True)
                self._thread.start()
                self._request_rates()
                return
        raise LinkError(f"no autopilot heartbeat on {self.url} within {timeout_s:g} s")

    def _drain(self) -> None:
        """Drop what queued up since the link opened (old state, old heartbeats)."""
        for _ in range(DRAIN_MAX):
            try:
                if self.conn.recv_msg() is None:
                    return
            except (OSError, ValueError):
                return

    def _request_rates(self) -> None:
        """``SET_MESSAGE_INTERVAL`` for the state messages (a PX4 link in its normal mode
        sends ``LOCAL_POSITION_NED`` at 1 Hz only); the answers go to ``rate_answers``."""
        interval_us = 1e6 / TELEMETRY_HZ
        for name, msg_id in TELEMETRY_IDS.items():
            params = [float(msg_id), interval_us, 0.0, 0.0, 0.0, 0.0, 0.0]
            try:
                result = self.command(MAV_CMD_SET_MESSAGE_INTERVAL, params, RATE_REQUEST_S)
                self.rate_answers[name] = self._result_name(result)
            except LinkError:
                self.rate_answers[name] = "no answer"

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
            if msg is not None and msg.get_srcSystem() == self.target[0]:
                self._last_rx = time.monotonic()
                self._dispatch(msg)
            if time.monotonic() >= next_beat:
                self._heartbeat()
                next_beat = time.monotonic() + HEARTBEAT_S

    def _dispatch(self, msg: Any) -> None:
        """A message of the autopilot's system: the autopilot's own state, heartbeat,
        acks and texts; every kind to its handlers (e.g. the arm's joints)."""
        kind = msg.get_type()
        own = msg.get_srcComponent() == self.target[1]
        if own and kind in ("LOCAL_POSITION_NED", "ATTITUDE"):
            self._on_telemetry(kind, msg)
        elif own and kind == "HEARTBEAT":
            with self._cond:
                self._on_heartbeat(msg)
                self._cond.notify_all()
        elif own and kind == "COMMAND_ACK" and self._for_us(msg):
            with self._cond:
                self._acks[int(msg.command)] = int(msg.result)
                self._cond.notify_all()
        elif kind == "STATUSTEXT" and msg.severity <= self.m.MAV_SEVERITY_WARNING:
            self._on_text(msg)
        for fn in self._handlers.get(kind, ()):
            fn(msg)

    def _on_text(self, msg: Any) -> None:
        """Keep a warning's text; PX4 sends a text over 50 characters in chunks with one
        ``id`` (``streams/STATUSTEXT.hpp`` L88-118): they are joined."""
        text, chunk_id = str(msg.text).rstrip("\x00"), int(getattr(msg, "id", 0))
        with self._cond:
            if chunk_id and chunk_id == self._text_id and self._texts:
                when, head = self._texts[-1]
                self._texts[-1] = (when, head + text)
            else:
                self._texts = [*self._texts[-(TEXTS_KEPT - 1) :], (time.monotonic(), text)]
            self._text_id = chunk_id

    def _for_us(self, msg: Any) -> bool:
        """Whether an ack is addressed to us (PX4 addresses it to the command's sender;
        0 is anyone)."""
        ours = (self.conn.mav.srcSystem, self.conn.mav.srcComponent)
        to = (getattr(msg, "target_system", 0), getattr(msg, "target_component", 0))
        return all(t in (0, o) for t, o in zip(to, ours, strict=True))

    def _on_telemetry(self, kind: str, msg: Any) -> None:
        now = time.monotonic()
        if not self._clock.check(kind, int(msg.time_boot_ms), now):
            return
        verdict = check_position(msg) if kind == "LOCAL_POSITION_NED" else check_attitude(msg)
        if verdict is not None:
            self._set_fault(verdict)
            return
        self._stamps[kind] = now
        if kind == "ATTITUDE":
            roll, pitch, yaw = frames.attitude_ned_to_enu(msg.roll, msg.pitch, msg.yaw)
            rate = frames.euler_yaw_rate(msg.roll, msg.pitch, msg.pitchspeed, msg.yawspeed)
            self._att = (roll, pitch, yaw, frames.yaw_rate_ned_to_enu(rate))
        else:
            self._on_position(msg, now)

    def _set_fault(self, text: str) -> None:
        with self._cond:
            if self._fault is None:
                self._fault = text

    def _on_position(self, msg: Any, now: float) -> None:
        if self._att is None:
            return
        roll, pitch, yaw, yaw_rate = self._att
        state = VehicleState(
            stamp=now,
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
        self._armed = bool(msg.base_mode & MAV_MODE_FLAG_SAFETY_ARMED)

    def _heartbeat(self) -> None:
        with self._send_lock:
            self.conn.mav.heartbeat_send(
                self.m.MAV_TYPE_ONBOARD_CONTROLLER, self.m.MAV_AUTOPILOT_INVALID, 0, 0, 0
            )

    def state(self) -> VehicleState | None:
        """The latest state (ENU/FLU), or ``None`` before the first."""
        with self._cond:
            return self._state

    def fault(self) -> str | None:
        """The first telemetry fault (``telemetry``), or ``None``."""
        with self._cond:
            return self._fault

    def telemetry_age(self, now: float) -> tuple[float, str]:
        """The age [s] of the older of the last good ``LOCAL_POSITION_NED`` and
        ``ATTITUDE`` at ``now``, and its name (with the last dropped stamp, if any)."""
        name = min(self._stamps, key=lambda k: self._stamps[k])
        age = now - self._stamps[name]
        if not math.isfinite(age):
            return 0.0, name
        why = f"; last dropped: {self._clock.last_drop}" if self._clock.last_drop else ""
        return age, name + why

    def link_silence(self, now: float) -> float:
        """How long [s] nothing came from the autopilot's system."""
        return now - self._last_rx if math.isfinite(self._last_rx) else 0.0

    def mode(self) -> str:
        """The autopilot's mode from its last heartbeat."""
        return self._mode

    def is_armed(self) -> bool:
        """Whether the autopilot's last heartbeat says armed."""
        return self._armed

    def send(self, setpoint: Setpoint) -> None:
        """One ``SET_POSITION_TARGET_LOCAL_NED``: NED velocity and yaw rate (a setpoint
        that is not finite is not sent: it is a fault)."""
        vx, vy, vz = frames.enu_to_ned(setpoint.velocity)
        rate = frames.yaw_rate_enu_to_ned(setpoint.yaw_rate)
        if not all(map(math.isfinite, (vx, vy, vz, rate))):
            self._set_fault(f"the controller's setpoint {(vx, vy, vz, rate)} is not finite")
            return
        ms = max(0, round(1e3 * setpoint.mission_t)) & 0xFFFFFFFF
        with self._send_lock:
            self.conn.mav.set_position_target_local_ned_send(
                ms, *self.target, MAV_FRAME_LOCAL_NED, VELOCITY_YAW_RATE,
                0.0, 0.0, 0.0, vx, vy, vz, 0.0, 0.0, 0.0, 0.0, rate,
            )  # fmt: skip

    def command_nowait(self, command: int, params: Sequence[float], confirmation: int = 0) -> None:
        """Send a ``COMMAND_LONG`` (7 params) without waiting for its answer."""
        with self._send_lock:
            self.conn.mav.command_long_send(*self.target, command, confirmation, *params)

    def command(self, command: int, params: Sequence[float], timeout_s: float) -> int:
        """Send a ``COMMAND_LONG`` (again every ``COMMAND_RETRY_S``, ``confirmation``
        counting up, not while the answer is ``IN_PROGRESS``) until its ``COMMAND_ACK``
        arrives; return its ``MAV_RESULT`` (``LinkError`` on timeout)."""
        end = time.monotonic() + timeout_s
        in_progress = self.m.MAV_RESULT_IN_PROGRESS
        with self._cond:
            self._acks.pop(command, None)
        for confirmation in itertools.count():
            if time.monotonic() >= end:
                break
            if self._acks.get(command) != in_progress:
                self.command_nowait(command, params, min(confirmation, 255))
            with self._cond:
                wait = min(COMMAND_RETRY_S, end - time.monotonic())
                done = self._cond.wait_for(
                    lambda: self._acks.get(command, in_progress) != in_progress, max(wait, 0.0)
                )
                if done:
                    return self._acks[command]
        raise LinkError(f"no COMMAND_ACK for command {command} within {timeout_s:g} s")

    def _result_name(self, result: int) -> str:
        names = self.m.enums["MAV_RESULT"]
        return names[result].name if result in names else str(result)

    def _check(self, what: str, result: int, since: float) -> None:
        if result != self.m.MAV_RESULT_ACCEPTED:
            with self._cond:
                said = [t for when, t in self._texts if when >= since]
            why = f" (it said: {said[-1].strip()})" if said else ""  # PX4's end in a tab
            raise LinkError(f"{what}: the autopilot answered {self._result_name(result)}{why}")

    def _confirm(self, what: str, seen: Callable[[], bool], timeout_s: float) -> None:
        """Wait until the autopilot's heartbeat shows ``seen()`` (PX4 may ack a mode
        switch before its commander decides, ``docs/mavlink/bridge-vs-px4.md``)."""
        with self._cond:
            if not self._cond.wait_for(seen, timeout_s):
                state = f"mode {self._mode}, {'armed' if self._armed else 'disarmed'}"
                raise LinkError(
                    f"{what}: accepted, but the autopilot's heartbeat still says {state} "
                    f"after {timeout_s:g} s"
                )

    def arm(self, timeout_s: float) -> None:
        """``MAV_CMD_COMPONENT_ARM_DISARM`` (arm): ACCEPTED, then armed in a heartbeat."""
        since = time.monotonic()
        params = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
        self._check("arm", self.command(MAV_CMD_COMPONENT_ARM_DISARM, params, timeout_s), since)
        self._confirm("arm", lambda: self._armed, CONFIRM_S)

    def set_mode(self, mode: str, timeout_s: float) -> None:
        """``MAV_CMD_DO_SET_MODE`` to a PX4 custom mode: ACCEPTED, then that mode in a
        heartbeat."""
        since = time.monotonic()
        main, sub = MODES[mode]
        params = [float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(main), float(sub), 0, 0, 0, 0]
        result = self.command(MAV_CMD_DO_SET_MODE, params, timeout_s)
        self._check(f"mode {mode}", result, since)
        self._confirm(f"mode {mode}", lambda: self._mode == mode, CONFIRM_S)

    def close(self) -> None:
        """Stop the receive thread and close the link."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)
        self.conn.close()
