"""The setpoint stream: a thread that, ``rate_hz`` times a second, sends the follower's
setpoint for the latest state (velocity + yaw rate to the autopilot, joint targets to
the arm), and watches the vehicle.

It stops commanding motion (sends nothing more) at the first of, each noticed within a
period (the thread wakes at the loss deadline too, so within a few ms of it):

- ``telemetry fault``: the transport's ``fault()`` (a value not finite or out of range);
- ``link lost``: no telemetry for ``loss_s`` [s] and nothing else from the vehicle since;
- ``telemetry stale``: no telemetry for ``loss_s`` while other messages still come;
- once ``flying`` is set (the vehicle in offboard): ``disarmed`` (its heartbeat says so)
  or ``left offboard`` (a pilot or the autopilot's failsafe switched modes).

Then ``lost`` is set and ``stop_reason`` says which and why (one line); the runtime
decides what else to command (``loop``).
"""

from __future__ import annotations

import itertools
import threading
import time
from dataclasses import dataclass

from aeromanip.runtime.follower import PlanFollower
from aeromanip.runtime.measure import MissionClock, StateReader
from aeromanip.runtime.transport import ArmInterface, Setpoint, Transport

STREAM_HZ = 50.0  # [Hz] setpoints per second (PX4 leaves offboard below 2 Hz)
LINK_LOSS_S = 0.5  # [s] no vehicle state for this long: the link is lost
LINK_MARGIN_S = 0.1  # [s] the link is up if a message came this long after the last state


@dataclass(frozen=True)
class StopReason:
    """Why the stream stopped: ``kind`` (module docstring) and one line ``text``."""

    kind: str
    text: str


class Streamer:
    """Streams setpoints on its own thread (``start``/``stop``).

    Attributes:
        lost: set when the stream stopped by itself (``stop_reason`` says why);
            lost_age: the state's age then [s]; lost_wall: ``time.time()`` then.
        flying: set by the runtime while the vehicle must be armed and in offboard.
        sent: monotonic times [s] of every setpoint sent.
    """

    def __init__(
        self,
        transport: Transport,
        arm: ArmInterface,
        follower: PlanFollower,
        reader: StateReader,
        clock: MissionClock,
        rate_hz: float = STREAM_HZ,
        loss_s: float = LINK_LOSS_S,
    ) -> None:
        self.transport, self.arm, self.follower = transport, arm, follower
        self.reader, self.clock = reader, clock
        self.period, self.loss_s = 1.0 / rate_hz, loss_s
        self.lost = threading.Event()
        self.lost_age = float("nan")
        self.lost_wall = float("nan")
        self.stop_reason: StopReason | None = None
        self.flying = threading.Event()
        self.sent: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="setpoints", daemon=True)

    def start(self) -> None:
        """Start streaming."""
        self._thread.start()

    def stop(self) -> None:
        """Stop streaming (the last setpoint was sent; idempotent)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)

    def _run(self) -> None:
        next_send = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if (why := self._problem(now)) is not None:
                self._halt(why, now)
                return
            m = self.reader.read()
            if now >= next_send and m is not None:
                t = self.clock.now()
                sp = self.follower.setpoint(t, m.predicted(now))
                if sp is not None:
                    velocity, yaw_rate, joints = sp
                    self.transport.send(Setpoint(velocity, yaw_rate, t))
                    self.arm.send(joints)
                    self.sent.append(now)
                next_send = max(next_send + self.period, now)
            age, _ = self.transport.telemetry_age(now)
            self._stop.wait(max(0.0, min(next_send, now + self.loss_s - age) - time.monotonic()))

    def _problem(self, now: float) -> StopReason | None:
        """Why the stream must stop now (module docstring), or ``None``."""
        tr = self.transport
        if (fault := tr.fault()) is not None:
            return StopReason("telemetry fault", f"telemetry fault: {fault}")
        age, what = tr.telemetry_age(now)
        if age >= self.loss_s:
            if tr.link_silence(now) < age - LINK_MARGIN_S:
                text = f"telemetry stale: no {what} for {age:.2f} s (the link is up)"
                return StopReason("telemetry stale", text)
            return StopReason("link lost", f"link lost: no vehicle state for {age:.2f} s")
        if self.flying.is_set():
            if not tr.is_armed():
                text = "the vehicle disarmed in flight (a kill switch or its failsafe)"
                return StopReason("disarmed", f"{text}: not commanding")
            if (mode := tr.mode()) != "offboard":
                text = f"the autopilot left offboard (now {mode}): not commanding"
                return StopReason("left offboard", text)
        return None

    def _halt(self, why: StopReason, now: float) -> None:
        self.lost_age, self.lost_wall = self.transport.telemetry_age(now)[0], time.time()
        self.stop_reason = why
        self.lost.set()

    def rate_between(self, t0: float, t1: float) -> tuple[int, float]:
        """Setpoints sent in ``[t0, t1)`` [s, monotonic] and the longest gap between
        consecutive ones there [s]."""
        times = [s for s in self.sent if t0 <= s < t1]
        gaps = [b - a for a, b in itertools.pairwise(times)]
        return len(times), max(gaps, default=float("nan"))
