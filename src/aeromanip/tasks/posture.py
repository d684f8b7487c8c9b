"""Posture task: chosen DoFs toward a rest configuration (a common lowest-priority task).

The paper's tasks leave some motions free: with the arm CoG aligned, the platform's yaw
and the arm's pan joint can turn together or against each other without changing the
end effector or the CoG, and only the control-rate regulariser decides, so the split
drifts until a bound stops it. A small posture term at a secondary level settles such
redundancy without touching the higher levels.
"""

from __future__ import annotations

from collections.abc import Sequence

import casadi as ca

from aeromanip.config import Table
from aeromanip.errors import ConfigError
from aeromanip.references import Reference
from aeromanip.tasks.base import TASKS, Stage, Task


@TASKS.register("posture")
class Posture(Task):
    """``r = x[dofs] - target`` [m or rad]: the named state entries toward ``target``.

    Args:
        dofs: state names (``"yaw"``, ``"q1"``...); checked against the robot when the
            residual is built.
        target: one value per DoF (default 0).
    """

    name = "posture"

    def __init__(self, dofs: Sequence[str], target: Sequence[float] | None = None) -> None:
        self.dofs = [str(d) for d in dofs]
        if not self.dofs or len(set(self.dofs)) != len(self.dofs):
            raise ConfigError(f"Posture.dofs: expected distinct state names, got {list(dofs)}")
        values = [0.0] * len(self.dofs) if target is None else [float(v) for v in target]
        if len(values) != len(self.dofs):
            raise ConfigError(
                f"Posture.target: expected {len(self.dofs)} values (one per DoF), got {len(values)}"
            )
        self.target = values

    def residual(self, stage: Stage) -> ca.SX:
        """The chosen state entries minus their targets."""
        names = stage.kin.spec.state_names
        unknown = [d for d in self.dofs if d not in names]
        if unknown:
            raise ConfigError(f"posture.dofs: {unknown[0]!r} is not a state of the robot {names}")
        idx = [names.index(d) for d in self.dofs]
        return ca.vertcat(*[stage.x[i] for i in idx]) - ca.DM(self.target)

    @classmethod
    def from_table(cls, table: Table, reference: Reference) -> Posture:
        """Options: ``dofs`` (state names), ``target`` (one value each, default 0)."""
        dofs = table.raw("dofs")
        if not isinstance(dofs, list) or not all(isinstance(d, str) for d in dofs):
            raise ConfigError(f"{table.key('dofs')}: expected an array of state names")
        target = table.floats("target", [0.0] * len(dofs), size=len(dofs))
        return cls(dofs, target)
