"""The multiple-shooting NLP of a ``Problem`` for one objective (one hierarchy level).

To keep every term stage-local (what structure-exploiting solvers need), the previous
command is carried in an augmented state ``z = [x; v]`` with ``v[k+1] = u[k]`` and
``v[0]`` = the applied command: the control-rate cost is then ``||u[k] - v[k]||^2``, the
terminal control cost ``||v[N]||^2`` and the command-rate bounds ``|u[k] - v[k]| <= a dt``.
With rate responses (``nmpc.model``) the actual rates ride along: ``z = [x; v; r]``.

Variables are ordered stage by stage ``[z0, u0, z1, u1, ..., z_N]``; constraint rows
likewise, each stage's gap-closing rows first (what fatrop's structure detection needs),
then path, hierarchy and command-rate rows. The NLP's parameters are ``p = [z0, refs]``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.nmpc.constraints import PathRows
from aeromanip.nmpc.problem import Problem, TaskEntry
from aeromanip.tasks.base import Stage

# how a hierarchy level keeps the higher levels at their optima: "strict" pins their
# weighted residual vectors (the others bound their costs, relaxed by tolerances)
MODES = ("strict", "stagewise", "total", "residual")
RESIDUAL_ROWS = ("strict", "residual")  # modes whose rows are the residuals themselves
COUPLING = -1  # the stage of a row that couples every stage (mode "total")


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


@dataclass
class RowBook:
    """The constraint rows ``g`` of an NLP, as they are added: expressions, bounds, and
    per row its kind (``"gap"``, ``"path"``, ``"terminal"``, ``"accel"``, ``"hier<j>"``) and
    stage."""

    exprs: list[ca.SX] = field(default_factory=list)
    lower: list[np.ndarray] = field(default_factory=list)
    upper: list[np.ndarray] = field(default_factory=list)
    kind: list[str] = field(default_factory=list)
    stage: list[int] = field(default_factory=list)

    def add(self, expr: ca.SX, lo: np.ndarray, hi: np.ndarray, kind: str, stage: int) -> list[int]:
        """Append rows; return their indices in ``g``."""
        start, n = len(self.kind), expr.numel()
        self.exprs.append(expr)
        self.lower.append(np.broadcast_to(np.asarray(lo, dtype=float).ravel(), (n,)))
        self.upper.append(np.broadcast_to(np.asarray(hi, dtype=float).ravel(), (n,)))
        self.kind += [kind] * n
        self.stage += [stage] * n
        return list(range(start, start + n))


@dataclass
class StageModel:
    """Stage and terminal Functions of one objective and its constrained groups.

    ``cost(z, u, pk) -> (objective cost, each group's cost, path rows, each task's cost)``;
    ``residuals(z, u, pk) -> (objective residuals, each group's residuals)`` (weighted:
    the costs are their squared norms); ``terminal_*`` the same of ``(z, pk)``;
    ``accel(z, u)``: the command-rate rows ``u - v`` of the bounded DoFs, within
    ``accel_bounds`` (``None`` without command-rate bounds).
    """

    cost: ca.Function
    terminal_cost: ca.Function
    residuals: ca.Function
    terminal_residuals: ca.Function
    path: PathRows
    terminal_path: PathRows
    accel: ca.Function | None = None
    accel_bounds: tuple[np.ndarray, np.ndarray] | None = None


def _stage_model(
    problem: Problem, objective: list[int], groups: list[list[int]], regularizer_scale: float
) -> StageModel:
    """Build the stage and terminal Functions (see ``StageModel``); the regularisers'
    weights times ``regularizer_scale``."""
    kin, nx = problem.kin, problem.kin.nx
    z, u = ca.SX.sym("z", problem.model.nz), ca.SX.sym("u", nx)
    pk = ca.SX.sym("pk", problem.param_size)
    offsets = np.cumsum([0] + [e.task.param_size for e in problem.entries])

    def stage(i: int | None, with_u: bool) -> Stage:
        a, b = (offsets[i], offsets[i + 1]) if i is not None else (0, 0)
        return Stage(kin, z[:nx], u if with_u else None, z[nx : 2 * nx], pk[a:b], problem.dt)

    def weighted(with_u: bool) -> list[ca.SX]:
        """``sqrt(W) r`` per task (its cost is the squared norm)."""
        out = []
        for i, e in enumerate(problem.entries):
            task, st = e.task, stage(i, with_u)
            r = task.residual(st) if with_u else task.terminal_residual(st)
            w = e.weight if with_u else e.terminal_weight
            w = w * regularizer_scale if e.level is None else w
            out.append(ca.SX(0, 1) if r is None else ca.sqrt(ca.DM(w)) * ca.vec(r))
        return out

    def pick(c: list[ca.SX], ids: list[int]) -> ca.SX:
        return sum((c[i] for i in ids), ca.SX(0))

    def stack(r: list[ca.SX], ids: list[int]) -> ca.SX:
        return ca.vertcat(*[r[i] for i in ids])  # none: 0 x 1

    def functions(name: str, args: list[ca.SX], r: list[ca.SX], path: PathRows) -> tuple:
        c = [ca.sumsqr(ri) for ri in r]
        costs = [pick(c, objective), ca.vertcat(*[pick(c, g) for g in groups])]
        cost = ca.Function(name, args, [*costs, path.expr, ca.vertcat(*c)])
        res = [stack(r, objective), *[stack(r, g) for g in groups]]
        return cost, ca.Function(f"{name}_residuals", args, res)

    path = _path_rows(problem, stage(None, True), with_u=True)
    terminal_path = _path_rows(problem, stage(None, False), with_u=False)
    cost, residuals = functions("stage", [z, u, pk], weighted(True), path)
    terminal_cost, terminal_residuals = functions(
        "terminal", [z, pk], weighted(False), terminal_path
    )
    model = StageModel(cost, terminal_cost, residuals, terminal_residuals, path, terminal_path)
    limits = problem.bounds.accel_limits
    if limits is not None:  # |u - v| <= a dt on the bounded DoFs
        dofs = np.flatnonzero(np.isfinite(limits))
        model.accel = ca.Function("accel", [z, u], [(u - z[nx : 2 * nx])[dofs.tolist()]])
        model.accel_bounds = (-limits[dofs] * problem.dt, limits[dofs] * problem.dt)
    return model


def _path_rows(problem: Problem, stage: Stage, with_u: bool) -> PathRows:
    """Every path constraint's rows at a stage (at the terminal one, those without ``u``)."""
    parts = [c.expression(stage) for c in problem.constraints if with_u or not c.uses_command()]
    if not parts:
        return PathRows(ca.SX(0, 1), np.zeros(0), np.zeros(0))
    return PathRows(
        ca.vertcat(*[p.expr for p in parts]),
        np.concatenate([p.lower for p in parts]),
        np.concatenate([p.upper for p in parts]),
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
        regularizer_scale: the factor on the regularisers' (``level=None``) weights in
            this objective (a higher hierarchy level's, ``strategies.REGULARIZER_SCALE``).

    Attributes:
        w, p, f, g: the NLP's variables, parameters, cost and constraint rows (CasADi SX).
        lbw, ubw, lbg, ubg: their bounds (stage 0 is pinned by ``variable_bounds``).
        residuals: the objective's stacked weighted residuals (``f = ||residuals||^2``).
        g_kind, g_stage: per row of ``g`` its kind and stage (``COUPLING``: every stage).
        gap_rows: the rows ``z[k+1] = f(z[k], u[k])``.
        hier_rows: per constrained group, its rows in ``g``.
        hier_residuals: (row, weighted residuals whose squared norm that row is), for
            the cost-bound rows of modes ``stagewise`` and ``total``.
        stage_model: the stage and terminal Functions.
    """

    def __init__(
        self,
        problem: Problem,
        objective: Sequence[TaskEntry],
        constrained: Sequence[Sequence[TaskEntry]] = (),
        mode: str = "stagewise",
        regularizer_scale: float = 1.0,
    ) -> None:
        if mode not in MODES:
            raise ConfigError(f"hierarchy.mode: {mode!r} is not one of {MODES}")
        self.problem, self.mode = problem, mode
        self.N, self.nx = problem.horizon, problem.kin.nx
        self.model = problem.model
        self.nz = self.model.nz
        self.stride = self.nz + self.nx
        idx = {e.name: i for i, e in enumerate(problem.entries)}
        groups = [[idx[e.name] for e in g] for g in constrained]
        self.stage_model = _stage_model(
            problem, [idx[e.name] for e in objective], groups, regularizer_scale
        )
        self._build(len(groups))
        self._layout()
        limits = problem.bounds.accel_limits
        #: per DoF, the most the command may change in one step (``inf``: unbounded)
        self.max_change = np.full(self.nx, np.inf) if limits is None else limits * problem.dt
        #: the last ``variable_bounds``: (z0's bytes, (lbw, ubw), whether a plan was needed)
        self._bounds_memo: tuple[bytes, tuple[np.ndarray, np.ndarray], bool] | None = None
        #: a transcription with the same variables and bounds whose ``variable_bounds``
        #: this one returns (``share_variable_bounds``: a hierarchy's levels)
        self._bounds_source: Transcription | None = None

    # -- building the NLP ---------------------------------------------------------------
    def _build(self, n_groups: int) -> None:
        N, nx, nz = self.N, self.nx, self.nz
        Z = [ca.SX.sym(f"z{k}", nz) for k in range(N + 1)]
        U = [ca.SX.sym(f"u{k}", nx) for k in range(N)]
        P = ca.SX.sym("P", self.problem.param_size, N + 1)
        self.rows = RowBook()
        self.gap_rows: list[int] = []
        self.hier_rows: list[list[int]] = [[] for _ in range(n_groups)]
        self.hier_residuals: list[tuple[int, ca.SX]] = []
        w, lbw, ubw = [], [], []
        f, per_task, res_obj = ca.SX(0), [], []
        totals = [(ca.SX(0), []) for _ in range(n_groups)]  # mode "total": sums per group
        for k in range(N + 1):
            for var, lo, hi in self._stage_variables(k, Z, U):
                w.append(var)
                lbw.append(lo)
                ubw.append(hi)
            cost, hier, path, costs, res = self._stage_terms(k, Z, U, P)
            f += cost
            per_task.append(costs)
            res_obj.append(res[0])
            self._stage_rows(k, Z, U, path, hier, res[1:], totals)
        for j, (c_sum, r_list) in enumerate(totals if self.mode == "total" else ()):
            self.hier_rows[j] = self.rows.add(c_sum, -np.inf, np.inf, f"hier{j}", COUPLING)
            self.hier_residuals.append((self.hier_rows[j][0], ca.vertcat(*r_list)))
        self.w, self.f = ca.vertcat(*w), f
        self.p = ca.vertcat(ca.SX.sym("z0", nz), ca.vec(P))
        self.residuals = ca.vertcat(*res_obj)
        self.g = ca.vertcat(*self.rows.exprs)
        self.lbw, self.ubw = np.concatenate(lbw), np.concatenate(ubw)
        # never empty: every stage but the last has its gap rows
        self.lbg, self.ubg = np.concatenate(self.rows.lower), np.concatenate(self.rows.upper)
        self.equality = (self.lbg == self.ubg).tolist()
        self.g_kind, self.g_stage = self.rows.kind, self.rows.stage
        # per task (rows) and stage (columns) weighted costs, for reports and hierarchy
        self.stage_costs = ca.Function(
            "stage_costs", [self.w, self.p], [ca.densify(ca.horzcat(*per_task))], ["w", "p"], ["C"]
        )

    def _stage_variables(
        self, k: int, Z: list[ca.SX], U: list[ca.SX]
    ) -> list[tuple[ca.SX, np.ndarray, np.ndarray]]:
        """Stage ``k``'s variables with their bounds: ``z[k]`` (free at stage 0, pinned at
        solve time; ``v`` and ``r`` always free) and ``u[k]`` (but at the terminal stage)."""
        b, free = self.problem.bounds, np.full(self.nz - self.nx, np.inf)
        if k == 0:
            out = [(Z[0], -np.full(self.nz, np.inf), np.full(self.nz, np.inf))]
        else:
            out = [(Z[k], np.concatenate([b.x_lower, -free]), np.concatenate([b.x_upper, free]))]
        if k < self.N:
            out.append((U[k], b.u_lower, b.u_upper))
        return out

    def _stage_terms(
        self, k: int, Z: list[ca.SX], U: list[ca.SX], P: ca.SX
    ) -> tuple[ca.SX, ca.SX, ca.SX, ca.SX, list[ca.SX]]:
        """Stage ``k``'s objective cost, group costs, path rows, per-task costs, residuals."""
        sm = self.stage_model
        if k < self.N:
            cost, hier, path, costs = sm.cost(Z[k], U[k], P[:, k])
            res = sm.residuals(Z[k], U[k], P[:, k])
        else:
            cost, hier, path, costs = sm.terminal_cost(Z[k], P[:, k])
            res = sm.terminal_residuals(Z[k], P[:, k])
        return cost, hier, path, costs, list(res) if isinstance(res, tuple | list) else [res]

    def _stage_rows(
        self,
        k: int,
        Z: list[ca.SX],
        U: list[ca.SX],
        path: ca.SX,
        hier: ca.SX,
        group_res: list[ca.SX],
        totals: list[tuple[ca.SX, list[ca.SX]]],
    ) -> None:
        """Stage ``k``'s rows: the gap-closing ones first, path rows, hierarchy rows, then
        the command-rate rows."""
        book, sm = self.rows, self.stage_model
        if k < self.N:
            gap = Z[k + 1] - self.model.next_sx(Z[k], U[k])
            self.gap_rows += book.add(gap, 0.0, 0.0, "gap", k)
        if k > 0 and path.numel():
            bounds = sm.path if k < self.N else sm.terminal_path
            book.add(path, bounds.lower, bounds.upper, "path" if k < self.N else "terminal", k)
        for j, r in enumerate(group_res):
            if self.mode == "stagewise":
                rows = book.add(hier[j], -np.inf, np.inf, f"hier{j}", k)
                self.hier_rows[j] += rows
                self.hier_residuals.append((rows[0], r))
            elif self.mode in RESIDUAL_ROWS:  # the residuals themselves (nonlinear in w)
                self.hier_rows[j] += book.add(r, -np.inf, np.inf, f"hier{j}", k)
            else:
                c_sum, r_list = totals[j]
                totals[j] = (c_sum + hier[j], [*r_list, r])
        if k < self.N and sm.accel is not None and sm.accel_bounds is not None:
            book.add(sm.accel(Z[k], U[k]), *sm.accel_bounds, "accel", k)

    def _layout(self) -> None:
        """Where each block sits in ``w``, and the shift maps of the warm start."""
        N, nx, s = self.N, self.nx, self.stride
        k = np.arange(N + 1)[:, None] * s
        #: where X (N+1, nx), V (N+1, nx), Z (N+1, nz) and U (N, nx) sit in ``w``
        self.index_x = k + np.arange(nx)
        self.index_v = k + nx + np.arange(nx)
        self.index_z = k + np.arange(self.nz)
        self.index_u = k[:N] + self.nz + np.arange(nx)
        # the multipliers of the next control step, predicted: ``lam[shift]`` gives each
        # row (variable) of stage k the one of the same kind and place in stage k+1; rows
        # without such a twin (the last stage's, terminal and coupling rows) keep theirs
        nw = self.w.numel()
        self.shift_w = np.arange(nw) + s
        self.shift_w[self.shift_w >= nw] -= s
        self.shift_g = shift_map(list(zip(self.g_kind, self.g_stage, strict=True)))
        self._costs_buf: tuple | None = None
        # rows that no decision can change: they depend on the measured stage 0 alone
        jac = ca.jacobian(self.g, self.w).sparsity()
        rows, cols = np.array(jac.get_triplet(), dtype=int).reshape(2, -1)
        movable = np.zeros(self.g.numel(), dtype=bool)
        movable[rows[cols >= self.nz]] = True
        #: per row of g: whether any decision variable (not the pinned stage 0) moves it
        self.g_movable = movable

    def strict_pins(self, group: int) -> tuple[np.ndarray, np.ndarray]:
        """A strict hierarchy's rule for a higher level's residual rows in this NLP
        (``hier_rows[group]``): the rows a decision moves, held at that level's values
        (in ``hier_rows`` order), and the rows none does, left free."""
        rows = np.asarray(self.hier_rows[group], dtype=int)
        movable = self.g_movable[rows]
        return rows[movable], rows[~movable]

    # -- evaluation and packing ---------------------------------------------------------
    def use_stage_costs(self, f: ca.Function) -> None:
        """Evaluate ``stage_costs`` (and ``costs``) with ``f``, e.g. its compiled twin."""
        self.stage_costs = f
        self._costs_buf = None

    def costs(self, w: np.ndarray, p: np.ndarray) -> np.ndarray:
        """``stage_costs(w, p)`` as an array (tasks x stages), without conversions (its
        output is dense: ``_build`` densifies it)."""
        if self._costs_buf is None:
            f = self.stage_costs
            buf, run = f.buffer()
            args = [np.zeros(f.nnz_in(i)) for i in range(2)]
            out = np.zeros(f.nnz_out(0))
            for i, a in enumerate(args):
                buf.set_arg(i, memoryview(a))
            buf.set_res(0, memoryview(out))
            self._costs_buf = (buf, run, args, out, f.size_out(0))
        buf, run, args, out, shape = self._costs_buf
        args[0][:] = w
        args[1][:] = p
        run()
        return out.reshape(shape, order="F").copy()

    def variable_bounds(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``lbw, ubw`` with the stage-0 augmented state pinned to ``z0`` (from ``p``) and
        the state box of each later stage widened, where needed, to hold a recovery plan
        (``RateModel.recovery``: each step as far into the box as the rates allow): a
        state outside its box, or whose rates carry it out before it can stop (lagging
        rates, command-rate bounds), would otherwise make every plan infeasible. The box
        is kept wherever that plan keeps it; the widening ends where it is back inside.
        Near a bound, the plan may first brake into the margin as far as the vehicle
        would coast (``Bounds.return_bounds``, ``bounds.margin_ramp``). The arrays are
        read-only: the same ones come back until ``p``'s state changes."""
        if self._bounds_source is not None:
            return self._bounds_source.variable_bounds(p)
        z0 = np.asarray(p[: self.nz], dtype=float)
        key = z0.tobytes()
        if self._bounds_memo is not None and self._bounds_memo[0] == key:
            return self._bounds_memo[1]
        lbw, ubw = self.lbw.copy(), self.ubw.copy()
        lbw[: self.nz] = ubw[: self.nz] = z0
        b, x0 = self.problem.bounds, z0[: self.nx]
        soft = min(self.N, int(np.ceil(b.margin_ramp / self.problem.dt)))
        if soft > 0:  # where the vehicle would coast with its commands zeroed
            coast = self.model.rollout(z0, np.zeros((soft, self.nx)))[1:, : self.nx]
            ahead = self.problem.dt * np.arange(1, soft + 1)[:, None]
            idx = self.index_x[1 : soft + 1]
            lbw[idx], ubw[idx] = b.return_bounds(coast, ahead)
        reach = self.model.reach(z0, self.max_change)  # no plan needed where it is short
        near = bool(np.any(x0 - reach < b.x_lower) or np.any(x0 + reach > b.x_upper))
        if near:
            x_brake = self.model.recovery(
                z0, self.N, self.max_change, (b.x_lower, b.x_upper), (b.u_lower, b.u_upper)
            )
            idx = self.index_x[1:]
            lbw[idx] = np.minimum(lbw[idx], x_brake)
            ubw[idx] = np.maximum(ubw[idx], x_brake)
        lbw.flags.writeable = ubw.flags.writeable = False  # kept for the step's other calls
        self._bounds_memo = (key, (lbw, ubw), near)
        return lbw, ubw

    def share_variable_bounds(self, other: Transcription) -> bool:
        """Return ``other``'s ``variable_bounds`` from now on (one computation per step for
        a hierarchy's levels), if its variables, bounds and model are this one's; whether
        they are."""
        same = (
            other.model is self.model
            and other.problem.bounds is self.problem.bounds
            and other.N == self.N
            and np.array_equal(other.lbw, self.lbw)
            and np.array_equal(other.ubw, self.ubw)
            and np.array_equal(other.index_x, self.index_x)
        )
        self._bounds_source = other if same and other is not self else None
        return same

    def box_widening(self, p: np.ndarray) -> np.ndarray:
        """Per DoF, how far [m, rad] ``variable_bounds(p)`` widens the state box (0: not)."""
        if self._bounds_source is not None:
            return self._bounds_source.box_widening(p)
        lbw, ubw = self.variable_bounds(p)
        if not self._bounds_memo[2]:
            return np.zeros(self.nx)
        idx = self.index_x[1:]
        with np.errstate(invalid="ignore"):  # inf - inf where a side is unbounded
            below = np.nan_to_num(self.lbw[idx] - lbw[idx], nan=0.0)
            above = np.nan_to_num(ubw[idx] - self.ubw[idx], nan=0.0)
        return np.maximum(below, above).max(axis=0)

    def parameters(
        self,
        x0: np.ndarray,
        u_prev: np.ndarray,
        stage_params: np.ndarray,
        rates: np.ndarray | None = None,
    ) -> np.ndarray:
        """Pack ``p = [z0, refs]``; ``stage_params`` is (N+1, param_size), stage-major;
        ``rates``: the measured actual rates (with a rate response; default ``u_prev``)."""
        z0 = self.model.initial(x0, u_prev, rates)
        return np.concatenate([z0, np.asarray(stage_params, dtype=float).reshape(-1)])

    def unpack(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """States ``X`` (N+1, nx) and commands ``U`` (N, nx) from the variable vector."""
        w = np.asarray(w, dtype=float).ravel()
        return w[self.index_x], w[self.index_u]

    def pack(
        self, X: np.ndarray, U: np.ndarray, u_prev: np.ndarray, rates: np.ndarray | None = None
    ) -> np.ndarray:
        """Variable vector for a trajectory (``v`` and ``r`` rolled out from the commands)."""
        w = np.empty(self.stride * self.N + self.nz)
        if self.model.has_response:
            w[self.index_z] = self.model.rollout(self.model.initial(X[0], u_prev, rates), U)
        else:  # z = [x; v], v[k] the command before stage k
            w[self.index_v[0]] = u_prev
            w[self.index_v[1:]] = U
        w[self.index_x] = X
        w[self.index_u] = U
        return w
