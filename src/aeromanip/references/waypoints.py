"""Minimum-jerk (quintic) segments through waypoints (paper Sec. VI-B/C)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import casadi as ca
import numpy as np

from aeromanip.config import Table
from aeromanip.errors import ConfigError
from aeromanip.references.base import REFERENCES, Reference, as_times, points_from_table


def _min_jerk(tau: np.ndarray) -> np.ndarray:
    """Quintic blend 10 tau^3 - 15 tau^4 + 6 tau^5: zero velocity/acceleration at 0 and 1."""
    return tau**3 * (10.0 + tau * (-15.0 + 6.0 * tau))


HOLD = 0.0  # [s] dwell at intermediate waypoints (with speed) and at the last one


@REFERENCES.register("waypoints")
class Waypoints(Reference):
    """A C2 reference through waypoints [m], minimum-jerk (quintic) between each pair.

    Each segment starts and ends with zero velocity and acceleration and passes exactly
    through its waypoints at their times. Give either ``times`` [s] (strictly
    increasing, one per point; before ``times[0]`` the first point is held) or
    ``speed`` [m/s], the average speed of each segment, from which segment durations
    are derived (start at t = 0). ``hold_s`` [s]: with ``speed``, the dwell at every
    intermediate waypoint; in both cases the time the last point is held before
    ``duration`` ends. After the last waypoint the reference holds it.
    """

    def __init__(
        self,
        points: Sequence[Sequence[float]] | np.ndarray,
        times: Sequence[float] | np.ndarray | None = None,
        *,
        speed: float | None = None,
        hold_s: float = HOLD,
        name: str = "reference",
    ) -> None:
        pts = np.asarray(points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 1:
            raise ConfigError(f"{name}.points: expected a list of [x, y, z], got shape {pts.shape}")
        if not np.all(np.isfinite(pts)):
            raise ConfigError(f"{name}.points: must be finite numbers")
        if not (math.isfinite(hold_s) and hold_s >= 0):
            raise ConfigError(f"{name}.hold: must be >= 0 s, got {hold_s!r}")
        if (times is None) == (speed is None):
            raise ConfigError(f"{name}: give exactly one of 'times' and 'speed'")
        self.points = pts
        self.hold_s = float(hold_s)
        if times is not None:
            self.times = _checked_times(times, pts.shape[0], name)
            knot_t, knot_p = self.times, pts
        else:
            self.times, knot_t, knot_p = _knots_at_speed(pts, float(speed), self.hold_s, name)
        self._knot_t = knot_t
        self._knot_p = knot_p
        self.duration = float(self.times[-1] + self.hold_s)

    def markers(self) -> np.ndarray:
        """The waypoints [m], shape (n, 3)."""
        return self.points

    def sample(self, times: np.ndarray | Sequence[float]) -> np.ndarray:
        """Reference positions [m] at ``times`` [s], shape (len(times), 3)."""
        t = as_times(times)
        if self._knot_t.size == 1:
            return np.tile(self._knot_p[0], (t.size, 1))
        kt, kp = self._knot_t, self._knot_p
        i = np.clip(np.searchsorted(kt, t, side="right") - 1, 0, kt.size - 2)
        tau = np.clip((t - kt[i]) / (kt[i + 1] - kt[i]), 0.0, 1.0)
        s = _min_jerk(tau)
        return kp[i] + s[:, None] * (kp[i + 1] - kp[i])

    def expression(self, t: ca.SX) -> ca.SX:
        """``sample`` at one time ``t`` [s] as a CasADi expression (3,): the first knot
        plus every segment's share of its step (all of it before ``t``, none after)."""
        kt, kp = self._knot_t, self._knot_p
        p = ca.SX(ca.DM(kp[0]))
        for i in range(kt.size - 1):
            tau = ca.fmin(ca.fmax((t - kt[i]) / (kt[i + 1] - kt[i]), 0.0), 1.0)
            p += tau**3 * (10.0 + tau * (-15.0 + 6.0 * tau)) * ca.DM(kp[i + 1] - kp[i])
        return p

    @classmethod
    def from_table(cls, table: Table, base_dir: Path | None = None) -> Waypoints:
        """Keys: ``points`` [m], and ``times`` [s] or ``speed`` [m/s]; optional ``hold`` [s]."""
        points = points_from_table(table, "points")
        times = table.floats("times") if table.has("times") else None
        speed = table.float("speed") if table.has("speed") else None
        hold = table.float("hold", HOLD)
        return cls(points, times, speed=speed, hold_s=hold, name=table.path or "reference")


def _checked_times(times: Sequence[float] | np.ndarray, n: int, name: str) -> np.ndarray:
    """``times`` [s] as an array: one per point, finite, strictly increasing."""
    tk = np.asarray(times, dtype=float).reshape(-1)
    if tk.size != n:
        raise ConfigError(f"{name}.times: expected {n} times (one per point), got {tk.size}")
    if not np.all(np.isfinite(tk)):
        raise ConfigError(f"{name}.times: must be finite numbers")
    bad = np.nonzero(np.diff(tk) <= 0)[0]
    if bad.size:
        k = int(bad[0]) + 1
        raise ConfigError(
            f"{name}.times[{k}]: times must be strictly increasing, "
            f"got {float(tk[k - 1])!r} then {float(tk[k])!r}"
        )
    return tk


def _knots_at_speed(
    pts: np.ndarray, speed: float, hold_s: float, name: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Arrival times [s] at each point at ``speed`` [m/s] from t = 0, dwelling ``hold_s``
    at every intermediate point; and the knots (times, points) of the segments."""
    if not (math.isfinite(speed) and speed > 0):
        raise ConfigError(f"{name}.speed: must be > 0 m/s, got {speed!r}")
    knot_t, knot_p, arrivals = [0.0], [pts[0]], [0.0]
    t = 0.0
    for k in range(1, pts.shape[0]):
        dist = float(np.linalg.norm(pts[k] - pts[k - 1]))
        if dist < 1e-12:
            raise ConfigError(
                f"{name}.points[{k}]: repeats the previous point; "
                "use 'hold' or explicit 'times' to pause"
            )
        t += dist / speed
        knot_t.append(t)
        knot_p.append(pts[k])
        arrivals.append(t)
        if hold_s > 0 and k < pts.shape[0] - 1:
            t += hold_s
            knot_t.append(t)
            knot_p.append(pts[k])
    return np.array(arrivals), np.array(knot_t), np.array(knot_p)
