"""What the bridge accepts from a vehicle's telemetry, without I/O.

A ``LOCAL_POSITION_NED`` or ``ATTITUDE`` with a value that is not finite or out of its
range is a *fault*: the vehicle's estimate cannot be flown on (``check_position``,
``check_attitude``; one line naming the message, the field, the value and what is
allowed). Times (``TelemetryClock``): a message whose ``time_boot_ms`` is older than the
last one of its kind is dropped (a reordered datagram; or the autopilot rebooted, or sent
an absurd time once: then nothing new arrives and the state goes stale). Ranges are what
a multirotor's local frame and PX4's estimator can report; PX4 sends the estimator's values
as they are (``streams/LOCAL_POSITION_NED.hpp`` L67-73, ``streams/ATTITUDE.hpp`` L72-80 at
PX4 161b530; Euler angles from ``matrix::Eulerf``: roll, yaw in [-pi, pi], pitch in
[-pi/2, pi/2]).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

MAX_POSITION_M = 1.0e4  # [m] |x|, |y|, |z| of the local frame's origin
MAX_SPEED_M_S = 100.0  # [m/s] per axis
MAX_BODY_RATE_RAD_S = 35.0  # [rad/s] per axis (a 2000 deg/s gyro's range)
ANGLE_SLACK_RAD = 1e-3  # float32 rounding at the ends of the angle ranges

PI = math.pi


def _check(kind: str, fields: Iterable[tuple[str, float, float, float, str]]) -> str | None:
    """The first field of ``kind`` not finite or outside ``[lo, hi]`` as one line."""
    for name, value, lo, hi, unit in fields:
        v = float(value)
        if not math.isfinite(v):
            return f"{kind}.{name} = {v} (not finite)"
        if not lo <= v <= hi:
            return f"{kind}.{name} = {v:g} {unit} (allowed: [{lo:g}, {hi:g}] {unit})"
    return None


def check_position(msg: Any) -> str | None:
    """A ``LOCAL_POSITION_NED``'s fault, or ``None`` if it can be flown on."""
    p, v = MAX_POSITION_M, MAX_SPEED_M_S
    return _check(
        "LOCAL_POSITION_NED",
        [(n, getattr(msg, n), -p, p, "m") for n in ("x", "y", "z")]
        + [(n, getattr(msg, n), -v, v, "m/s") for n in ("vx", "vy", "vz")],
    )


def check_attitude(msg: Any) -> str | None:
    """An ``ATTITUDE``'s fault, or ``None`` if it can be flown on."""
    a, w = PI + ANGLE_SLACK_RAD, MAX_BODY_RATE_RAD_S
    return _check(
        "ATTITUDE",
        [
            ("roll", msg.roll, -a, a, "rad"),
            ("pitch", msg.pitch, -PI / 2 - ANGLE_SLACK_RAD, PI / 2 + ANGLE_SLACK_RAD, "rad"),
            ("yaw", msg.yaw, -a, a, "rad"),
        ]
        + [(n, getattr(msg, n), -w, w, "rad/s") for n in ("rollspeed", "pitchspeed", "yawspeed")],
    )


class TelemetryClock:
    """Per message kind: the last ``time_boot_ms`` accepted and when it arrived."""

    def __init__(self) -> None:
        self._last: dict[str, tuple[int, float]] = {}
        self.dropped = 0
        self.last_drop = ""

    def check(self, kind: str, boot_ms: int, now: float) -> bool:
        """Whether a ``kind`` message stamped ``boot_ms`` [ms] arriving at ``now`` [s] is
        new (not older than the last one of its kind): use it; else it is dropped."""
        last = self._last.get(kind)
        if last is not None and boot_ms < last[0]:
            self.dropped += 1
            self.last_drop = (
                f"{kind}.time_boot_ms went back from {last[0]} to {boot_ms} ms "
                "(reordered, or the autopilot rebooted)"
            )
            return False
        self._last[kind] = (boot_ms, now)
        return True
