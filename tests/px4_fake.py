"""A PX4 stand-in on 127.0.0.1 for the bridge's tests (pymavlink, one thread, no physics).

It behaves as PX4 does towards an offboard computer, as far as these tests need
(PX4-Autopilot at commit 161b530): a HEARTBEAT at a fixed 1 Hz from system 1, component
1 (``mavlink_main.cpp`` L2310-2311; custom_mode ``main << 16 | sub << 24``,
``px4_custom_mode.h``); ``LOCAL_POSITION_NED``, ``ATTITUDE`` and the arm's
``NAMED_VALUE_FLOAT`` q1..qn at ``STATE_HZ``, stamped with its boot time [ms]; COMMAND_ACKs
addressed to the sender (``mavlink_receiver.cpp`` L121-133), ``DO_SET_ACTUATOR`` acked too
(``Commander.cpp`` L1528-1530). It stands still where it is
put. It records every message it receives with its raw bytes and arrival time, and lets a
test change what it sends (``mutate``) or do something (``at``) some time after offboard.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil

mavutil.set_dialect("common")
M = mavutil.mavlink

HOST = "127.0.0.1"
STATE_HZ = 50.0
HEARTBEAT_S = 1.0
OFFBOARD, AUTO, LOITER = 6, 4, 3  # px4_custom_mode.h L45-55, L58-76


@dataclass
class Received:
    """A message the fake received: arrival [s, monotonic], the message, its raw bytes."""

    t: float
    msg: Any
    raw: bytes


@dataclass
class FakePx4:
    """The fake autopilot (module docstring), sending to ``udpin`` peer ``port``.

    Attributes:
        ned: position [m] (north, east, down); yaw_ned [rad] from north, clockwise.
        joints: the arm's joint positions [rad].
        acks: command id -> MAV_RESULT it answers (default ACCEPTED), or ``None``: no answer.
        mutate: (kind, fields, seconds since offboard or None) -> fields to send, or None
            to send nothing.
        at: (seconds after offboard, action(fake)) done once each.
    """

    port: int
    ned: tuple[float, float, float] = (0.0, 0.0, -1.0)
    yaw_ned: float = 0.0
    joints: tuple[float, ...] = ()
    acks: dict[int, int | None] = field(default_factory=dict)
    mutate: Callable[[str, dict, float | None], dict | None] | None = None
    at: list[tuple[float, Callable[[FakePx4], None]]] = field(default_factory=list)
    sysid: int = 1
    compid: int = 1
    modes_taken: bool = True  # False: a mode switch is acked ACCEPTED but not made
    reject_text: str = ""  # a STATUSTEXT (critical) sent before an ack that is not ACCEPTED
    ack_to: tuple[int, int] | None = None  # address the acks here instead of the sender

    def __post_init__(self) -> None:
        self.conn = mavutil.mavlink_connection(
            f"udpout:{HOST}:{self.port}", source_system=self.sysid, source_component=self.compid
        )
        self.received: list[Received] = []
        self.main, self.sub, self.armed = AUTO, LOITER, False
        self.offboard_at: float | None = None  # when it entered offboard [s, monotonic]
        self.boot = time.monotonic()
        self._stop = threading.Event()
        self._done: set[int] = set()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> FakePx4:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.conn.close()

    def of_type(self, kind: str) -> list[Received]:
        """The received messages of ``kind``."""
        return [r for r in self.received if r.msg.get_type() == kind]

    def _run(self) -> None:
        next_state, next_beat = 0.0, 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            while (msg := self.conn.recv_msg()) is not None:
                self.received.append(Received(time.monotonic(), msg, bytes(msg.get_msgbuf())))
                if msg.get_type() == "COMMAND_LONG":
                    self._on_command(msg)
            since = None if self.offboard_at is None else now - self.offboard_at
            for i, (delay, action) in enumerate(self.at):
                if since is not None and since >= delay and i not in self._done:
                    self._done.add(i)
                    action(self)
            if now >= next_beat:
                self.heartbeat()
                next_beat = now + HEARTBEAT_S
            if now >= next_state:
                self._send_state(now, since)
                next_state = now + 1.0 / STATE_HZ
            time.sleep(0.002)

    def heartbeat(self) -> None:
        """One HEARTBEAT as PX4's (HEARTBEAT.hpp): custom-mode flag, armed flag."""
        base = 1 | (128 if self.armed else 0)
        custom = (self.main << 16) | (self.sub << 24)
        self.conn.mav.heartbeat_send(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, base, custom, 4)

    def _send_state(self, now: float, since: float | None) -> None:
        ms = int(1e3 * (now - self.boot))
        n, e, d = self.ned
        fields = {
            "LOCAL_POSITION_NED": dict(time_boot_ms=ms, x=n, y=e, z=d, vx=0.0, vy=0.0, vz=0.0),
            "ATTITUDE": dict(
                time_boot_ms=ms, roll=0.0, pitch=0.0, yaw=self.yaw_ned,
                rollspeed=0.0, pitchspeed=0.0, yawspeed=0.0,
            ),
        }  # fmt: skip
        for kind, f in fields.items():
            if self.mutate is not None and (f := self.mutate(kind, f, since)) is None:
                continue
            send = getattr(self.conn.mav, kind.lower() + "_send")
            send(**f)
        for i, q in enumerate(self.joints):
            self.conn.mav.named_value_float_send(ms, f"q{i + 1}".encode(), q)

    def say(self, text: str) -> None:
        """A critical STATUSTEXT, in chunks of 50 characters with one id as PX4 sends a
        longer one (streams/STATUSTEXT.hpp L88-118)."""
        chunks = [text[i : i + 50] for i in range(0, len(text), 50)]
        for seq, chunk in enumerate(chunks):
            chunk_id = 1 if len(chunks) > 1 else 0
            self.conn.mav.statustext_send(M.MAV_SEVERITY_CRITICAL, chunk.encode(), chunk_id, seq)

    def _on_command(self, msg: Any) -> None:
        cmd = int(msg.command)
        result = self.acks.get(cmd, M.MAV_RESULT_ACCEPTED)
        if result is None:
            return
        if result != M.MAV_RESULT_ACCEPTED and self.reject_text:
            self.say(self.reject_text)
        if result == M.MAV_RESULT_ACCEPTED:
            if cmd == 400:
                self.armed = round(msg.param1) == 1
            elif cmd == 176 and int(msg.param1) & 1 and self.modes_taken:
                self.main, self.sub = int(msg.param2), int(msg.param3)
                if self.main == OFFBOARD and self.offboard_at is None:
                    self.offboard_at = time.monotonic()
        to = self.ack_to or (msg.get_srcSystem(), msg.get_srcComponent())
        self.conn.mav.command_ack_send(cmd, result, 0, 0, *to)


def nan_after(kind: str, name: str, value: float, delay: float):
    """A ``mutate`` that sets ``kind``'s ``name`` to ``value`` from ``delay`` [s] after
    offboard on."""

    def mutate(k: str, f: dict, since: float | None) -> dict | None:
        if k == kind and since is not None and since >= delay:
            f = dict(f, **{name: value})
        return f

    return mutate


def silent_after(kind: str, delay: float):
    """A ``mutate`` that stops sending ``kind`` ``delay`` [s] after offboard."""

    def mutate(k: str, f: dict, since: float | None) -> dict | None:
        return None if k == kind and since is not None and since >= delay else f

    return mutate


INF = math.inf
