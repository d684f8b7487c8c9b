"""Normal-force regulation: the contact spring's predicted force to a set force.

``r = f_n(x) - f_ref(t)`` [N] with ``f_n`` the spring of ``tasks.contact``
(``ContactSpring``: stiffness, rest offset, softplus width) on one surface. ``f_ref`` is
the constant ``f_ref`` or, with ``schedule = [[t, f], ...]`` (times in s, increasing),
linear between its points and held beyond them. Out of contact the residual's gradient
is nearly zero (``f_n`` is flat there): a force task regulates the push once the probe
touches, the approach belongs to a position task.
"""

from __future__ import annotations

from collections.abc import Sequence

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.tasks.base import TASKS, Stage
from aeromanip.tasks.contact import PROBE_RADIUS, SMOOTHING, ContactSpring, Plane, SurfaceTask

F_REF = 0.0  # [N] the set normal force without a schedule
MAX_FORCE = 1000.0  # [N]


def _schedule(schedule: Sequence[Sequence[float]], key: str) -> np.ndarray:
    """``[[t, f], ...]`` checked: (n, 2), times increasing, forces in ``[0, MAX_FORCE]``."""
    try:
        a = np.asarray(schedule, dtype=float)
    except (TypeError, ValueError):
        a = np.zeros((0, 0))
    ok = a.ndim == 2 and a.shape[0] >= 1 and a.shape[1] == 2 and np.all(np.isfinite(a))
    if not ok or np.any(np.diff(a[:, 0]) <= 0) or np.any(a[:, 1] < 0) or a[:, 1].max() > MAX_FORCE:
        raise ConfigError(
            f"{key}: must be [[t, f], ...] with times increasing [s] and forces in "
            f"[0, {MAX_FORCE:g}] N, got {schedule!r}"
        )
    return a


@TASKS.register("force")
class NormalForce(SurfaceTask):
    """``f_n(x) - f_ref(t)`` [N] (module docstring).

    Args:
        stiffness: the spring's ``k`` [N/m].
        f_ref: the set normal force [N] (without ``schedule``).
        schedule: ``[[t, f], ...]``: the set force [N] against time [s].
        surface, point, normal: the surface (``SurfaceTask``).
        probe_radius: the probe's radius [m]; ``None``: the scenario's
            ``physics.probe_radius`` (else ``PROBE_RADIUS``).
        rest_offset: the spring's rest point behind the face [m].
        smoothing: the softplus width [m].
    """

    name = "force"

    def __init__(
        self,
        stiffness: float,
        f_ref: float = F_REF,
        schedule: list[tuple[float, float]] | None = None,
        surface: int = 0,
        point: tuple[float, float, float] | None = None,
        normal: tuple[float, float, float] | None = None,
        probe_radius: float | None = None,
        rest_offset: float = 0.0,
        smoothing: float = SMOOTHING,
    ) -> None:
        if not (0.0 <= f_ref <= MAX_FORCE):
            raise ConfigError(f"{self.name}.f_ref: must be in [0, {MAX_FORCE:g}] N, got {f_ref}")
        self.f_ref = float(f_ref)
        self.schedule = None if schedule is None else _schedule(schedule, f"{self.name}.schedule")
        self.stiffness, self.rest_offset, self.smoothing = stiffness, rest_offset, smoothing
        self.probe_radius = probe_radius
        self.param_size = 1
        self._set_surface(surface, point, normal)
        ContactSpring((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), *self._spring_numbers())  # checked now

    def _spring_numbers(self) -> tuple[float, float, float, float]:
        radius = PROBE_RADIUS if self.probe_radius is None else self.probe_radius
        return self.stiffness, radius, self.rest_offset, self.smoothing

    def use_scenario(self, planes: Sequence[Plane], probe_radius: float) -> None:
        """The scenario's surface (``SurfaceTask``) and, unless given, its probe radius."""
        super().use_scenario(planes, probe_radius)
        if self.probe_radius is None:
            self.probe_radius = float(probe_radius)
        self.spring()

    def spring(self) -> ContactSpring:
        """The contact model of this task's surface."""
        point, normal = self.plane()
        return ContactSpring(tuple(point), tuple(normal), *self._spring_numbers())

    def residual(self, stage: Stage) -> ca.SX:
        """Predicted minus set normal force [N]."""
        return self.spring().normal_force(stage.kin.ee_position(stage.x)) - stage.params[0]

    def param_values(self, times: np.ndarray) -> np.ndarray:
        """The set force at each time [N]: (len(times), 1)."""
        t = np.asarray(times, dtype=float)
        if self.schedule is None:
            return np.full((len(t), 1), self.f_ref)
        return np.interp(t, self.schedule[:, 0], self.schedule[:, 1])[:, None]
