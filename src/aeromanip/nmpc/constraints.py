"""NMPC constraints (paper Sec. V): state/command bounds, self-collision, user constraints.

State bounds and path constraints apply at stages ``1..N`` (the state at stage 0 is the
measured one); command bounds at stages ``0..N-1``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError, InfeasibleProblemError
from aeromanip.robot.spec import RobotSpec
from aeromanip.tasks.base import Stage

D_MIN = 0.1  # [m] default self-collision clearance below the base (paper eq. 17)


@dataclass(frozen=True)
class Bounds:
    """Box bounds on the state ``x`` [m, rad] and the command ``u = dx/dt`` [m/s, rad/s],
    and on how fast the command may change, ``|u[k] - u[k-1]| <= accel dt`` [m/s^2, rad/s^2]
    (the platform's and the joints' acceleration; ``None``: unbounded).

    Unbounded entries are ``-inf``/``inf``. ``margin`` (set by ``tightened``): per DoF,
    how far the state bounds were shrunk [m, rad]; ``margin_ramp`` [s]: for this long
    ahead a plan may use the margin where the vehicle would coast into it
    (``return_bounds``); 0: never.
    """

    names: tuple[str, ...]
    x_lower: np.ndarray
    x_upper: np.ndarray
    u_lower: np.ndarray
    u_upper: np.ndarray
    accel: np.ndarray | None = None
    margin: np.ndarray | None = None
    margin_ramp: float = 0.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.margin_ramp) and self.margin_ramp >= 0):
            raise ConfigError(f"bounds.margin_ramp: must be >= 0 s, got {self.margin_ramp}")
        if self.accel is not None:
            a = np.asarray(self.accel, dtype=float)
            if a.shape != (len(self.names),) or np.any(np.isnan(a)) or np.any(a <= 0):
                raise ConfigError(
                    f"bounds.acceleration: expected {len(self.names)} values > 0, got {a}"
                )
        for kind in ("x", "u"):
            lo, hi = getattr(self, f"{kind}_lower"), getattr(self, f"{kind}_upper")
            if lo.shape != (len(self.names),) or hi.shape != (len(self.names),):
                raise ConfigError(f"bounds.{kind}: expected {len(self.names)} entries")
            for i, n in enumerate(self.names):
                if np.isnan(lo[i]) or np.isnan(hi[i]):
                    raise ConfigError(f"bounds.{kind}.{n}: must not be NaN")
                if lo[i] > hi[i]:
                    raise InfeasibleProblemError(
                        f"bounds.{kind}.{n}: lower {lo[i]:.6g} is above upper {hi[i]:.6g}"
                    )

    @classmethod
    def from_robot(
        cls,
        spec: RobotSpec,
        *,
        joint_limits: bool = True,
        velocity_limits: bool = True,
        platform_box: Mapping[str, Sequence[float]] | None = None,
    ) -> Bounds:
        """Joint position limits and velocity limits from the robot, plus a platform box.

        ``platform_box`` maps active platform DoFs to ``(lower, upper)`` [m or rad].
        """
        names = spec.state_names
        n = len(names)
        xl, xu = np.full(n, -np.inf), np.full(n, np.inf)
        ul, uu = np.full(n, -np.inf), np.full(n, np.inf)
        npf = spec.n_platform
        for i, j in enumerate(spec.joints):
            if joint_limits:
                xl[npf + i], xu[npf + i] = j.lower, j.upper
            if velocity_limits:
                ul[npf + i], uu[npf + i] = -j.velocity, j.velocity
        for i, dof in enumerate(spec.platform.dofs):
            if velocity_limits:
                v = spec.platform.velocity_limit(dof)
                ul[i], uu[i] = -v, v
        for dof, box in (platform_box or {}).items():
            if dof not in spec.platform.dofs:
                raise ConfigError(
                    f"platform_box.{dof}: not an active platform DoF of {spec.name!r} "
                    f"(active: {list(spec.platform.dofs)})"
                )
            if len(box) != 2:
                raise ConfigError(f"platform_box.{dof}: expected [lower, upper]")
            i = spec.platform.dofs.index(dof)
            xl[i], xu[i] = float(box[0]), float(box[1])
        return cls(names, xl, xu, ul, uu)

    def tightened(self, margins: Mapping[str, float], ramp: float = 0.0) -> Bounds:
        """The state bounds shrunk by ``margins`` (state name -> margin [m or rad]), with
        ``ramp`` [s] of soft braking into them (``return_bounds``).

        Constraint tightening: a controller planning inside the tightened box keeps the
        real system, which lags its references a little, inside the true one. Near an
        active bound, though, the state fed back (noisy) is past the tightened bound
        every other step, or its lagging rates carry it there: forcing the next predicted
        states inside at once takes hard commands that the vehicle turns into jolts and
        tilt, and the loop rings along the bound.
        """
        lo, hi = self.x_lower.copy(), self.x_upper.copy()
        shrink = np.zeros(len(self.names))
        for name, m in margins.items():
            if name not in self.names:
                raise ConfigError(f"bounds margin: unknown state {name!r}")
            i = self.names.index(name)
            lo[i], hi[i], shrink[i] = lo[i] + m, hi[i] - m, m
            if lo[i] > hi[i]:
                raise ConfigError(f"bounds margin: {m} closes the bounds of {name}")
        return Bounds(
            self.names,
            lo,
            hi,
            self.u_lower.copy(),
            self.u_upper.copy(),
            self.accel_limits,
            shrink,
            float(ramp),
        )

    def return_bounds(
        self, x_coast: np.ndarray, t: float | np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The bounds of a state predicted ``t`` [s] ahead, given ``x_coast``, where the
        vehicle would be then with its commands set to zero: the tightened bounds, but a
        plan may go as far into the margin as that coasting state, up to a share
        ``1 - t / margin_ramp`` of the margin (all of it now, none from ``margin_ramp``
        on). Braking into the margin is soft, coming back takes ``margin_ramp``, and a
        plan can never go further out than the vehicle would coast. Several states at
        once: ``x_coast`` (k, nx) and ``t`` (k, 1)."""
        if self.margin is None or self.margin_ramp <= 0 or np.all(t >= self.margin_ramp):
            return self.x_lower, self.x_upper
        share = np.maximum(1.0 - np.asarray(t, dtype=float) / self.margin_ramp, 0.0)
        room = share * self.margin  # none from margin_ramp on
        above = np.clip(x_coast - self.x_upper, 0.0, room)
        below = np.clip(self.x_lower - x_coast, 0.0, room)
        return self.x_lower - below, self.x_upper + above

    @property
    def accel_limits(self) -> np.ndarray | None:
        """The command-rate bounds [unit/s^2] (a copy; ``None`` if every one is infinite)."""
        if self.accel is None or not np.any(np.isfinite(self.accel)):
            return None
        return np.asarray(self.accel, dtype=float).copy()

    def with_accel(self, accel: np.ndarray | None) -> Bounds:
        """The same bounds with command-rate bounds ``accel`` (per DoF, ``inf``: none)."""
        return Bounds(
            self.names,
            self.x_lower,
            self.x_upper,
            self.u_lower,
            self.u_upper,
            accel,
            self.margin,
            self.margin_ramp,
        )

    def as_dict(self) -> dict[str, list[float]]:
        """Finite bounds keyed like the run log columns: ``q1``, ``x``, ``u_q1``, ..."""
        out = {}
        for i, n in enumerate(self.names):
            for prefix, lo, hi in (
                ("", self.x_lower, self.x_upper),
                ("u_", self.u_lower, self.u_upper),
            ):
                if np.isfinite(lo[i]) or np.isfinite(hi[i]):
                    out[prefix + n] = [float(lo[i]), float(hi[i])]
        return out

    def violation(self, x: np.ndarray) -> float:
        """How far ``x`` lies outside the state bounds (0 inside) [m or rad]."""
        return float(max(np.max(self.x_lower - x), np.max(x - self.x_upper), 0.0))


class PathRows(NamedTuple):
    """Constraint rows ``lower <= expr <= upper`` at one stage."""

    expr: ca.SX
    lower: np.ndarray
    upper: np.ndarray


class PathConstraint(ABC):
    """``lower <= expression(stage) <= upper`` at stages ``1..N``.

    Subclass and implement ``expression``, or use ``UserConstraint`` with a callable.
    """

    name: str = "constraint"

    @abstractmethod
    def expression(self, stage: Stage) -> PathRows:
        """The constrained expression (a column vector) and its bounds."""

    def uses_command(self) -> bool:
        """Whether the expression needs the command (then not applied at stage N)."""
        return False


class Clearance(PathConstraint):
    """Self-collision avoidance (paper eq. 17): each point at least ``d_min`` [m] below the base.

    ``points`` are names from ``Kinematics.point_names()`` (``joint1..jointN``, ``ee``);
    by default every joint origin after the first and the end effector.
    """

    name = "clearance"

    def __init__(self, d_min: float = D_MIN, points: Sequence[str] | None = None) -> None:
        if not np.isfinite(d_min):
            raise ConfigError(f"clearance.d_min: must be finite, got {d_min}")
        self.d_min = float(d_min)
        self.points = None if points is None else list(points)

    def expression(self, stage: Stage) -> PathRows:
        """Depth of each point below the base [m], at least ``d_min``."""
        f = stage.kin.clearance(self.points)
        n = f.size1_out(0)
        return PathRows(f(stage.x), np.full(n, self.d_min), np.full(n, np.inf))


class UserConstraint(PathConstraint):
    """``lb <= fn(stage) <= ub`` for a user expression of the state (and command)."""

    def __init__(
        self,
        name: str,
        fn: Callable[[Stage], ca.SX],
        lb: float | Sequence[float],
        ub: float | Sequence[float],
        *,
        uses_command: bool = False,
    ) -> None:
        self.name = name
        self.fn = fn
        self.lb, self.ub = lb, ub
        self._uses_command = uses_command

    def expression(self, stage: Stage) -> PathRows:
        """``fn(stage)``, with bounds broadcast to its size."""
        e = ca.vec(self.fn(stage))
        n = e.numel()
        lower = np.broadcast_to(np.asarray(self.lb, dtype=float), (n,)).copy()
        upper = np.broadcast_to(np.asarray(self.ub, dtype=float), (n,)).copy()
        bad = np.nonzero(lower > upper)[0]
        if bad.size:
            raise InfeasibleProblemError(
                f"constraint {self.name!r}[{bad[0]}]: lower is above upper"
            )
        return PathRows(e, lower, upper)

    def uses_command(self) -> bool:
        """As declared by the user."""
        return self._uses_command
