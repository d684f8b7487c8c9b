"""The SITL autopilot's rules, without I/O: modes, arming, offboard entry and failsafe,
and what the vehicle flies in each mode (PX4's behaviour, as far as this subset goes).

- Disarmed: the vehicle is pinned at its start (the physics does not run).
  ``arm`` is accepted (the vehicle hovers in ``hold``); ``disarm`` is denied in flight.
- ``offboard`` is accepted while a setpoint younger than the offboard-loss timeout
  (``loss_s``, PX4's ``COM_OF_LOSS_T``) is there, as PX4's ``offboardCheck.cpp`` L38-66
  at ``161b530`` asks; else ``TEMPORARILY_REJECTED``.
- Offboard failsafe: no setpoint for ``loss_s`` -> ``hold`` where the vehicle is.
- ``hold`` (PX4's Hold, AUTO.LOITER): brake (zero velocity and yaw rate) until the speed
  is below ``BRAKED_SPEED``, then hold that position by a P loop (``HOLD_GAIN``) to
  velocity setpoints, and that yaw; the arm held at once at its last target.
- Arm targets (``on_joints``): the servo reference ramps from the last target along the
  rate of the last two (clipped to the joint velocity limits), for ``EXTRAPOLATE_S`` at
  most; in hold it stays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aeromanip.robot.spec import RobotSpec
from aeromanip.sim.flight_controller import FlightGains

LOSS_S = 0.5  # [s] offboard failsafe: no setpoint for this long (COM_OF_LOSS_T's default)
HOLD_GAIN = FlightGains().pos_p_xy  # [1/s] the position P of hold
BRAKED_SPEED = 0.02  # [m/s] hold brakes until the vehicle is this slow, then holds there
EXTRAPOLATE_S = 0.1  # [s] longest ramp of a joint target past its arrival

ACCEPTED, TEMPORARILY_REJECTED, DENIED = 0, 1, 2  # MAV_RESULT


@dataclass
class Event:
    """A change the autopilot announces: at SITL time ``t`` [s], ``text``."""

    t: float
    text: str


class Vehicle:
    """Mode logic and setpoint handling of the SITL autopilot for ``spec``'s robot.

    Times are the SITL's clock [s]. ``x`` arguments are the true NMPC state.
    """

    def __init__(self, spec: RobotSpec, x0: np.ndarray) -> None:
        self.spec = spec
        self.n_p = spec.n_platform
        self.index = {d: i for i, d in enumerate(spec.platform.dofs)}
        self.qdot_max = np.array([j.velocity for j in spec.joints])
        self.armed, self.mode = False, "hold"
        self.hold_x = np.asarray(x0, dtype=float).copy()
        self.braking = False
        self.events: list[Event] = []
        self.velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self.yaw_rate = 0.0
        self.mission_ms = 0
        self.last_sp = -math.inf  # when the last setpoint arrived
        self.q_target = self.hold_x[self.n_p :].copy()
        self.q_rate = np.zeros(spec.n_joints)
        self.q_time = -math.inf

    def _event(self, t: float, text: str) -> None:
        self.events.append(Event(t, text))

    def on_setpoint(
        self, t: float, velocity: tuple[float, float, float], yaw_rate: float, mission_ms: int
    ) -> None:
        """A velocity [m/s, ENU] + yaw-rate [rad/s] setpoint arrived."""
        self.velocity, self.yaw_rate, self.mission_ms = velocity, yaw_rate, mission_ms
        self.last_sp = t

    def steer(self, velocity: tuple[float, float, float], yaw_rate: float) -> None:
        """Fly ``velocity`` [m/s, ENU] and ``yaw_rate`` [rad/s] from now on, for the last
        setpoint (e.g. its position loop, re-evaluated each tick): the stream's timing
        (``on_setpoint``) is not touched."""
        self.velocity, self.yaw_rate = velocity, yaw_rate

    def on_joints(self, t: float, q: np.ndarray) -> None:
        """Joint position targets [rad] arrived."""
        q = np.asarray(q, dtype=float)
        gap = t - self.q_time
        if 0.0 < gap <= EXTRAPOLATE_S:
            self.q_rate = np.clip((q - self.q_target) / gap, -self.qdot_max, self.qdot_max)
        else:
            self.q_rate = np.zeros_like(q)
        self.q_target, self.q_time = q, t

    def arm(self, t: float, arm: bool, x: np.ndarray) -> int:
        """``MAV_CMD_COMPONENT_ARM_DISARM``: the ``MAV_RESULT``."""
        if not arm:
            return DENIED if self.armed else ACCEPTED  # no disarming in the air
        if not self.armed:
            self.armed = True
            self._hold(t, x, "armed: hold")
        return ACCEPTED

    def set_mode(self, t: float, mode: str, x: np.ndarray) -> int:
        """``MAV_CMD_DO_SET_MODE`` to ``"hold"``, ``"offboard"`` (else DENIED)."""
        if mode == "hold":
            if self.mode != "hold":
                self._hold(t, x, "hold (commanded)")
            return ACCEPTED
        if mode != "offboard":
            return DENIED
        if not self.streaming(t):
            self._event(t, "offboard refused: no setpoint stream")
            return TEMPORARILY_REJECTED
        if self.mode != "offboard":
            self.mode = "offboard"
            self._event(t, "offboard")
        return ACCEPTED

    def loss_s(self) -> float:
        """The offboard-loss timeout [s]."""
        return LOSS_S

    def streaming(self, t: float) -> bool:
        """Whether setpoints arrive (the last within ``loss_s()``)."""
        return t - self.last_sp <= self.loss_s()

    def _hold(self, t: float, x: np.ndarray, why: str) -> None:
        self.mode, self.braking = "hold", True
        self.hold_x = np.asarray(x, dtype=float).copy()
        self.hold_x[self.n_p :] = self.joint_reference(t)
        self.q_target, self.q_rate = self.hold_x[self.n_p :].copy(), np.zeros(len(self.q_rate))
        self._event(t, why)

    def joint_reference(self, t: float) -> np.ndarray:
        """The servo reference now [rad]."""
        ahead = min(max(t - self.q_time, 0.0), EXTRAPOLATE_S) if self.mode == "offboard" else 0.0
        return self.q_target + self.q_rate * ahead

    def command(self, t: float, x: np.ndarray, speed: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """What to fly now, at true ``speed`` [m/s]: rates ``u`` (platform velocity and yaw
        rate, joint rates) and the start of the joint ramp (``plan_x[0]``); checks the
        offboard failsafe first."""
        if self.mode == "offboard" and not self.streaming(t):
            self._hold(t, x, f"failsafe: no setpoint for {self.loss_s():g} s: hold")
        u, start = np.zeros(len(x)), np.asarray(x, dtype=float).copy()
        start[self.n_p :] = self.joint_reference(t)
        if self.mode == "offboard":
            rates = dict(zip("xyz", self.velocity, strict=True)) | {"yaw": self.yaw_rate}
            for d, i in self.index.items():
                u[i] = rates[d]
            u[self.n_p :] = self.q_rate if t - self.q_time < EXTRAPOLATE_S else 0.0
        elif self.braking:  # zero velocity: the velocity loop brakes
            if speed < BRAKED_SPEED:
                self.braking = False
                self.hold_x[: self.n_p] = x[: self.n_p]
        else:
            for i in range(self.n_p):
                err = self.hold_x[i] - x[i]
                if self.spec.platform.dofs[i] == "yaw":
                    err = math.remainder(err, 2.0 * math.pi)
                u[i] = HOLD_GAIN * err
        return u, start

    def mission_t(self, t: float) -> float:
        """The runtime's mission clock now [s] (NaN outside offboard)."""
        if self.mode != "offboard":
            return math.nan
        return 1e-3 * self.mission_ms + (t - self.last_sp)
