"""End-effector tracking task ``h1`` (paper eq. 8-9), position and optional orientation."""

from __future__ import annotations

from collections.abc import Sequence

import casadi as ca
import numpy as np

from aeromanip.config import Table
from aeromanip.errors import ConfigError
from aeromanip.references import Reference
from aeromanip.robot.kinematics import Kinematics
from aeromanip.tasks.base import TASKS, Stage, Task

TRACKED = "xyz"  # the world coordinates tracked by default


@TASKS.register("tracking")
class EndEffectorTracking(Task):
    """``e_e = p_e(x) - p_e^d(t)`` for the ``tracked`` world coordinates [m].

    With ``orientation`` (a fixed desired rotation matrix, world frame) the residual is
    augmented by the orientation error ``vee(R_d^T R - R^T R_d) / 2`` (= sin(angle) * axis,
    dimensionless), so that the tracking of the full pose is one task as the paper allows.
    """

    name = "tracking"

    def __init__(
        self,
        reference: Reference,
        tracked: str | Sequence[str] = TRACKED,
        orientation: np.ndarray | None = None,
    ) -> None:
        self.reference = reference
        self.rows = Kinematics.tracked_rows(tracked)
        self.tracked = "".join("xyz"[r] for r in self.rows)
        self.param_size = 3
        self.orientation = None
        if orientation is not None:
            R = np.asarray(orientation, dtype=float)
            if R.shape != (3, 3) or not np.allclose(R.T @ R, np.eye(3), atol=1e-6):
                raise ConfigError("tracking.orientation: must be a 3x3 rotation matrix")
            self.orientation = R

    def residual(self, stage: Stage) -> ca.SX:
        """Position error of the tracked coordinates (and orientation error)."""
        err = stage.kin.ee_position(stage.x) - stage.params
        parts = [err[self.rows]]
        if self.orientation is not None:
            R = stage.kin.ee_rotation(stage.x)
            Rd = ca.DM(self.orientation)
            E = Rd.T @ R - R.T @ Rd
            parts.append(0.5 * ca.vertcat(E[2, 1], E[0, 2], E[1, 0]))
        return ca.vertcat(*parts)

    def param_values(self, times: np.ndarray) -> np.ndarray:
        """The reference position at each time [m]."""
        return np.asarray(self.reference.sample(np.asarray(times, dtype=float)), dtype=float)

    def param_expression(self, t: ca.SX) -> ca.SX:
        """``param_values`` at one time ``t`` [s] as a CasADi expression (3,)."""
        return self.reference.expression(t)

    @classmethod
    def from_table(cls, table: Table, reference: Reference) -> EndEffectorTracking:
        """Option: ``tracked`` (e.g. ``"yz"``); the reference is the scenario's."""
        return cls(reference, tracked=table.str("tracked", TRACKED))
