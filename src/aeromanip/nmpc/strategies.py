"""Task composition strategies (paper Sec. III-A, III-B): weighted sum or strict hierarchy.

Hierarchical (nested optimisations): level ``i`` minimises its tasks subject to every
higher level ``j < i`` keeping its optimal cost, as in the paper's eq. (5). An equality on
an optimal value is degenerate (no interior, multipliers unbounded), so it is relaxed to

    c_j <= c_j* + max(abs_tol, rel_tol * |c_j*|)

stage by stage (``mode="stagewise"``, the paper's form: one constraint per predicted step
``k = 0..N``) or on the level's total cost (``mode="total"``). Regularisers (task entries
with ``level=None``, e.g. the control rate) are in every level's objective but never
constrained, which keeps each level's problem well posed when higher levels leave
redundancy.

``mode="residual"`` keeps instead each higher level's weighted residual vector ``R_k``
(cost ``c_k = ||R_k||^2``) in a box around its optimum ``R*_k``, with the half-width
``delta_k`` that keeps ``c_k <= c*_k + tol_k`` at every corner. The rows are linear in the
residuals, well conditioned even where ``c*_k`` is 0 (where the squared norm's gradient
vanishes), and Newton-type solvers converge on them in a few steps. It is stricter than
the paper's form (the residual may not rotate on the sphere ``c_k = c*_k``): a different
problem, for when speed matters more.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends import Backend, NlpResult, make_backend
from aeromanip.nmpc.problem import Problem, TaskEntry
from aeromanip.nmpc.transcription import Transcription

MODE = "stagewise"  # the paper's form: one cost bound per predicted step
REL_TOL = 1e-3  # relative relaxation of a higher level's optimal cost
ABS_TOL = 1e-6  # absolute relaxation (where the optimum is ~0)
MAX_REL_TOL = 1.0  # a level may double the higher optimum at most: beyond, no hierarchy
MAX_ABS_TOL = 1e6  # [cost units]


@dataclass
class LevelReport:
    """Outcome of one priority level at one step.

    Attributes:
        level: priority (0 highest).
        cost: the level's cost at its own optimum (regularisers excluded).
        gain: how much this level's cost dropped against the previous level's solution
            (what optimising it bought); 0 for the first level.
        success, status, iterations, solve_time_s: solver outcome.
    """

    level: int
    cost: float
    gain: float
    success: bool
    status: str
    iterations: int
    solve_time_s: float


@dataclass
class StrategyResult:
    """The solution a strategy settled on, and how it got there."""

    w: np.ndarray
    transcription: Transcription
    success: bool
    status: str
    iterations: int
    solve_time_s: float
    levels: list[LevelReport] = field(default_factory=list)
    level_w: list[np.ndarray] = field(default_factory=list)  # each solved level's solution


@dataclass
class LevelSolver:
    """One level's NLP and its solver, with the last result (the warm start)."""

    entries: list[TaskEntry]
    tr: Transcription
    backend: Backend
    warm: NlpResult | None = None
    g_fun: ca.Function | None = None  # the constraints, for residual bounds


def _level_cost(tr: Transcription, w: np.ndarray, p: np.ndarray, rows: list[int]) -> np.ndarray:
    return tr.costs(w, p)[rows].sum(axis=0)


class Weighted:
    """One optimisation of the weighted sum of every task (levels ignored)."""

    def __init__(
        self, problem: Problem, backend: str = "ipopt", options: Mapping[str, Any] | None = None
    ) -> None:
        if not problem.entries:
            raise ConfigError("tasks: the problem has no task")
        tr = Transcription(problem, problem.entries)
        self.solvers = [LevelSolver(problem.entries, tr, make_backend(tr, backend, options))]
        self.problem = problem

    @property
    def transcription(self) -> Transcription:
        """The transcription whose variable layout results use."""
        return self.solvers[-1].tr

    def reset(self) -> None:
        """Forget the warm starts."""
        for solver in self.solvers:
            solver.warm = None

    def solve(self, p: np.ndarray, guesses: list[np.ndarray | None]) -> StrategyResult:
        """Solve from the primal guess ``guesses[0]`` (duals are reused from the last solve)."""
        st = self.solvers[0]
        res = _solve_level(st, p, guesses[0], st.tr.ubg)
        C = st.tr.costs(res.w, p).sum() if res.success else np.nan
        rep = LevelReport(
            0, float(C), 0.0, res.success, res.status, res.iterations, res.solve_time_s
        )
        status = "ok" if res.success else res.status  # the solver's own is in the report
        return StrategyResult(
            res.w, st.tr, res.success, status, res.iterations, res.solve_time_s, [rep], [res.w]
        )


def _solve_level(
    st: LevelSolver, p: np.ndarray, w0: np.ndarray, ubg: np.ndarray, lbg: np.ndarray | None = None
) -> NlpResult:
    lam_g = lam_x = None
    lbg = st.tr.lbg if lbg is None else lbg
    if st.warm is not None and st.warm.success:
        lam_g, lam_x = st.warm.lam_g, st.warm.lam_x
    res = st.backend.solve(w0, p, lbg, ubg, lam_g, lam_x)
    if not res.success and lam_g is not None:  # stale multipliers can mislead: retry cold
        # out of iterations on the way somewhere: go on from there, else start again
        go_on = res.status == "Maximum_Iterations_Exceeded" and bool(np.isfinite(res.w).all())
        cold = st.backend.solve(res.w if go_on else w0, p, lbg, ubg)
        cold.solve_time_s += res.solve_time_s
        cold.iterations += res.iterations
        res = cold
    st.warm = res
    return res


class Hierarchical:
    """Nested optimisations over ``problem.levels`` (see module docstring).

    Args:
        problem: tasks with their levels; at least one level.
        mode: ``"stagewise"`` (default, the paper's), ``"total"`` or ``"residual"``.
        rel_tol, abs_tol: the relaxation of each higher level's optimal cost.
        backend, options: NLP solver for every level.
    """

    def __init__(
        self,
        problem: Problem,
        mode: str = MODE,
        rel_tol: float = REL_TOL,
        abs_tol: float = ABS_TOL,
        backend: str = "ipopt",
        options: Mapping[str, Any] | None = None,
    ) -> None:
        if not problem.levels:
            raise ConfigError("tasks: a hierarchy needs at least one task with a level")
        if not 0 <= rel_tol <= MAX_REL_TOL:
            raise ConfigError(f"hierarchy.rel_tol: must be in [0, {MAX_REL_TOL:g}], got {rel_tol}")
        if not 0 <= abs_tol <= MAX_ABS_TOL:
            raise ConfigError(f"hierarchy.abs_tol: must be in [0, {MAX_ABS_TOL:g}], got {abs_tol}")
        self.problem, self.mode = problem, mode
        self.rel_tol, self.abs_tol = rel_tol, abs_tol
        reg = [e for e in problem.entries if e.level is None]
        self.levels = problem.levels
        self.solvers: list[LevelSolver] = []
        for i, lvl in enumerate(self.levels):
            own = [e for e in problem.entries if e.level == lvl]
            higher = [[e for e in problem.entries if e.level == h] for h in self.levels[:i]]
            tr = Transcription(problem, own + reg, higher, mode)
            self.solvers.append(LevelSolver(own, tr, make_backend(tr, backend, options)))
        self.own_guess = backend.startswith("sqp")
        idx = {e.name: i for i, e in enumerate(problem.entries)}
        self.rows = [[idx[e.name] for e in st.entries] for st in self.solvers]

    def _residual_box(
        self, st: LevelSolver, j: int, w_j: np.ndarray, p: np.ndarray, c_star: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Bounds ``R*_k -+ delta_k`` on group ``j``'s residual rows of level ``st``, with
        ``sum_i (|R*_ki| + delta_k)^2 = c*_k + tol_k`` (the cost bound at every corner)."""
        tr, rows = st.tr, np.asarray(st.tr.hier_rows[j], dtype=int)
        if st.g_fun is None:
            st.g_fun = ca.Function("g", [tr.w, tr.p], [tr.g])
        R = np.asarray(st.g_fun(w_j, p)).ravel()[rows]
        stage = np.asarray(tr.g_stage, dtype=int)[rows]
        tol = np.maximum(self.abs_tol, self.rel_tol * np.abs(c_star))
        lo, hi = np.empty_like(R), np.empty_like(R)
        for k in np.unique(stage):
            sel = stage == k
            a, m = np.abs(R[sel]).sum(), sel.sum()
            delta = (np.sqrt(a * a + m * tol[k]) - a) / m
            lo[sel], hi[sel] = R[sel] - delta, R[sel] + delta
        return lo, hi

    @property
    def transcription(self) -> Transcription:
        """The transcription whose variable layout results use (all levels share it)."""
        return self.solvers[-1].tr

    def reset(self) -> None:
        """Forget the warm starts."""
        for solver in self.solvers:
            solver.warm = None

    def solve(self, p: np.ndarray, guesses: list[np.ndarray | None]) -> StrategyResult:
        """Solve level by level; a failed lower level keeps the last successful solution.

        Level ``i`` starts from ``guesses[i]`` (e.g. its own previous solution, shifted) if
        given and the backend is an SQP (which needs no feasible start), else from the
        higher level's solution (feasible for its constraints: what interior-point
        methods like). ``guesses[0]`` must be given.
        """
        reports: list[LevelReport] = []
        optima: list[np.ndarray] = []
        w_best: np.ndarray | None = None
        total_t, total_it, status = 0.0, 0, "ok"
        level_w: list[np.ndarray] = []
        for i, st in enumerate(self.solvers):
            lbg, ubg = st.tr.lbg.copy(), st.tr.ubg.copy()
            for j, c_star in enumerate(optima):
                bound = c_star + np.maximum(self.abs_tol, self.rel_tol * np.abs(c_star))
                rows = st.tr.hier_rows[j]
                if self.mode == "residual":
                    lbg[rows], ubg[rows] = self._residual_box(st, j, level_w[j], p, c_star)
                else:
                    ubg[rows] = bound if self.mode == "stagewise" else bound.sum()
            mine = guesses[i] if i < len(guesses) else None
            if w_best is None:
                w0 = mine if mine is not None else guesses[0]
            else:
                w0 = mine if (mine is not None and self.own_guess) else w_best
            res = _solve_level(st, p, w0, ubg, lbg)
            total_t += res.solve_time_s
            total_it += res.iterations
            if not res.success:
                reports.append(
                    LevelReport(
                        self.levels[i],
                        np.nan,
                        np.nan,
                        False,
                        res.status,
                        res.iterations,
                        res.solve_time_s,
                    )
                )
                status = res.status
                break
            own = _level_cost(st.tr, res.w, p, self.rows[i])
            before = (
                0.0 if w_best is None else float(_level_cost(st.tr, w_best, p, self.rows[i]).sum())
            )
            reports.append(
                LevelReport(
                    self.levels[i],
                    float(own.sum()),
                    0.0 if w_best is None else before - float(own.sum()),
                    True,
                    res.status,
                    res.iterations,
                    res.solve_time_s,
                )
            )
            optima.append(own if self.mode != "total" else np.array([own.sum()]))
            w_best = res.w
            level_w.append(res.w)
        if w_best is None:
            n = self.transcription.w.numel()
            return StrategyResult(
                np.full(n, np.nan), self.transcription, False, status, total_it, total_t, reports
            )
        partial = len(optima) < len(self.solvers)
        return StrategyResult(
            w_best,
            self.transcription,
            True,
            f"partial: {status}" if partial else "ok",
            total_it,
            total_t,
            reports,
            level_w,
        )
