"""The NMPC problem: robot, horizon, tasks with weights and levels, constraints.

Problem (paper eq. 3-4): ``x[k+1] = x[k] + dt u[k]`` over ``N`` steps (or, with rate
responses, the model of ``nmpc.model``), cost = weighted task residuals, under bounds
and path constraints. It only describes what to optimise;
``nmpc.transcription`` turns it into an NLP per hierarchy level, built once and solved at
every control step.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.nmpc.constraints import Bounds, PathConstraint
from aeromanip.nmpc.model import RateModel
from aeromanip.robot.kinematics import Kinematics
from aeromanip.robot.spec import RobotSpec
from aeromanip.tasks.base import Task

Weight = float | Sequence[float] | Mapping[str, float]
MAX_WEIGHT = 1e9  # larger weights only wreck the NLP's scaling


@dataclass
class TaskEntry:
    """A task placed in a problem: its weights and priority level.

    ``level`` 0 is the highest priority. ``level=None`` marks a regulariser (typically the
    control rate): part of every level's objective, never turned into a hierarchy constraint.
    """

    task: Task
    weight: np.ndarray
    terminal_weight: np.ndarray
    level: int | None
    name: str


class Problem:
    """What to optimise: robot, horizon, tasks with weights and levels, constraints.

    Args:
        robot: the UAM description.
        horizon: number of steps ``N``.
        dt: step ``Ts`` [s].
        bounds: state/command bounds; default: the robot's joint and velocity limits.
        response_tau: per DoF, the time constant of its rate response [s] (``RateModel``;
            ``None``: the paper's model, rates followed at once).
        weights_dt: the control period [s] the weights were tuned at: at another ``dt``
            each stage weight is rescaled (``Task.time_scaling``) so that the cost stays
            the same time integral (``None``: weights taken as they are).
    """

    def __init__(
        self,
        robot: RobotSpec,
        horizon: int,
        dt: float,
        bounds: Bounds | None = None,
        response_tau: np.ndarray | None = None,
        weights_dt: float | None = None,
    ) -> None:
        if isinstance(horizon, bool) or not isinstance(horizon, int) or horizon < 1:
            raise ConfigError(f"horizon: must be an integer >= 1, got {horizon!r}")
        if not (dt > 0 and np.isfinite(dt)):
            raise ConfigError(f"dt: must be a finite number > 0, got {dt!r}")
        self.robot = robot
        self.kin = Kinematics(robot)
        self.horizon = horizon
        self.dt = float(dt)
        self.bounds = bounds if bounds is not None else Bounds.from_robot(robot)
        if self.bounds.names != robot.state_names:
            raise ConfigError(f"bounds: names {self.bounds.names} != state {robot.state_names}")
        self.model = RateModel(robot.nx, self.dt, response_tau)
        if weights_dt is not None and not (weights_dt > 0 and np.isfinite(weights_dt)):
            raise ConfigError(f"weights_dt: must be a finite number > 0, got {weights_dt!r}")
        self.weights_dt = weights_dt
        self.entries: list[TaskEntry] = []
        self.constraints: list[PathConstraint] = []

    def add_task(
        self,
        task: Task,
        weight: Weight = 1.0,
        terminal_weight: Weight | None = None,
        level: int | None = 0,
        name: str | None = None,
    ) -> TaskEntry:
        """Add ``task`` with diagonal weight ``W`` and terminal weight ``W_s`` at ``level``.

        A weight is a scalar, one value per residual entry, or (for residuals of state
        size such as the control rate) a mapping from state names (``"x"``, ``"q1"``...)
        to values, unnamed entries taking ``weight.get("default", 0)``. ``terminal_weight``
        defaults to ``weight``.
        """
        name = name or task.name
        if any(e.name == name for e in self.entries):
            raise ConfigError(f"tasks.{name}: a task of this name is already in the problem")
        if level is not None and (
            isinstance(level, bool) or not isinstance(level, int) or level < 0
        ):
            raise ConfigError(f"tasks.{name}.level: must be an integer >= 0, got {level!r}")
        size = task.residual_size(self.kin)
        w = self._weight(weight, size, f"tasks.{name}.weight")
        ws = (
            w
            if terminal_weight is None
            else self._weight(terminal_weight, size, f"tasks.{name}.terminal_weight")
        )
        entry = TaskEntry(task, w * self._time_scale(task, f"tasks.{name}"), ws, level, name)
        self.entries.append(entry)
        return entry

    def add_constraint(self, constraint: PathConstraint) -> None:
        """Add a path constraint (applied at stages 1..N)."""
        self.constraints.append(constraint)

    def _time_scale(self, task: Task, path: str) -> float:
        """The factor on the task's stage weight for ``weights_dt`` (terminal: none)."""
        if self.weights_dt is None:
            return 1.0
        s = self.dt / self.weights_dt
        if task.time_scaling == "integral":
            return s
        if task.time_scaling == "difference":
            return 1.0 / s
        raise ConfigError(
            f"{path}: time_scaling {task.time_scaling!r} is not 'integral' or 'difference'"
        )

    def _weight(self, weight: Weight, size: int, path: str) -> np.ndarray:
        if isinstance(weight, Mapping):
            names = self.robot.state_names
            if size != len(names):
                raise ConfigError(f"{path}: named weights need a residual of state size")
            unknown = set(weight) - set(names) - {"default"}
            if unknown:
                raise ConfigError(f"{path}.{sorted(unknown)[0]}: unknown DoF (use {list(names)})")
            w = np.array([float(weight.get(n, weight.get("default", 0.0))) for n in names])
        else:
            w = (
                np.broadcast_to(np.asarray(weight, dtype=float), (size,)).copy()
                if np.ndim(weight) == 0
                else np.asarray(weight, dtype=float)
            )
            if w.shape != (size,):
                raise ConfigError(f"{path}: expected 1 or {size} values, got {w.size}")
        if not np.all(np.isfinite(w)) or np.any(w < 0) or np.any(w > MAX_WEIGHT):
            raise ConfigError(f"{path}: weights must be in [0, {MAX_WEIGHT:g}], got {w.tolist()}")
        return w

    @property
    def levels(self) -> list[int]:
        """Priority levels in use, highest priority first."""
        return sorted({e.level for e in self.entries if e.level is not None})

    @property
    def param_size(self) -> int:
        """Stage parameters per stage (all tasks' references, concatenated)."""
        return sum(e.task.param_size for e in self.entries)

    def stage_params(self, t: float) -> np.ndarray:
        """Every task's parameters at the stage times ``t + k dt``: (N+1, param_size)."""
        times = t + self.dt * np.arange(self.horizon + 1)
        cols = [e.task.param_values(times) for e in self.entries if e.task.param_size]
        if not cols:
            return np.zeros((self.horizon + 1, 0))
        return np.hstack([np.asarray(c, dtype=float).reshape(len(times), -1) for c in cols])

    def reset_tasks(self) -> None:
        """Every task forgets what it measured (a new run)."""
        for e in self.entries:
            e.task.reset()

    def ee_of(self, x: np.ndarray) -> np.ndarray:
        """The EE position [m, world] of a state (numbers)."""
        return np.asarray(self.kin.ee_position(ca.DM(np.asarray(x, dtype=float)))).ravel()

    def observe(
        self,
        x: np.ndarray,
        wrench: np.ndarray | None,
        t: float,
        attitude: tuple[float, float] | None = None,
    ) -> None:
        """Hand this step's measured state, wrist wrench and (if measured) the platform's
        ``(roll, pitch)`` [rad] to every task (``Task.observe``)."""
        users = self.overriding("observe")
        if not users:  # nothing to compute (the step's time is the solver's)
            return
        ee = self.ee_of(x)
        tilted = None if attitude is None else self.ee_tilted(x, ee, *attitude)
        for task in users:
            task.observe(ee, wrench, t, tilted)

    def overriding(self, method: str) -> list[Task]:
        """The tasks that override ``Task.<method>`` (the others do nothing there)."""
        return [
            e.task
            for e in self.entries
            if getattr(type(e.task), method) is not getattr(Task, method)
        ]

    def ee_tilted(self, x: np.ndarray, ee: np.ndarray, roll: float, pitch: float) -> np.ndarray:
        """The EE position [m, world] of state ``x`` (whose EE is ``ee``) with the platform
        also rolled and pitched (ZYX angles [rad]): its arm swings with the base."""
        names = self.robot.state_names
        fixed_yaw = float(self.robot.platform.fixed.get("yaw", 0.0))
        yaw = float(x[names.index("yaw")]) if "yaw" in names else fixed_yaw
        body = np.asarray(self.kin.ee_position_body(ca.DM(np.asarray(x, dtype=float)))).ravel()
        cy, sy = np.cos(yaw), np.sin(yaw)
        rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        cp, sp, cr, sr = np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
        ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
        rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
        return ee + rz @ (ry @ rx - np.eye(3)) @ body

    def observations(self, t: float) -> dict[str, float]:
        """Every task's logged values; a name two tasks share is prefixed ``<task>_``."""
        out: dict[str, float] = {}
        for e in self.entries:
            for key, value in e.task.observations(t).items():
                out[f"{e.name}_{key}" if key in out else key] = value
        return out

    def force_feedforward(self, x_now: np.ndarray, x_next: np.ndarray) -> np.ndarray | None:
        """The thrust feed-forward of every task [N, world] (sum), given the plan's first
        two states; ``None`` when no task asks for one."""
        users = self.overriding("force_feedforward")
        if not users:
            return None
        ee_now, ee_next = self.ee_of(x_now), self.ee_of(x_next)
        forces = [
            f
            for task in users
            if (f := task.force_feedforward(ee_now, ee_next, self.dt)) is not None
        ]
        return None if not forces else np.sum(forces, axis=0)
