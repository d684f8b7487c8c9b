"""The NMPC problem (tasks, weights, levels, constraints) and its multiple-shooting NLP.

Problem (paper eq. 3-4): ``x[k+1] = x[k] + dt u[k]`` over ``N`` steps, cost = weighted
task residuals. To keep every term stage-local (what structure-exploiting solvers need),
the previous command is carried in an augmented state ``z = [x; v]`` with ``v[k+1] = u[k]``
and ``v[0]`` = the applied command: the control-rate cost is then ``||u[k] - v[k]||^2`` and
the terminal control cost ``||v[N]||^2``.

The NLP is built once per problem and level, with parameters ``p = [x0, u_prev, refs]``,
and solved at every control step. Variables are ordered stage by stage
``[z0, u0, z1, u1, ..., z_N]``; constraints likewise.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import casadi as ca
import numpy as np

from aeromanip.constraints import Bounds, PathConstraint
from aeromanip.errors import ConfigError
from aeromanip.robot.kinematics import Kinematics
from aeromanip.robot.spec import RobotSpec
from aeromanip.tasks.base import Stage, Task

Weight = float | Sequence[float] | Mapping[str, float]


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
    """

    def __init__(
        self, robot: RobotSpec, horizon: int, dt: float, bounds: Bounds | None = None
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
        entry = TaskEntry(task, w, ws, level, name)
        self.entries.append(entry)
        return entry

    def add_constraint(self, constraint: PathConstraint) -> None:
        """Add a path constraint (applied at stages 1..N)."""
        self.constraints.append(constraint)

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
        if not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ConfigError(f"{path}: weights must be finite and >= 0, got {w.tolist()}")
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


class Transcription:
    """The multiple-shooting NLP of a ``Problem`` for one objective.

    Args:
        problem: the problem.
        objective: entries whose weighted residuals make the cost.
        constrained: groups of entries (higher levels) whose cost must stay within bounds
            given at solve time: per stage (``mode="stagewise"``, N+1 rows per group) or
            in total (``mode="total"``, one row per group).
        mode: ``"stagewise"`` or ``"total"``.
    """

    def __init__(
        self,
        problem: Problem,
        objective: Sequence[TaskEntry],
        constrained: Sequence[Sequence[TaskEntry]] = (),
        mode: str = "stagewise",
    ) -> None:
        if mode not in ("stagewise", "total"):
            raise ConfigError(f"hierarchy.mode: {mode!r} is not 'stagewise' or 'total'")
        self.problem = problem
        self.mode = mode
        kin, N, nx = problem.kin, problem.horizon, problem.kin.nx
        self.N, self.nx, self.nz = N, nx, 2 * nx
        self.np_stage = problem.param_size
        z = ca.SX.sym("z", 2 * nx)
        u = ca.SX.sym("u", nx)
        pk = ca.SX.sym("pk", self.np_stage)
        offsets, off = {}, 0
        for e in problem.entries:
            offsets[e.name] = (off, off + e.task.param_size)
            off += e.task.param_size

        def stage(entry: TaskEntry | None, with_u: bool) -> Stage:
            a, b = offsets[entry.name] if entry else (0, 0)
            return Stage(kin, z[:nx], u if with_u else None, z[nx:], pk[a:b], problem.dt)

        def costs(with_u: bool) -> list[ca.SX]:
            out = []
            for e in problem.entries:
                if with_u:
                    r, w = e.task.residual(stage(e, True)), e.weight
                else:
                    r, w = e.task.terminal_residual(stage(e, False)), e.terminal_weight
                out.append(ca.SX(0) if r is None else ca.dot(ca.DM(w), r * r))
            return out

        idx = {e.name: i for i, e in enumerate(problem.entries)}
        obj = [idx[e.name] for e in objective]
        groups = [[idx[e.name] for e in g] for g in constrained]
        c_stage, c_term = costs(True), costs(False)

        def pick(c: list[ca.SX], ids: list[int]) -> ca.SX:
            return sum((c[i] for i in ids), ca.SX(0))

        path_s, path_t, lo_s, hi_s, lo_t, hi_t = [], [], [], [], [], []
        for con in problem.constraints:
            e = con.expression(stage(None, True))
            path_s.append(e)
            lo_s.append(con.lower)
            hi_s.append(con.upper)
            if not con.uses_command():
                path_t.append(con.expression(stage(None, False)))
                lo_t.append(con.lower)
                hi_t.append(con.upper)
        self.f_stage = ca.Function(
            "stage",
            [z, u, pk],
            [
                pick(c_stage, obj),
                ca.vertcat(*[pick(c_stage, g) for g in groups]),
                ca.vertcat(*path_s),
                ca.vertcat(*c_stage),
            ],
        )
        self.f_term = ca.Function(
            "terminal",
            [z, pk],
            [
                pick(c_term, obj),
                ca.vertcat(*[pick(c_term, g) for g in groups]),
                ca.vertcat(*path_t),
                ca.vertcat(*c_term),
            ],
        )
        self._build(groups, lo_s, hi_s, lo_t, hi_t)

    def _build(self, groups: list, lo_s: list, hi_s: list, lo_t: list, hi_t: list) -> None:
        N, nx, nz, npk = self.N, self.nx, self.nz, self.np_stage
        b = self.problem.bounds
        dt = self.problem.dt
        Z = [ca.SX.sym(f"z{k}", nz) for k in range(N + 1)]
        U = [ca.SX.sym(f"u{k}", nx) for k in range(N)]
        x0, u_prev = ca.SX.sym("x0", nx), ca.SX.sym("u_prev", nx)
        P = ca.SX.sym("P", npk, N + 1)
        w, lbw, ubw, g, lbg, ubg = [], [], [], [], [], []
        inf_z = np.full(nz, np.inf)
        self.hier_rows: list[list[int]] = [[] for _ in groups]
        f_total, stage_costs, hier_sum = ca.SX(0), [], [ca.SX(0) for _ in groups]
        n_g = 0

        def add_g(expr: ca.SX, lo: np.ndarray, hi: np.ndarray) -> list[int]:
            nonlocal n_g
            g.append(expr)
            lbg.append(np.asarray(lo, dtype=float).ravel())
            ubg.append(np.asarray(hi, dtype=float).ravel())
            rows = list(range(n_g, n_g + expr.numel()))
            n_g += expr.numel()
            return rows

        lo_s_v = np.concatenate(lo_s) if lo_s else np.zeros(0)
        hi_s_v = np.concatenate(hi_s) if hi_s else np.zeros(0)
        for k in range(N + 1):
            w.append(Z[k])
            if k == 0:
                lbw.append(-inf_z)
                ubw.append(inf_z)
            else:
                lbw.append(np.concatenate([b.x_lower, -np.full(nx, np.inf)]))
                ubw.append(np.concatenate([b.x_upper, np.full(nx, np.inf)]))
            if k < N:
                w.append(U[k])
                lbw.append(b.u_lower)
                ubw.append(b.u_upper)
                cost, hier, path, per_task = self.f_stage(Z[k], U[k], P[:, k])
            else:
                cost, hier, path, per_task = self.f_term(Z[k], P[:, k])
            f_total += cost
            stage_costs.append(per_task)
            if k < N:  # gap-closing rows first in each stage (what fatrop detects)
                x_next = Z[k][:nx] + dt * U[k]
                add_g(Z[k + 1] - ca.vertcat(x_next, U[k]), np.zeros(nz), np.zeros(nz))
            if k > 0 and path.numel():
                if k < N:
                    add_g(path, lo_s_v, hi_s_v)
                else:
                    add_g(path, np.concatenate(lo_t), np.concatenate(hi_t))
            for j in range(len(groups)):
                if self.mode == "stagewise":
                    self.hier_rows[j] += add_g(hier[j], [-np.inf], [np.inf])
                else:
                    hier_sum[j] += hier[j]
        if self.mode == "total":
            for j in range(len(groups)):
                self.hier_rows[j] = add_g(hier_sum[j], [-np.inf], [np.inf])
        self.w = ca.vertcat(*w)
        self.p = ca.vertcat(x0, u_prev, ca.vec(P))
        self.f = f_total
        self.g = ca.vertcat(*g)
        self.lbw, self.ubw = np.concatenate(lbw), np.concatenate(ubw)
        self.lbg = np.concatenate(lbg) if lbg else np.zeros(0)
        self.ubg = np.concatenate(ubg) if ubg else np.zeros(0)
        self.equality = (self.lbg == self.ubg).tolist()
        # per task (rows) and stage (columns) weighted costs, for reports and hierarchy
        self.stage_costs = ca.Function(
            "stage_costs", [self.w, self.p], [ca.horzcat(*stage_costs)], ["w", "p"], ["C"]
        )
        self.stride = nz + nx

    def variable_bounds(self, x0: np.ndarray, u_prev: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``lbw, ubw`` with the stage-0 augmented state pinned to ``[x0, u_prev]``."""
        lbw, ubw = self.lbw.copy(), self.ubw.copy()
        lbw[: self.nz] = ubw[: self.nz] = np.concatenate([x0, u_prev])
        return lbw, ubw

    def parameters(
        self, x0: np.ndarray, u_prev: np.ndarray, stage_params: np.ndarray
    ) -> np.ndarray:
        """Pack ``p = [x0, u_prev, refs]``; ``stage_params`` is (N+1, param_size), stage-major."""
        return np.concatenate([x0, u_prev, np.asarray(stage_params, dtype=float).reshape(-1)])

    def unpack(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """States ``X`` (N+1, nx) and commands ``U`` (N, nx) from the variable vector."""
        w = np.asarray(w, dtype=float).ravel()
        N, nx, s = self.N, self.nx, self.stride
        X = np.array([w[k * s : k * s + nx] for k in range(N + 1)])
        U = np.array([w[k * s + self.nz : k * s + self.nz + nx] for k in range(N)])
        return X, U

    def pack(self, X: np.ndarray, U: np.ndarray, u_prev: np.ndarray) -> np.ndarray:
        """Variable vector for a trajectory (``v`` filled from the commands)."""
        parts = []
        V = np.vstack([u_prev, U])
        for k in range(self.N + 1):
            parts.append(X[k])
            parts.append(V[k])
            if k < self.N:
                parts.append(U[k])
        return np.concatenate(parts)
