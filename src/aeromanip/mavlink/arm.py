"""The arm through the autopilot: joint targets as ``MAV_CMD_DO_SET_ACTUATOR``, joint
positions back as ``NAMED_VALUE_FLOAT``.

Targets: joint ``i`` (1-based) is actuator ``i``: ``param(i)`` of the command, whose
``param7`` (the actuator set index) is 0; unused params are NaN (no change). PX4 reads
set index 0 only, six outputs (``FunctionActuatorSet.hpp`` L55-76 at PX4 161b530), so an
arm of more than six joints is refused (``ConfigError``) before anything is sent. A
joint target ``q`` [rad] is sent as ``2 (q - lower) / (upper - lower) - 1``, in
``[-1, 1]`` across the joint's limits. On PX4 assign the servo outputs the functions
"Peripheral via Actuator Set 1..n" and set their PWM range to the joint limits.

Feedback: ``NAMED_VALUE_FLOAT`` named ``q1``.. ``qn`` [rad] (the SITL autopilot sends them
with its state; on a vehicle, whatever reads the joint encoders). Without feedback the
arm reports the targets it sent (open loop): say so with ``feedback=False``.

The wrist force/torque sensor, where there is one: ``NAMED_VALUE_FLOAT`` named
``wrist_fx``, ``wrist_fy``, ``wrist_fz`` [N] and ``wrist_tx``, ``wrist_ty``, ``wrist_tz``
[N m], world frame (ENU, as the controller takes it: ``Controller.step``'s ``wrench``);
the SITL autopilot sends them beside the joints when its scenario has a surface.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Sequence
from typing import Any

from aeromanip.errors import ConfigError
from aeromanip.robot.spec import RobotSpec
from aeromanip.runtime.transport import ArmInterface

MAV_CMD_DO_SET_ACTUATOR = 187
ACTUATORS_PER_COMMAND = 6


def joint_to_actuator(q: float, lower: float, upper: float) -> float:
    """A joint position [rad] as an actuator value in [-1, 1] across its limits."""
    v = 2.0 * (float(q) - lower) / (upper - lower) - 1.0
    return min(1.0, max(-1.0, v))


def actuator_to_joint(value: float, lower: float, upper: float) -> float:
    """An actuator value in [-1, 1] as the joint position [rad] it stands for."""
    return lower + 0.5 * (float(value) + 1.0) * (upper - lower)


def actuator_params(q: Sequence[float], limits: Sequence[tuple[float, float]]) -> list[list[float]]:
    """The seven params of each ``DO_SET_ACTUATOR`` command carrying targets ``q`` [rad]."""
    values = [joint_to_actuator(v, lo, hi) for v, (lo, hi) in zip(q, limits, strict=True)]
    out = []
    for k in range(0, len(values), ACTUATORS_PER_COMMAND):
        chunk = values[k : k + ACTUATORS_PER_COMMAND]
        out.append(chunk + [math.nan] * (ACTUATORS_PER_COMMAND - len(chunk)) + [float(k // 6)])
    return out


def check_arm(spec: RobotSpec) -> None:
    """``ConfigError`` if PX4 cannot drive ``spec``'s joints (more than six)."""
    if spec.n_joints > ACTUATORS_PER_COMMAND:
        raise ConfigError(
            f"robot: {spec.n_joints} joints; MAV_CMD_DO_SET_ACTUATOR drives at most "
            f"{ACTUATORS_PER_COMMAND} (PX4 reads actuator set 0 only)"
        )


#: the ``NAMED_VALUE_FLOAT`` names of the wrist sensor's reading, in ``[f, tau]`` order
WRENCH_NAMES = ("wrist_fx", "wrist_fy", "wrist_fz", "wrist_tx", "wrist_ty", "wrist_tz")


def joint_name(i: int) -> str:
    """The ``NAMED_VALUE_FLOAT`` name of joint ``i`` (0-based): ``q1``, ``q2``..."""
    return f"q{i + 1}"


class MavlinkActuatorArm(ArmInterface):
    """The arm behind the autopilot (module docstring).

    Args:
        transport: a ``MavlinkTransport`` (it routes the feedback messages here).
        spec: the robot (joint limits).
        feedback: read the joints from ``NAMED_VALUE_FLOAT``; ``False``: report the last
            targets sent (servos without feedback).
    """

    def __init__(self, transport: Any, spec: RobotSpec, feedback: bool = True) -> None:
        check_arm(spec)
        self.transport = transport
        self.limits = [(j.lower, j.upper) for j in spec.joints]
        self.names = {joint_name(i): i for i in range(spec.n_joints)}
        self.feedback = feedback
        self._q: list[float | None] = [None] * spec.n_joints
        self._wrench: list[float | None] = [None] * len(WRENCH_NAMES)
        self._stamp = 0.0
        self._lock = threading.Lock()
        transport.add_handler("NAMED_VALUE_FLOAT", self._on_value)

    def _on_value(self, msg: Any) -> None:
        name = str(msg.name).rstrip("\x00")
        i = self.names.get(name)
        if i is not None and self.feedback:
            with self._lock:
                self._q[i] = float(msg.value)
                self._stamp = time.monotonic()
        elif name in WRENCH_NAMES:
            with self._lock:
                self._wrench[WRENCH_NAMES.index(name)] = float(msg.value)

    def send(self, q: Sequence[float]) -> None:
        """Stream joint targets [rad] (one ``DO_SET_ACTUATOR`` per six joints)."""
        for params in actuator_params(q, self.limits):
            self.transport.command_nowait(MAV_CMD_DO_SET_ACTUATOR, params)
        if not self.feedback:
            with self._lock:
                self._q, self._stamp = [float(v) for v in q], time.monotonic()

    def joints(self) -> tuple[tuple[float, ...], float] | None:
        """The latest joint positions [rad] and their arrival time [s, monotonic]."""
        with self._lock:
            if any(v is None for v in self._q):
                return None
            return tuple(float(v) for v in self._q), self._stamp  # type: ignore[arg-type]

    def wrench(self) -> tuple[float, ...] | None:
        """The wrist sensor's latest reading ``[f, tau]`` [N, N m, world ENU], once every
        component has arrived; ``None`` before (or without a sensor)."""
        with self._lock:
            if any(v is None for v in self._wrench):
                return None
            return tuple(float(v) for v in self._wrench)  # type: ignore[arg-type]
