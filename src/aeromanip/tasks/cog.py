"""Arm centre-of-gravity tasks: alignment ``h2`` (paper eq. 10) and velocity ``h3`` (eq. 11-12)."""

from __future__ import annotations

import casadi as ca

from aeromanip.config import Table
from aeromanip.errors import ConfigError
from aeromanip.references import Reference
from aeromanip.tasks.base import TASKS, Stage, Task

TARGET_XY = (0.0, 0.0)  # [m] where the arm CoG goes in the body xy plane


@TASKS.register("cog")
class CogAlignment(Task):
    """``r = p_Gxy``: the arm CoG projected on the body xy plane [m] goes to the body origin.

    ``target_xy`` moves that equilibrium point for a platform that is not internally
    balanced (paper Sec. IV-B).
    """

    name = "cog"

    def __init__(self, target_xy: tuple[float, float] = TARGET_XY) -> None:
        self.target = ca.DM(list(target_xy))

    def residual(self, stage: Stage) -> ca.SX:
        """Body-frame xy offset of the arm CoG from the target [m]."""
        return stage.kin.cog_body(stage.x)[:2] - self.target

    @classmethod
    def from_table(cls, table: Table, reference: Reference) -> CogAlignment:
        """Option: ``target_xy`` [m]."""
        x, y = table.floats("target_xy", TARGET_XY, size=2)
        return cls((x, y))


@TASKS.register("cog_velocity")
class CogVelocity(Task):
    """``r = J_Gxy(x) u``: body-frame xy velocity of the arm CoG [m/s] (eq. 12).

    Only the arm joints move the CoG in the body frame, so the joint part of ``u`` is used.
    It has no terminal term: no command exists at the terminal stage.
    """

    name = "cog_velocity"

    def residual(self, stage: Stage) -> ca.SX:
        """``J_Gxy(x) qdot``."""
        if stage.u is None:
            raise ConfigError(
                f"{type(self).__name__}.residual: needs the stage command u, got None "
                "(the terminal stage has none: use terminal_residual)"
            )
        qdot = stage.u[stage.kin.n_platform :]
        return (stage.kin.cog_jacobian(stage.x) @ qdot)[:2]

    def terminal_residual(self, stage: Stage) -> None:
        """No terminal term (see class docstring)."""
        return None
