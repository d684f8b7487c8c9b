"""Setpoints between solves: follow the current plan, or hold.

The NMPC solves at its control rate (2 Hz in ``flight``) but an autopilot wants a
setpoint stream (PX4: > 2 Hz; ``STREAM_HZ`` here). At mission time ``t`` the follower
reads the plan's ramp, ``x_ref(t) = X[i] + U[i] (t - t_i)`` with ``i`` the plan step
``t`` falls in (the plan keeps going past its first step if no new plan comes, e.g. after
a deadline miss), and asks for::

    velocity = U[i] + GAIN (x_ref - x)        (platform x, y, z; yaw likewise)
    joints   = x_ref (the joint part)

i.e. PX4's own position loop (P on position, velocity feed-forward) closed on the
companion computer: the autopilot flies velocity setpoints. Holding: ``x_ref`` a fixed
point, no feed-forward, the joints held where they are. Velocities are clipped to the
robot's limits. Thread-safe: the solver thread installs plans, the streaming thread reads.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np

from aeromanip.robot.spec import PLATFORM_DOFS, RobotSpec

GAIN = 1.5  # [1/s] velocity per metre (rad) of error: the physics' pos_p (FlightGains)


@dataclass(frozen=True)
class Plan:
    """A plan that starts at mission time ``t0`` [s]: states ``X`` (N+1, nx) and
    commands ``U`` (N, nx) every ``dt`` [s]."""

    t0: float
    X: np.ndarray
    U: np.ndarray
    dt: float

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The plan's reference state and command at mission time ``t`` (clamped to the
        plan: before it, its start; after it, its end at rest)."""
        s = max(0.0, t - self.t0)
        i = int(s // self.dt)
        if i >= len(self.U):
            return self.X[-1].copy(), np.zeros_like(self.U[-1])
        return self.X[i] + self.U[i] * (s - i * self.dt), self.U[i].copy()


class PlanFollower:
    """Setpoints from the current plan or a hold point, for ``spec``'s NMPC state."""

    def __init__(self, spec: RobotSpec, gain: float = GAIN) -> None:
        self.spec = spec
        self.gain = float(gain)
        names = spec.state_names
        #: per platform DoF (x, y, z, yaw): its index in the NMPC state or None (fixed)
        self.index = {d: (names.index(d) if d in names else None) for d in PLATFORM_DOFS}
        self.fixed = {d: float(spec.platform.fixed.get(d, 0.0)) for d in PLATFORM_DOFS}
        self.vmax = {d: spec.platform.velocity_limit(d) for d in PLATFORM_DOFS}
        self.n_p = spec.n_platform
        self._lock = threading.Lock()
        self._plan: Plan | None = None
        self._previous: Plan | None = None
        self._hold: np.ndarray | None = None

    def follow(self, plan: Plan) -> None:
        """Fly ``plan`` from its ``t0`` on (the previous plan flies until then)."""
        with self._lock:
            self._previous = self._plan
            self._plan, self._hold = plan, None

    def hold(self, x: np.ndarray) -> None:
        """Hold NMPC state ``x`` (platform in place, arm still) until the next ``follow``."""
        with self._lock:
            self._plan = self._previous = None
            self._hold = np.asarray(x, dtype=float).copy()

    @property
    def holding(self) -> bool:
        """Whether there is no plan to follow."""
        return self._plan is None

    def reference(self, t: float) -> tuple[np.ndarray, np.ndarray] | None:
        """The reference state and feed-forward at mission time ``t`` (None: nothing set)."""
        with self._lock:
            plan, previous, hold = self._plan, self._previous, self._hold
        if plan is not None:
            if t < plan.t0 and previous is not None:
                return previous.at(t)
            return plan.at(t)
        if hold is not None:
            return hold.copy(), np.zeros_like(hold)
        return None

    def setpoint(
        self, t: float, x: np.ndarray
    ) -> tuple[tuple[float, float, float], float, np.ndarray] | None:
        """(ENU velocity [m/s], yaw rate [rad/s], joint targets [rad]) at mission time
        ``t`` [s] for the measured NMPC state ``x``; a platform DoF the NMPC does not
        move gets 0. ``None`` before a plan or hold point is set."""
        ref = self.reference(t)
        if ref is None:
            return None
        x_ref, u_ff = ref
        out = {}
        for d in PLATFORM_DOFS:
            i = self.index[d]
            if i is None:  # an inactive DoF: not controlled by the NMPC
                out[d] = 0.0
                continue
            err = x_ref[i] - x[i]
            if d == "yaw":
                err = math.remainder(err, 2.0 * math.pi)
            v = u_ff[i] + self.gain * err
            out[d] = min(self.vmax[d], max(-self.vmax[d], float(v)))
        velocity = (out["x"], out["y"], out["z"])
        return velocity, out["yaw"], x_ref[self.n_p :].copy()
