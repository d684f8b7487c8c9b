"""What the real-time runtime needs from a link to a vehicle: a small interface, so that
a transport is one module (MAVLink: ``aeromanip.mavlink.bridge``; a ROS 2 one would
publish the same setpoints and subscribe to the same state).

Everything here is in aeromanip's frames (world ENU, body FLU, SI units, rad): a
transport converts at its edge. Times are ``time.monotonic()`` of this process [s].
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass

from aeromanip.errors import AeromanipError, ExitCode

Vec3 = tuple[float, float, float]


class LinkError(AeromanipError):
    """The link could not be opened, the vehicle did not answer, refused a command, or
    the link was lost."""

    exit_code = ExitCode.LINK


@dataclass(frozen=True)
class VehicleState:
    """The latest vehicle state a transport received (platform only; joints come from
    the arm interface).

    Attributes:
        stamp: when it arrived [s, monotonic].
        position [m], velocity [m/s]: base origin, world ENU.
        roll, pitch, yaw [rad]: body FLU in world ENU (ZYX), yaw in [-pi, pi].
        yaw_rate: about world up [rad/s].
    """

    stamp: float
    position: Vec3
    velocity: Vec3
    roll: float
    pitch: float
    yaw: float
    yaw_rate: float


@dataclass(frozen=True)
class Setpoint:
    """What the autopilot is asked to fly: world ENU velocity [m/s] and yaw rate [rad/s];
    ``mission_t`` [s] is the runtime's mission clock (0 before the flight)."""

    velocity: Vec3
    yaw_rate: float
    mission_t: float = 0.0


class Transport(ABC):
    """A link to an autopilot that takes velocity + yaw-rate setpoints (PX4 offboard).

    ``connect`` waits for the autopilot; from then on the transport receives in the
    background and ``state()`` is the latest; ``send`` may be called from any thread.
    """

    @abstractmethod
    def connect(self, timeout_s: float) -> None:
        """Wait for the autopilot (``LinkError`` after ``timeout_s`` [s])."""

    @abstractmethod
    def state(self) -> VehicleState | None:
        """The latest vehicle state, or ``None`` before the first."""

    @abstractmethod
    def send(self, setpoint: Setpoint) -> None:
        """Send one setpoint (the autopilot needs a steady stream, PX4 > 2 Hz)."""

    @abstractmethod
    def arm(self, timeout_s: float) -> None:
        """Arm, and check the autopilot accepted (``LinkError`` naming its answer)."""

    @abstractmethod
    def set_mode(self, mode: str, timeout_s: float) -> None:
        """Switch to ``"offboard"`` or ``"hold"`` and check it was accepted."""

    @abstractmethod
    def mode(self) -> str:
        """The autopilot's mode from its last heartbeat (``hold``, ``offboard``, ``other``)."""

    @abstractmethod
    def close(self) -> None:
        """Stop receiving and release the link (idempotent)."""

    def fault(self) -> str | None:
        """What the vehicle reported that cannot be flown on (a value not finite or out of
        range, its clock running ahead), as one line; ``None`` if nothing. Once set it
        stays."""
        return None

    def telemetry_age(self, now: float) -> tuple[float, str]:
        """The age [s] at ``now`` of the oldest telemetry the state needs, and its name
        (by default: of the state)."""
        st = self.state()
        return (now - st.stamp if st is not None else 0.0), "vehicle state"

    def link_silence(self, now: float) -> float:
        """How long [s] at ``now`` nothing at all has come from the vehicle."""
        return self.telemetry_age(now)[0]

    def is_armed(self) -> bool:
        """Whether the vehicle says it is armed (its last heartbeat)."""
        return True


class ArmInterface(ABC):
    """The arm's joints: targets out, measured positions in (a bus of its own, e.g.
    Dynamixel, or through the autopilot: ``aeromanip.mavlink.arm``)."""

    @abstractmethod
    def send(self, q: Sequence[float]) -> None:
        """Joint position targets [rad], streamed with the setpoints."""

    @abstractmethod
    def joints(self) -> tuple[tuple[float, ...], float] | None:
        """The latest measured joint positions [rad] and when they arrived [s, monotonic];
        ``None`` before the first."""

    def wrench(self) -> tuple[float, ...] | None:
        """The wrist force/torque sensor's latest reading ``[f, tau]`` [N, N m] in the
        world frame (ENU), for the contact tasks (``Controller.step``'s ``wrench``);
        ``None``: no sensor (the default)."""
        return None
