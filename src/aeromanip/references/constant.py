"""A fixed reference point."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import casadi as ca
import numpy as np

from aeromanip.config import Table
from aeromanip.errors import ConfigError
from aeromanip.references.base import REFERENCES, Reference, as_times, vec3

DURATION = 0.0  # [s] nominal run length of a constant reference


@REFERENCES.register("constant")
class Constant(Reference):
    """A fixed point [m]; ``duration`` [s] is only the nominal run length."""

    def __init__(
        self,
        point: Sequence[float] | np.ndarray,
        duration: float = DURATION,
        *,
        name: str = "reference",
    ) -> None:
        self.point = vec3(point, f"{name}.point")
        if not math.isfinite(duration) or duration < 0:
            raise ConfigError(f"{name}.duration: must be >= 0, got {duration!r}")
        self.duration = float(duration)

    def sample(self, times: np.ndarray | Sequence[float]) -> np.ndarray:
        """Reference positions [m] at ``times`` [s], shape (len(times), 3)."""
        return np.tile(self.point, (as_times(times).size, 1))

    def expression(self, t: ca.SX) -> ca.SX:
        """``sample`` at one time ``t`` [s] as a CasADi expression (3,)."""
        return ca.SX(ca.DM(self.point))

    @classmethod
    def from_table(cls, table: Table, base_dir: Path | None = None) -> Constant:
        """Keys: ``point`` [m], optional ``duration`` [s]."""
        point, duration = table.floats("point", size=3), table.float("duration", DURATION)
        return cls(point, duration, name=table.path or "reference")
