"""The NMPC state from what the link reports, and the mission clock.

``StateReader.read`` assembles ``x = [active platform DoFs, q]`` from the transport's
latest ``VehicleState`` and the arm's joints (yaw unwrapped continuously, as the NMPC's
yaw is), with the measured rates: the platform's velocity and yaw rate (joint rates are
not measured: 0); and, for the contact tasks, the platform's roll and pitch and the arm
interface's wrist wrench, if it has a sensor. ``Measurement.predicted(now)`` moves it
forward by its age along those rates: the state at the time it is used, not when it was
measured.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numpy as np

from aeromanip.robot.spec import RobotSpec
from aeromanip.runtime.transport import ArmInterface, Transport


@dataclass(frozen=True)
class Measurement:
    """An NMPC state ``x``, its rates ``dx/dt`` and when it was measured [s, monotonic];
    the platform's ``(roll, pitch)`` [rad] and the wrist sensor's ``[f, tau]`` [N, N m,
    world] with it (``None``: not measured), for the tasks that use them."""

    x: np.ndarray
    rates: np.ndarray
    stamp: float
    attitude: tuple[float, float] | None = None
    wrench: np.ndarray | None = None

    def age(self, now: float) -> float:
        """How old it is at ``now`` [s]."""
        return now - self.stamp

    def predicted(self, now: float) -> np.ndarray:
        """The state at ``now`` [s, monotonic], moved on by its age along its rates."""
        return self.x + self.rates * max(0.0, self.age(now))


class StateReader:
    """NMPC states from a transport and an arm interface (thread-safe)."""

    def __init__(self, spec: RobotSpec, transport: Transport, arm: ArmInterface) -> None:
        self.spec, self.transport, self.arm = spec, transport, arm
        self.dofs = spec.platform.dofs
        self._yaw: float | None = None
        self._lock = threading.Lock()

    def _unwrap(self, yaw: float) -> float:
        with self._lock:
            if self._yaw is None:
                self._yaw = yaw
            else:
                self._yaw += math.remainder(yaw - self._yaw, 2.0 * math.pi)
            return self._yaw

    def read(self) -> Measurement | None:
        """The latest state, or ``None`` until both the vehicle and the arm reported."""
        st, joints = self.transport.state(), self.arm.joints()
        if st is None or joints is None:
            return None
        pose = dict(zip("xyz", st.position, strict=True))
        rate = dict(zip("xyz", st.velocity, strict=True))
        pose["yaw"], rate["yaw"] = self._unwrap(st.yaw), st.yaw_rate
        q, _ = joints
        x = np.array([pose[d] for d in self.dofs] + list(q))
        r = np.array([rate[d] for d in self.dofs] + [0.0] * len(q))
        wrench = self.arm.wrench()
        return Measurement(
            x, r, st.stamp, (st.roll, st.pitch), None if wrench is None else np.array(wrench)
        )


class MissionClock:
    """Mission time [s]: 0 until ``start()``, then the monotonic time since."""

    def __init__(self) -> None:
        self.t0: float | None = None

    def start(self) -> None:
        """The mission starts now."""
        self.t0 = time.monotonic()

    def now(self) -> float:
        """Mission time now [s] (0 before the start)."""
        return 0.0 if self.t0 is None else time.monotonic() - self.t0

    def at(self, mission_t: float) -> float:
        """The monotonic time [s] of mission time ``mission_t`` (from now if not started)."""
        return (time.monotonic() if self.t0 is None else self.t0) + mission_t
