"""Surface-tangential tracking: the end effector's position error in a surface's plane.

``r = T (p_e(x) - p_e^d(t))`` [m] with ``T`` (2 x 3) the surface's tangents as rows
(``tasks.contact.tangents``: ``t1`` horizontal unless the normal is vertical, ``t2 =
n x t1``): the error along the normal is left to a force task, so the two compose without
fighting (by weight or by level).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from aeromanip.references import Reference
from aeromanip.tasks.base import TASKS, Stage
from aeromanip.tasks.contact import SurfaceTask, tangents


@TASKS.register("surface_tracking")
class SurfaceTracking(SurfaceTask):
    """``T (p_e(x) - p_e^d(t))`` [m] (module docstring); the reference is the scenario's.

    Args:
        reference: the end effector's reference [m].
        surface, point, normal: the surface (``SurfaceTask``).
    """

    name = "surface_tracking"

    def __init__(
        self,
        reference: Reference,
        surface: int = 0,
        point: tuple[float, float, float] | None = None,
        normal: tuple[float, float, float] | None = None,
    ) -> None:
        self.reference = reference
        self.param_size = 3
        self._set_surface(surface, point, normal)

    def residual(self, stage: Stage) -> ca.SX:
        """The position error along ``t1`` and ``t2`` [m]."""
        T = ca.DM(tangents(self.plane()[1]))
        return T @ (stage.kin.ee_position(stage.x) - stage.params)

    def param_values(self, times: np.ndarray) -> np.ndarray:
        """The reference position at each time [m]."""
        return np.asarray(self.reference.sample(np.asarray(times, dtype=float)), dtype=float)
