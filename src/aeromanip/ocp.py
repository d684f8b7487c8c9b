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
MODES = ("stagewise", "total", "residual")  # how a hierarchy level keeps higher optima


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


def shift_map(rows: Sequence[tuple[str, int]]) -> np.ndarray:
    """For rows given as ``(kind, stage)``, in order: the index of each row's twin one
    stage on (the same kind, the same place among that kind's rows of its stage), or the
    row itself where there is none or the stage is negative (rows coupling every stage)."""
    place: dict[tuple[str, int, int], int] = {}
    count: dict[tuple[str, int], int] = {}
    keys = []
    for r, (kind, stage) in enumerate(rows):
        j = count.get((kind, stage), 0)
        count[(kind, stage)] = j + 1
        keys.append((kind, stage, j))
        place[(kind, stage, j)] = r
    return np.array(
        [r if st < 0 else place.get((kd, st + 1, j), r) for r, (kd, st, j) in enumerate(keys)],
        dtype=int,
    )


class Transcription:
    """The multiple-shooting NLP of a ``Problem`` for one objective.

    Args:
        problem: the problem.
        objective: entries whose weighted residuals make the cost.
        constrained: groups of entries (higher levels) whose cost must stay within bounds
            given at solve time: per stage (``mode="stagewise"``, N+1 rows per group), in
            total (``mode="total"``, one row per group), or their weighted residual vectors
            per stage (``mode="residual"``, one row per residual entry and stage).
        mode: ``"stagewise"``, ``"total"`` or ``"residual"``.
    """

    def __init__(
        self,
        problem: Problem,
        objective: Sequence[TaskEntry],
        constrained: Sequence[Sequence[TaskEntry]] = (),
        mode: str = "stagewise",
    ) -> None:
        if mode not in MODES:
            raise ConfigError(f"hierarchy.mode: {mode!r} is not one of {MODES}")
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

        def residuals(with_u: bool) -> list[ca.SX]:
            """Weighted residuals ``sqrt(W) r`` per task (cost = their squared norm)."""
            out = []
            for e in problem.entries:
                if with_u:
                    r, w = e.task.residual(stage(e, True)), e.weight
                else:
                    r, w = e.task.terminal_residual(stage(e, False)), e.terminal_weight
                out.append(ca.SX(0, 1) if r is None else ca.sqrt(ca.DM(w)) * ca.vec(r))
            return out

        idx = {e.name: i for i, e in enumerate(problem.entries)}
        obj = [idx[e.name] for e in objective]
        groups = [[idx[e.name] for e in g] for g in constrained]
        r_stage, r_term = residuals(True), residuals(False)
        c_stage = [ca.sumsqr(r) for r in r_stage]
        c_term = [ca.sumsqr(r) for r in r_term]

        def pick(c: list[ca.SX], ids: list[int]) -> ca.SX:
            return sum((c[i] for i in ids), ca.SX(0))

        def stack(r: list[ca.SX], ids: list[int]) -> ca.SX:
            return ca.vertcat(*[r[i] for i in ids]) if ids else ca.SX(0, 1)

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
        # Gauss-Newton data: the objective's and each constrained group's weighted residuals
        self.r_stage = ca.Function(
            "stage_residuals",
            [z, u, pk],
            [stack(r_stage, obj), *[stack(r_stage, g) for g in groups]],
        )
        self.r_term = ca.Function(
            "terminal_residuals", [z, pk], [stack(r_term, obj), *[stack(r_term, g) for g in groups]]
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
        res_obj: list[ca.SX] = []
        res_hier: list[list[ca.SX]] = [[] for _ in groups]  # per group, per stage
        #: (row of g, weighted residuals whose squared norm that hierarchy row is)
        self.hier_residuals: list[tuple[int, ca.SX]] = []
        self.stage_ng: list[int] = []  # rows per stage besides the gap-closing ones
        self.gap_rows: list[int] = []  # the rows z[k+1] = f(z[k], u[k])
        n_g = 0

        def add_g(expr: ca.SX, lo: np.ndarray, hi: np.ndarray, kind: str) -> list[int]:
            nonlocal n_g
            g.append(expr)
            lbg.append(np.asarray(lo, dtype=float).ravel())
            ubg.append(np.asarray(hi, dtype=float).ravel())
            rows = list(range(n_g, n_g + expr.numel()))
            n_g += expr.numel()
            self.g_stage += [stage_of_rows] * len(rows)
            self.g_kind += [kind] * len(rows)
            return rows

        lo_s_v = np.concatenate(lo_s) if lo_s else np.zeros(0)
        hi_s_v = np.concatenate(hi_s) if hi_s else np.zeros(0)
        #: the stage each row of g belongs to (-1: couples every stage), and its kind:
        #: "gap" (z[k+1] = f(z[k], u[k])), "path", "terminal", "hier<j>" (level j's bound)
        self.g_stage: list[int] = []
        self.g_kind: list[str] = []
        stage_of_rows = 0
        for k in range(N + 1):
            stage_of_rows = k
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
                res = self.r_stage(Z[k], U[k], P[:, k])
            else:
                cost, hier, path, per_task = self.f_term(Z[k], P[:, k])
                res = self.r_term(Z[k], P[:, k])
            res = res if isinstance(res, tuple | list) else [res]
            res_obj.append(res[0])
            n_stage_start = n_g
            f_total += cost
            stage_costs.append(per_task)
            if k < N:  # gap-closing rows first in each stage (what fatrop detects)
                x_next = Z[k][:nx] + dt * U[k]
                self.gap_rows += add_g(
                    Z[k + 1] - ca.vertcat(x_next, U[k]), np.zeros(nz), np.zeros(nz), "gap"
                )
            if k > 0 and path.numel():
                if k < N:
                    add_g(path, lo_s_v, hi_s_v, "path")
                else:
                    add_g(path, np.concatenate(lo_t), np.concatenate(hi_t), "terminal")
            for j in range(len(groups)):
                if self.mode == "stagewise":
                    rows = add_g(hier[j], [-np.inf], [np.inf], f"hier{j}")
                    self.hier_rows[j] += rows
                    self.hier_residuals.append((rows[0], res[1 + j]))
                elif self.mode == "residual":  # linear in the residuals: no curvature term
                    n_r = res[1 + j].numel()
                    self.hier_rows[j] += add_g(
                        res[1 + j], -np.full(n_r, np.inf), np.full(n_r, np.inf), f"hier{j}"
                    )
                else:
                    hier_sum[j] += hier[j]
                    res_hier[j].append(res[1 + j])
            self.stage_ng.append(n_g - n_stage_start - (nz if k < N else 0))
        if self.mode == "total":
            for j in range(len(groups)):
                stage_of_rows = -1
                self.hier_rows[j] = add_g(hier_sum[j], [-np.inf], [np.inf], f"hier{j}")
                self.hier_residuals.append((self.hier_rows[j][0], ca.vertcat(*res_hier[j])))
            self.stage_ng = []  # not stage-wise: the last row couples every stage
        self.w = ca.vertcat(*w)
        #: stacked weighted objective residuals (f = ||residuals||^2)
        self.residuals = ca.vertcat(*res_obj)
        self.p = ca.vertcat(x0, u_prev, ca.vec(P))
        self.f = f_total
        self.g = ca.vertcat(*g)
        self.lbw, self.ubw = np.concatenate(lbw), np.concatenate(ubw)
        self.lbg = np.concatenate(lbg) if lbg else np.zeros(0)
        self.ubg = np.concatenate(ubg) if ubg else np.zeros(0)
        self.equality = (self.lbg == self.ubg).tolist()
        # per task (rows) and stage (columns) weighted costs, for reports and hierarchy
        self.stage_costs = ca.Function(
            "stage_costs",
            [self.w, self.p],
            [ca.densify(ca.horzcat(*stage_costs))],
            ["w", "p"],
            ["C"],
        )
        self.stride = s = nz + nx
        k = np.arange(N + 1)[:, None] * s
        #: where X (N+1, nx), V (N+1, nx) and U (N, nx) sit in the variable vector
        self.index_x = k + np.arange(nx)
        self.index_v = k + nx + np.arange(nx)
        self.index_u = k[:N] + nz + np.arange(nx)
        # the multipliers of the next control step, predicted: ``lam[shift]`` gives each
        # row (variable) of stage k the one of the same kind and place in stage k+1; rows
        # without such a twin (the last stage's, terminal and coupling rows) keep theirs
        nw = self.w.numel()
        self.shift_w = np.arange(nw) + s
        self.shift_w[self.shift_w >= nw] -= s
        self.shift_g = shift_map(list(zip(self.g_kind, self.g_stage, strict=True)))

    def use_stage_costs(self, f: ca.Function) -> None:
        """Evaluate ``stage_costs`` (and ``costs``) with ``f``, e.g. its compiled twin."""
        self.stage_costs = f
        self._costs_buf = None

    def costs(self, w: np.ndarray, p: np.ndarray) -> np.ndarray:
        """``stage_costs(w, p)`` as an array (tasks x stages), without conversions."""
        if getattr(self, "_costs_buf", None) is None:
            f = self.stage_costs
            buf, run = f.buffer()
            args = [np.zeros(f.nnz_in(i)) for i in range(2)]
            out = np.zeros(f.nnz_out(0))
            for i, a in enumerate(args):
                buf.set_arg(i, memoryview(a))
            buf.set_res(0, memoryview(out))
            self._costs_buf = (buf, run, args, out, f.size_out(0), f.sparsity_out(0).is_dense())
        buf, run, args, out, shape, dense = self._costs_buf
        if not dense:
            return np.asarray(self.stage_costs(w, p))
        args[0][:] = w
        args[1][:] = p
        run()
        return out.reshape(shape, order="F").copy()

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
        return w[self.index_x], w[self.index_u]

    def pack(self, X: np.ndarray, U: np.ndarray, u_prev: np.ndarray) -> np.ndarray:
        """Variable vector for a trajectory (``v`` filled from the commands)."""
        w = np.empty(self.stride * self.N + self.nz)
        w[self.index_x] = X
        w[self.index_u] = U
        w[self.index_v[0]] = u_prev
        w[self.index_v[1:]] = U
        return w
