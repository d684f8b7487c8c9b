"""Ideal inner loop (paper Sec. III-C): the state integrates the command exactly."""

from __future__ import annotations

import numpy as np

from aeromanip.errors import StateError
from aeromanip.robot.spec import RobotSpec
from aeromanip.sim.base import SIMULATORS, Simulator


@SIMULATORS.register("kinematic")
class KinematicSimulator(Simulator):
    """``x <- x + dt u``: the NMPC model itself, a perfect tracking inner loop."""

    def __init__(self, spec: RobotSpec) -> None:
        self.spec = spec
        self.nx = nx = spec.nx
        self.x = np.zeros(nx)

    def reset(self, x0: np.ndarray) -> None:
        """Start at ``x0``."""
        x0 = np.asarray(x0, dtype=float).ravel()
        if x0.shape != (self.nx,) or not np.all(np.isfinite(x0)):
            raise StateError(f"initial state: expected {self.nx} finite values, got {x0}")
        self.x = x0.copy()
        self.u = np.zeros(self.nx)

    def advance(self, u: np.ndarray, plan_x: np.ndarray, dt: float) -> None:
        """Integrate the constant command over ``dt`` [s]."""
        self.u = np.asarray(u, dtype=float).copy()
        self.x = self.x + dt * self.u

    def rates(self) -> np.ndarray:
        """The last command: followed at once."""
        return self.u.copy()

    def state(self) -> np.ndarray:
        """The exact state."""
        return self.x.copy()
