"""A bounded approach speed near a surface: the NMPC's plan may close in on it only slowly.

With ``n`` the surface's outward normal, ``p_e`` the end effector and ``r`` the probe's
radius, the gap is ``g(x) = (p_e(x) - point) . n - r`` [m] (0: touching) and the speed
towards the surface over the step that ends at stage ``k``, from the state it started at
(``x_k - dt u_{k-1}``: the paper's model, exactly), ``v_in = -n . (p_e(x_k) -
p_e(x_k - dt u_{k-1})) / dt`` [m/s] (an instantaneous ``J u`` at either end lets a
plan swing the arm through the step faster than it says). At every stage ``k = 1..N``::

    v_in <= speed + gain * softplus_w(|g(x_k) - c| - h)

with the band ``[-release, distance]`` = ``[c - h, c + h]``: at most ``speed`` [m/s]
from ``distance`` [m] before the surface to ``release`` [m] past its face (the first
touch), more elsewhere (``gain`` [1/s] per metre beyond the band, rounded over ``w`` =
``SOFTPLUS_WIDTH``): far away the plan may hurry, and well in contact (the NMPC's
untilted model puts the EE past the face while the tilted platform pushes) the force
task and its bounds govern the push. The command of each stage is the one that brought
the state there (``Stage.u_prev``), so the command applied now is bounded too. Moving
away, or resting, always satisfies it: the constraint never makes a plan infeasible.

Scenario (``[approach]``): ``speed``, ``distance``, ``release`` (default ``RELEASE``),
``gain``, ``surface`` (the index of a ``[[physics.surfaces]]`` entry, default 0).
"""

from __future__ import annotations

from collections.abc import Sequence

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.nmpc.constraints import PathConstraint, PathRows
from aeromanip.tasks.base import Stage

APPROACH_GAIN = 2.0  # [1/s] extra speed allowed per metre beyond ``distance``
SOFTPLUS_WIDTH = 0.005  # [m]
RELEASE = 0.005  # [m] how far past the face the bound holds
MAX_SPEED = 10.0  # [m/s]


class ApproachSpeed(PathConstraint):
    """The bound of the module docstring.

    Args:
        point, normal: the surface (world frame; the normal outward, normalised here).
        speed: the largest speed towards it near it [m/s].
        distance: how near [m] (from the probe's surface to the face).
        gain: extra speed allowed per metre beyond the band [1/s].
        release: how far past the face [m] the bound holds.
        probe_radius: the probe's radius [m].
    """

    name = "approach"

    def __init__(
        self,
        point: Sequence[float],
        normal: Sequence[float],
        speed: float,
        distance: float,
        gain: float = APPROACH_GAIN,
        probe_radius: float = 0.0,
        release: float = RELEASE,
    ) -> None:
        n = np.asarray(normal, dtype=float)
        if n.shape != (3,) or not np.all(np.isfinite(n)) or np.linalg.norm(n) < 1e-9:
            raise ConfigError(f"approach.normal: must be a nonzero 3-vector, got {normal!r}")
        for key, value, high in (
            ("speed", speed, MAX_SPEED),
            ("distance", distance, 100.0),
            ("gain", gain, 1000.0),
            ("release", release, 100.0),
        ):
            if isinstance(value, bool) or not (0.0 < value <= high):
                raise ConfigError(f"approach.{key}: must be in (0, {high:g}], got {value!r}")
        self.point = np.asarray(point, dtype=float)
        self.normal = n / np.linalg.norm(n)
        self.speed, self.distance, self.gain = float(speed), float(distance), float(gain)
        self.probe_radius, self.release = float(probe_radius), float(release)

    def gap(self, kin_ee: ca.SX) -> ca.SX:
        """``g`` [m] of an EE position."""
        return ca.dot(ca.DM(self.normal), kin_ee - ca.DM(self.point)) - self.probe_radius

    def expression(self, stage: Stage) -> PathRows:
        """``v_in - allowed <= 0`` [m/s]."""
        x, kin = stage.x, stage.kin
        step = kin.ee_position(x) - kin.ee_position(x - stage.dt * stage.u_prev)
        v_in = -ca.dot(ca.DM(self.normal), step) / stage.dt
        w = SOFTPLUS_WIDTH
        centre, half = (self.distance - self.release) / 2, (self.distance + self.release) / 2
        off = self.gap(kin.ee_position(x)) - centre
        beyond = ca.sqrt(off * off + w * w) - half  # smooth |off| - half: out of the band
        soft = ca.fmax(beyond, 0) + w * ca.log1p(ca.exp(-ca.fabs(beyond) / w))
        return PathRows(v_in - self.speed - self.gain * soft, np.array([-np.inf]), np.zeros(1))
