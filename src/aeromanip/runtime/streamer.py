"""The setpoint stream: a thread that, ``rate_hz`` times a second, sends the follower's
setpoint for the latest state (velocity + yaw rate to the autopilot, joint targets to
the arm), and watches the link.

Link loss: no vehicle state for ``loss_s`` [s] (the thread wakes at that deadline, so it
notices within a few ms). It then stops commanding motion (sends nothing more: the
autopilot's own offboard failsafe takes over), says so on stderr and sets ``lost``.
"""

from __future__ import annotations

import itertools
import sys
import threading
import time

from aeromanip.runtime.follower import PlanFollower
from aeromanip.runtime.measure import MissionClock, StateReader
from aeromanip.runtime.transport import ArmInterface, Setpoint, Transport

STREAM_HZ = 50.0  # [Hz] setpoints per second (PX4 leaves offboard below 2 Hz)
LINK_LOSS_S = 0.5  # [s] no vehicle state for this long: the link is lost


class Streamer:
    """Streams setpoints on its own thread (``start``/``stop``).

    Attributes:
        lost: set when the link is lost; lost_age: the state's age then [s];
            lost_wall: ``time.time()`` then.
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
            m, st = self.reader.read(), self.transport.state()
            stamp = st.stamp if st is not None else now
            if now - stamp >= self.loss_s:
                self._lose(now - stamp)
                return
            if now >= next_send and m is not None:
                t = self.clock.now()
                sp = self.follower.setpoint(t, m.predicted(now))
                if sp is not None:
                    velocity, yaw_rate, joints = sp
                    self.transport.send(Setpoint(velocity, yaw_rate, t))
                    self.arm.send(joints)
                    self.sent.append(now)
                next_send = max(next_send + self.period, now)
            self._stop.wait(max(0.0, min(next_send, stamp + self.loss_s) - time.monotonic()))

    def _lose(self, age: float) -> None:
        self.lost_age, self.lost_wall = age, time.time()
        self.lost.set()
        print(
            f"aeromanip: link lost: no vehicle state for {age:.2f} s; "
            "no more setpoints (the autopilot's failsafe takes over)",
            file=sys.stderr,
            flush=True,
        )

    def rate_between(self, t0: float, t1: float) -> tuple[int, float]:
        """Setpoints sent in ``[t0, t1)`` [s, monotonic] and the longest gap between
        consecutive ones there [s]."""
        times = [s for s in self.sent if t0 <= s < t1]
        gaps = [b - a for a, b in itertools.pairwise(times)]
        return len(times), max(gaps, default=float("nan"))
