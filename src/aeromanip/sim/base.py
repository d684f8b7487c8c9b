"""The simulator interface the closed loop talks to.

A simulator stands in for the robot and its inner loops: it receives the NMPC's command
(rates ``u`` and the predicted plan) once per control period and reports the state the
NMPC sees next. The kinematic simulator assumes a perfect inner loop (paper Sec. III-C);
the physics simulator flies the full dynamics with a flight controller.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import Any

import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.registry import Registry
from aeromanip.robot.spec import RobotSpec

GRAVITY = 9.81  # [m/s^2] the simulated world's gravity (along -z, world ENU)


class Simulator(ABC):
    """One verb per control period: ``advance(u, plan_x, dt)``.

    Simulators are registered by name in ``SIMULATORS`` (one module each); a scenario's
    ``sim`` names one, or a subclass of your own as ``"package.module:Class"``.
    """

    kind: str = "simulator"
    #: the scenario table holding this simulator's options (``None``: it takes none)
    options_table: str | None = None

    @classmethod
    def check_options(cls, options: Mapping[str, Any]) -> dict[str, Any]:
        """The options checked without building anything (``ConfigError`` naming the
        key); by default a simulator takes none."""
        if options:
            raise ConfigError(f"{cls.kind}: takes no options, got {sorted(options)}")
        return {}

    @classmethod
    def from_options(cls, spec: RobotSpec, options: Mapping[str, Any]) -> Simulator:
        """Build for ``spec`` from its options table (see ``options_table``)."""
        if options:
            raise ConfigError(f"{cls.kind}: takes no options, got {sorted(options)}")
        return cls(spec)  # type: ignore[call-arg]

    #: keys of ``extras()`` that are values at the current instant (the others are means
    #: over the period the last ``advance`` flew)
    instant_extras: tuple[str, ...] = ()

    @abstractmethod
    def reset(self, x0: np.ndarray) -> None:
        """Start at NMPC state ``x0`` = [platform DoFs, q] at rest."""

    @abstractmethod
    def advance(self, u: np.ndarray, plan_x: np.ndarray, dt: float) -> None:
        """Apply command ``u`` (dx/dt) over ``dt`` [s]; ``plan_x`` (N+1, nx) is the plan."""

    def measured_attitude(self) -> tuple[float, float] | None:
        """The platform's measured ``(roll, pitch)`` [rad] now; ``None``: not simulated."""
        return None

    def set_force_feedforward(self, force: np.ndarray) -> None:
        """The thrust [N, world] the flight controller adds to its position loop's from
        now on (an acceleration feed-forward, as PX4's offboard setpoints carry); a
        simulator without a flight controller ignores it."""
        return None

    @abstractmethod
    def state(self) -> np.ndarray:
        """The NMPC state as measured now (possibly noisy)."""

    def true_state(self) -> np.ndarray:
        """The NMPC state without measurement noise (what the run log records)."""
        return self.state()

    def rates(self) -> np.ndarray | None:
        """The actual rates ``dx/dt`` now [m/s, rad/s] (the physics simulator's are exact,
        without noise); ``None``: not measured (a controller then takes its last command
        as followed)."""
        return None

    #: the simulator's time step [s] (commands and latencies must be whole multiples of
    #: it), from its options; ``None``: any duration
    @classmethod
    def time_step(cls, options: Mapping[str, Any]) -> float | None:
        """The time step ``options`` give [s] (see above); by default none."""
        return None

    def ee_position(self) -> np.ndarray | None:
        """The physical end-effector position [m], world frame, if it differs from the
        kinematic model's (e.g. tilted platform in physics); ``None`` otherwise."""
        return None

    def measured_wrench(self) -> np.ndarray | None:
        """The end effector's force/torque sensor reading now ``[f, tau]`` [N, N m], world
        frame, as the controller would receive it; ``None``: no sensor."""
        return None

    def extras(self) -> dict[str, float]:
        """Extra logged quantities (e.g. ``roll``, ``pitch`` in physics); none by default."""
        return {}


SIMULATORS: Registry[Simulator] = Registry("simulator", "aeromanip.sim", Simulator)
