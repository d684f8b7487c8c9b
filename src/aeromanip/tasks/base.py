"""Task base class: a residual of the state, command and stage parameters.

A task's cost at stage ``k`` is ``||r_k||^2_W`` with ``W`` given where tasks are combined
(``Problem.add_task``), not inside the task (as in Crocoddyl). Terminal stage ``N`` uses
``terminal_residual`` (no command exists there) with the terminal weight ``W_s``.
Residuals are built symbolically from the kinematics Functions, once per problem.

Tasks are registered by name in ``TASKS`` (one module each); a scenario's
``[tasks.NAME] kind = ...`` names one, or a ``Task`` subclass of your own as
``"package.module:Class"``, built by its ``from_table`` (by default from the
constructor's keyword parameters: ``aeromanip.tasks.options``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import casadi as ca
import numpy as np

from aeromanip.config import Table
from aeromanip.errors import ConfigError
from aeromanip.references import Reference
from aeromanip.registry import Registry
from aeromanip.robot.kinematics import Kinematics
from aeromanip.tasks.options import constructor_options


@dataclass(frozen=True)
class Stage:
    """Symbols available to a residual at one stage of the horizon.

    Attributes:
        kin: the robot's kinematics.
        x: state ``[platform DoFs, q]`` (nx x 1).
        u: command ``dx/dt`` (nx x 1); ``None`` at the terminal stage.
        u_prev: the command of the previous stage (the applied one for stage 0) (nx x 1).
        params: this task's stage parameters (``param_size`` x 1), e.g. the reference.
        dt: control period [s].
    """

    kin: Kinematics
    x: ca.SX
    u: ca.SX | None
    u_prev: ca.SX
    params: ca.SX
    dt: float


class Task(ABC):
    """A cost term ``||r||^2_W``. Subclass and implement ``residual``.

    Attributes:
        name: short identifier used in logs and per-task cost reports.
        time_scaling: ``"integral"`` or ``"difference"`` (see the attribute).
        param_size: number of time-varying parameters per stage (e.g. 3 for a position
            reference); their values come from ``param_values`` at every controller step.
    """

    name: str = "task"
    param_size: int = 0
    #: how the stage weight follows the control period ``dt`` when the weights were tuned
    #: at another one (``Problem(weights_dt=...)``): ``"integral"``, a cost per unit time
    #: (times ``dt / weights_dt``); ``"difference"``, a change over one step such as the
    #: control rate's ``u_k - u_{k-1}`` (times ``weights_dt / dt``, the time integral of
    #: the squared acceleration staying the same)
    time_scaling: str = "integral"

    def residual_size(self, kin: Kinematics) -> int:
        """Length of the residual vector (the weight has this many entries)."""
        x = ca.SX.sym("x", kin.nx)
        u = ca.SX.sym("u", kin.nx)
        stage = Stage(kin, x, u, u, ca.SX.sym("p", self.param_size), 1.0)
        return int(self.residual(stage).numel())

    @abstractmethod
    def residual(self, stage: Stage) -> ca.SX:
        """Stage residual ``r(x_k, u_k, p_k)`` (a column vector)."""

    def terminal_residual(self, stage: Stage) -> ca.SX | None:
        """Terminal residual ``r(x_N, p_N)``; ``None`` if the task has no terminal term.

        By default the stage residual evaluated without a command, when it needs none.
        """
        return self.residual(stage)

    def param_values(self, times: np.ndarray) -> np.ndarray:
        """Stage parameters at absolute ``times`` [s]: array (len(times), param_size)."""
        return np.zeros((len(times), self.param_size))

    def param_expression(self, t: ca.SX) -> ca.SX:
        """``param_values`` at one time ``t`` [s] as a CasADi expression (param_size,):
        what a controller exported to C computes (``aeromanip export``). A task whose
        parameters come from elsewhere (measurements) has none and cannot be exported."""
        if type(self).param_values is Task.param_values:
            return ca.SX.zeros(self.param_size)
        raise ConfigError(
            f"tasks.{self.name}: its parameters are not a function of time alone; "
            "a controller with it cannot be exported to C"
        )

    # Measurements: a task may use what is measured each control step beside the state
    # (the wrist force/torque sensor); by default it uses none.

    def reset(self) -> None:
        """Forget what was measured (a new run)."""
        return None

    def observe(
        self,
        ee: np.ndarray,
        wrench: np.ndarray | None,
        t: float,
        ee_tilted: np.ndarray | None = None,
    ) -> None:
        """This step's measurements at ``t`` [s], before the solve: ``ee``, the EE position
        of the measured state [m, world] (the NMPC's kinematics: no roll, pitch); the wrist
        wrench ``[f, tau]`` [N, N m, world] (``None``: no sensor); ``ee_tilted``, the EE
        with the measured roll and pitch too (``None``: not measured)."""
        return None

    def observations(self, t: float) -> dict[str, float]:
        """Values to log each step (name: value); the keys are the same every step."""
        return {}

    def force_feedforward(
        self, ee_now: np.ndarray, ee_next: np.ndarray, dt: float
    ) -> np.ndarray | None:
        """The thrust [N, world] the flight controller should add for this task, given the
        plan's EE position now and one step ``dt`` [s] later [m]; ``None``: none."""
        return None

    @classmethod
    def from_table(cls, table: Table, reference: Reference) -> Task:
        """Build from a scenario's ``[tasks.NAME]`` table (its own options only: the
        weights and level are read by the scenario). ``reference`` is the scenario's
        end-effector reference. By default the table's keys are the constructor's keyword
        parameters, checked against their annotations (``aeromanip.tasks.options``)."""
        return cls(**constructor_options(cls, table, reference))


TASKS: Registry[Task] = Registry("task", "aeromanip.tasks", Task)
