"""Surface-tangential tracking: the end effector's position error in a surface's plane.

``r = T (p_e(x) - p_e^d(t))`` [m] with ``T`` (2 x 3) the surface's tangents as rows
(``tasks.contact.tangents``: ``t1`` horizontal unless the normal is vertical, ``t2 =
n x t1``): the error along the normal is left to a force task, so the two compose without
fighting (by weight or by level).

With ``estimate = true`` the task corrects the NMPC's kinematics (no roll, pitch) with the
measured attitude: the EE's displacement by the platform's tilt (a platform pushing on a
surface tilts, and its hanging arm swings with it), low-passed with ``time_constant`` [s]
and in the surface's plane, is subtracted from the reference each step, so that the real
end effector, not the untilted model's, tracks it.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.references import Reference
from aeromanip.tasks.base import TASKS, Stage
from aeromanip.tasks.contact import SurfaceTask, tangents

#: [s] low-pass of the tilt correction: slower than the platform's accelerations (their
#: transient tilt, chased, makes the slide oscillate), fast against the friction's
TILT_TIME_CONSTANT = 1.0


@TASKS.register("surface_tracking")
class SurfaceTracking(SurfaceTask):
    """``T (p_e(x) - p_e^d(t))`` [m] (module docstring); the reference is the scenario's.

    Args:
        reference: the end effector's reference [m].
        surface, point, normal: the surface (``SurfaceTask``).
        estimate: correct for the platform's measured tilt (module docstring);
            ``time_constant`` [s] its low-pass.
    """

    name = "surface_tracking"

    def __init__(
        self,
        reference: Reference,
        surface: int = 0,
        point: tuple[float, float, float] | None = None,
        normal: tuple[float, float, float] | None = None,
        estimate: bool = False,
        time_constant: float = TILT_TIME_CONSTANT,
    ) -> None:
        self.reference = reference
        self.param_size = 3
        self._set_surface(surface, point, normal)
        if isinstance(time_constant, bool) or not (0.0 < time_constant <= 100.0):
            raise ConfigError(
                f"{self.name}.time_constant: must be in (0, 100] s, got {time_constant!r}"
            )
        self.estimate, self.time_constant = bool(estimate), float(time_constant)
        self.reset()

    def reset(self) -> None:
        """Forget the tilt correction (a new run)."""
        self.bias = np.zeros(3)
        self._t_last: float | None = None

    def observe(
        self,
        ee: np.ndarray,
        wrench: np.ndarray | None,
        t: float,
        ee_tilted: np.ndarray | None = None,
    ) -> None:
        """With ``estimate``: the tilt's displacement of the EE (``ee_tilted - ee``) in the
        surface's plane, low-passed [m]."""
        if not self.estimate or ee_tilted is None:
            return
        dt = 0.0 if self._t_last is None else max(t - self._t_last, 0.0)
        self._t_last = t
        T = tangents(self.plane()[1])
        target = T.T @ (T @ (np.asarray(ee_tilted) - np.asarray(ee)))
        alpha = 1.0 if dt == 0.0 and not self.bias.any() else dt / (self.time_constant + dt)
        self.bias = self.bias + alpha * (target - self.bias)

    def observations(self, t: float) -> dict[str, float]:
        """With ``estimate``: the tilt correction's size [m] (``tilt_correction``)."""
        return {"tilt_correction": float(np.linalg.norm(self.bias))} if self.estimate else {}

    def residual(self, stage: Stage) -> ca.SX:
        """The position error along ``t1`` and ``t2`` [m]."""
        T = ca.DM(tangents(self.plane()[1]))
        return T @ (stage.kin.ee_position(stage.x) - stage.params)

    def param_values(self, times: np.ndarray) -> np.ndarray:
        """The reference position at each time [m] (less the tilt correction)."""
        ref = np.asarray(self.reference.sample(np.asarray(times, dtype=float)), dtype=float)
        return ref - self.bias if self.estimate else ref
