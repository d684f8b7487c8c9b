"""Task composition strategies (paper Sec. III-A, III-B): weighted sum or strict hierarchy.

Hierarchical (nested optimisations, the paper's eq. 5): level ``i`` minimises its tasks
(plus the regularisers: entries with ``level=None`` such as the control rate, in every
level's objective and never constrained) while every higher level ``j < i`` stays at
its optimum. How it stays there is the ``mode``:

* ``"strict"`` (default): each higher level's weighted residual vector ``R_j`` is pinned
  to its value ``R*_j`` at level ``j``'s own optimum: ``R_j(w) = R*_j``, stage by stage.
  The rows are linear in the residuals and well conditioned (a tracking residual's
  Jacobian always has rank 3 through the platform's translation), so every backend
  solves them exactly; the lower level moves only in their null space. A higher level's
  cost is then its optimum to the solver's accuracy: its *loss* (reported per level) is
  ~0. Rows that no decision can change (stage 0 of tasks without the command) are left
  out. The residual may not rotate on the sphere ``||R_j|| = ||R*_j||``: the higher task
  keeps its errors, not just their size.
* ``"stagewise"``, ``"total"``: the paper's literal form, each stage's cost (or the total)
  bounded by ``c_j <= c*_j + max(abs_tol, rel_tol |c*_j|)``. An equality on an optimal
  value is degenerate, so the bound is relaxed, and the lower level uses the relaxation:
  the higher level's loss is up to the tolerance (reported).
* ``"residual"``: the residual vector kept in a box around ``R*_j`` whose half-width
  keeps ``c_j <= c*_j + tol`` at every corner (``strict`` with a tolerance).

In ``strict`` mode the regularisers weigh ``regularizer_scale`` (10 %) of their weight in
every level but the last: enough to keep the level well conditioned (at 1 % a real-time
iteration at 10 Hz lost the tracking in physics), too little to trade its task for
smoother commands (at full weight the tracking level gives up millimetres of error to
spare the rates, and the pinned residuals then keep that trade). The last level
smooths the plan at full weight within what the higher levels left free. The relaxed
modes keep the full weight everywhere: their allowance is what the lower level takes,
and with a lighter regulariser their degenerate cost bounds (a bound at a minimum)
became infeasible for IPOPT three levels down.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends import Backend, NlpResult, SolveRequest, make_backend
from aeromanip.nmpc.backends.codegen import Buffered
from aeromanip.nmpc.problem import Problem, TaskEntry
from aeromanip.nmpc.transcription import Transcription
from aeromanip.registry import Registry

MODE = "strict"  # higher levels' residuals pinned at their optimum (module docstring)
REL_TOL = 1e-3  # relaxed modes: relative relaxation of a higher level's optimal cost
ABS_TOL = 1e-6  # relaxed modes: absolute relaxation (where the optimum is ~0)
MAX_REL_TOL = 1.0  # a level may double the higher optimum at most: beyond, no hierarchy
MAX_ABS_TOL = 1e6  # [cost units]
REGULARIZER_SCALE = 0.1  # strict mode: the regularisers' share in every level but the last


@dataclass
class LevelReport:
    """Outcome of one priority level at one step.

    Attributes:
        level: priority (0 highest).
        cost: the level's own tasks' cost at its own optimum (regularisers excluded).
        objective: what the level minimised at its optimum (``cost`` + regularisers, at
            the level's ``regularizer_scale``).
        gain: how much this level's cost dropped against the previous level's solution
            (what optimising it bought); 0 for the first level.
        loss: how much higher this level's cost is at the applied solution than at its
            own optimum (what the lower levels took from it; ~0 for ``strict``).
        success, status, iterations, solve_time_s: solver outcome.
    """

    level: int
    cost: float
    gain: float
    success: bool
    status: str
    iterations: int
    solve_time_s: float
    objective: float = float("nan")
    loss: float = float("nan")


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
    g_fun: Buffered | None = None  # the constraints, for residual bounds


def _solve_level(
    st: LevelSolver, p: np.ndarray, w0: np.ndarray, ubg: np.ndarray, lbg: np.ndarray | None = None
) -> NlpResult:
    """Solve with the last step's multipliers; on failure retry cold (or go on from the
    last iterate when the solver only ran out of iterations, unless its iterations are
    bounded: ``Backend.bounded_iterations``)."""
    lam_g = lam_x = None
    lbg = st.tr.lbg if lbg is None else lbg
    if st.warm is not None and st.warm.success:
        lam_g, lam_x = st.warm.lam_g, st.warm.lam_x
    request = SolveRequest(w0, p, lbg, ubg, lam_g, lam_x)
    res = st.backend.solve(request)
    out_of_iterations = res.status == "Maximum_Iterations_Exceeded"
    spent = out_of_iterations and st.backend.bounded_iterations
    if not res.success and lam_g is not None and not spent:  # stale multipliers: retry cold
        go_on = out_of_iterations and bool(np.isfinite(res.w).all())
        cold = st.backend.solve(request.cold_from(res.w if go_on else w0))
        cold.solve_time_s += res.solve_time_s
        cold.iterations += res.iterations
        res = cold
    st.warm = res
    return res


class Strategy(ABC):
    """How the tasks' costs become NLPs (one per level, ``solvers``) and how their
    solutions make one answer. Registered by name in ``STRATEGIES``; a strategy of your
    own is a subclass named ``"package.module:Class"``.
    """

    kind: str = "strategy"
    #: solved level by level: takes the ``hierarchy`` options and reports every level
    by_level: ClassVar[bool] = False
    solvers: list[LevelSolver]

    @classmethod
    def build(
        cls,
        problem: Problem,
        backend: str,
        options: Mapping[str, Any] | None,
        hierarchy: Mapping[str, Any],
    ) -> Strategy:
        """The strategy for ``problem`` with the ``backend`` (and its ``options``) at every
        level; ``hierarchy``: the options of a strategy ``by_level`` (else empty)."""
        if hierarchy and not cls.by_level:
            raise ConfigError(f"hierarchy: options given but strategy is {cls.kind!r}")
        return cls(problem, backend=backend, options=options, **dict(hierarchy))  # type: ignore[call-arg]

    @property
    def transcription(self) -> Transcription:
        """The transcription whose variable layout results use (the last level's)."""
        return self.solvers[-1].tr

    def reset(self) -> None:
        """Forget the warm starts."""
        for solver in self.solvers:
            solver.warm = None

    @abstractmethod
    def solve(self, p: np.ndarray, guesses: list[np.ndarray | None]) -> StrategyResult:
        """Solve from ``guesses`` (each level's primal guess; ``guesses[0]`` given)."""


STRATEGIES: Registry[Strategy] = Registry("strategy", "aeromanip.nmpc.strategies", Strategy)


@STRATEGIES.register("weighted")
class Weighted(Strategy):
    """One optimisation of the weighted sum of every task (levels ignored)."""

    def __init__(
        self, problem: Problem, backend: str = "ipopt", options: Mapping[str, Any] | None = None
    ) -> None:
        if not problem.entries:
            raise ConfigError("tasks: the problem has no task")
        tr = Transcription(problem, problem.entries)
        self.solvers = [LevelSolver(problem.entries, tr, make_backend(tr, backend, options))]
        self.problem = problem

    def solve(self, p: np.ndarray, guesses: list[np.ndarray | None]) -> StrategyResult:
        """Solve from the primal guess ``guesses[0]`` (duals are reused from the last solve)."""
        st = self.solvers[0]
        res = _solve_level(st, p, guesses[0], st.tr.ubg)
        C = st.tr.costs(res.w, p).sum() if res.success else np.nan
        rep = LevelReport(
            0, float(C), 0.0, res.success, res.status, res.iterations, res.solve_time_s, float(C)
        )
        rep.loss = 0.0 if res.success else np.nan
        status = "ok" if res.success else res.status  # the solver's own is in the report
        return StrategyResult(
            res.w, st.tr, res.success, status, res.iterations, res.solve_time_s, [rep], [res.w]
        )


@STRATEGIES.register("hierarchical")
class Hierarchical(Strategy):
    """Nested optimisations over ``problem.levels`` (see module docstring).

    Args:
        problem: tasks with their levels; at least one level.
        mode: ``"strict"`` (default), ``"stagewise"`` (the paper's literal form),
            ``"total"`` or ``"residual"``.
        rel_tol, abs_tol: the relaxation of each higher level's optimal cost (the relaxed
            modes; ``strict`` has none).
        backend, options: NLP solver for every level.
        regularizer_scale: the share of their weight the regularisers keep in every
            level but the last, in (0, 1] (module docstring; 1: full weight everywhere;
            default: ``REGULARIZER_SCALE`` in ``strict`` mode, else 1).
    """

    by_level: ClassVar[bool] = True

    def __init__(
        self,
        problem: Problem,
        mode: str = MODE,
        rel_tol: float = REL_TOL,
        abs_tol: float = ABS_TOL,
        backend: str = "ipopt",
        options: Mapping[str, Any] | None = None,
        regularizer_scale: float | None = None,
    ) -> None:
        if not problem.levels:
            raise ConfigError("tasks: a hierarchy needs at least one task with a level")
        if not 0 <= rel_tol <= MAX_REL_TOL:
            raise ConfigError(f"hierarchy.rel_tol: must be in [0, {MAX_REL_TOL:g}], got {rel_tol}")
        if not 0 <= abs_tol <= MAX_ABS_TOL:
            raise ConfigError(f"hierarchy.abs_tol: must be in [0, {MAX_ABS_TOL:g}], got {abs_tol}")
        if regularizer_scale is None:
            regularizer_scale = REGULARIZER_SCALE if mode == "strict" else 1.0
        if not 0 < regularizer_scale <= 1:
            raise ConfigError(
                f"hierarchy.regularizer_scale: must be in (0, 1], got {regularizer_scale}"
            )
        self.problem, self.mode = problem, mode
        self.rel_tol, self.abs_tol = rel_tol, abs_tol
        reg = [e for e in problem.entries if e.level is None]
        self.levels = problem.levels
        self.solvers: list[LevelSolver] = []
        for i, lvl in enumerate(self.levels):
            own = [e for e in problem.entries if e.level == lvl]
            higher = [[e for e in problem.entries if e.level == h] for h in self.levels[:i]]
            scale = 1.0 if i == len(self.levels) - 1 else regularizer_scale
            tr = Transcription(problem, own + reg, higher, mode, scale)
            self.solvers.append(LevelSolver(own, tr, make_backend(tr, backend, options)))
        # a backend that needs no feasible start (an SQP): a relaxed level starts from its
        # own last solution; a strict one from the level above's, on its rows exactly (from
        # its own, with velocity bounds binding, it crawls back onto the curved rows)
        needs_feasible = type(self.solvers[0].backend).needs_feasible_start
        self.own_guess = not needs_feasible and mode != "strict"
        idx = {e.name: i for i, e in enumerate(problem.entries)}
        self.rows = [[idx[e.name] for e in st.entries] for st in self.solvers]
        self.reg_rows = [idx[e.name] for e in reg]
        for st in self.solvers[1:]:  # the levels' variable bounds: computed once a step
            st.tr.share_variable_bounds(self.solvers[0].tr)

    def _bounds(
        self, i: int, p: np.ndarray, optima: list[np.ndarray], level_w: list[np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Level ``i``'s row bounds: each higher level ``j`` kept at its optimum."""
        st = self.solvers[i]
        lbg, ubg = st.tr.lbg.copy(), st.tr.ubg.copy()
        for j, c_star in enumerate(optima):
            rows = np.asarray(st.tr.hier_rows[j], dtype=int)
            if self.mode == "strict":
                pinned, free = st.tr.strict_pins(j)
                lbg[pinned] = ubg[pinned] = self._rows_at(st, level_w[j], p)[pinned]
                lbg[free], ubg[free] = -np.inf, np.inf
            elif self.mode == "residual":
                lbg[rows], ubg[rows] = self._residual_box(st, j, level_w[j], p, c_star)
            else:
                bound = c_star + np.maximum(self.abs_tol, self.rel_tol * np.abs(c_star))
                ubg[rows] = bound if self.mode == "stagewise" else bound.sum()
        return lbg, ubg

    def _rows_at(self, st: LevelSolver, w: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Level ``st``'s constraint rows evaluated at ``w``."""
        if st.g_fun is None:  # evaluated on buffers: no conversions per call
            st.g_fun = Buffered(ca.Function("g", [st.tr.w, st.tr.p], [ca.densify(st.tr.g)]))
        return st.g_fun(w, p)[0].copy()

    def _residual_box(
        self, st: LevelSolver, j: int, w_j: np.ndarray, p: np.ndarray, c_star: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Bounds ``R*_k -+ delta_k`` on group ``j``'s residual rows of level ``st``, with
        ``sum_i (|R*_ki| + delta_k)^2 = c*_k + tol_k`` (the cost bound at every corner)."""
        tr, rows = st.tr, np.asarray(st.tr.hier_rows[j], dtype=int)
        R = self._rows_at(st, w_j, p)[rows]
        stage = np.asarray(tr.g_stage, dtype=int)[rows]
        tol = np.maximum(self.abs_tol, self.rel_tol * np.abs(c_star))
        lo, hi = np.empty_like(R), np.empty_like(R)
        for k in np.unique(stage):
            sel = stage == k
            a, m = np.abs(R[sel]).sum(), sel.sum()
            delta = (np.sqrt(a * a + m * tol[k]) - a) / m
            lo[sel], hi[sel] = R[sel] - delta, R[sel] + delta
        return lo, hi

    def _start(
        self, i: int, guesses: list[np.ndarray | None], w_best: np.ndarray | None
    ) -> np.ndarray:
        """Level ``i``'s initial guess: its own (shifted) one for an SQP, which needs no
        feasible start, else the higher level's solution (feasible: interior points like it)."""
        if w_best is None:  # the first level (a failed one ends the solve)
            return guesses[0]
        mine = guesses[i] if i < len(guesses) else None
        return mine if (mine is not None and self.own_guess) else w_best

    def solve(self, p: np.ndarray, guesses: list[np.ndarray | None]) -> StrategyResult:
        """Solve level by level; a failed lower level keeps the last successful solution.

        ``guesses[i]`` is level ``i``'s guess (e.g. its own previous solution, shifted),
        used as ``_start`` says; ``guesses[0]`` must be given.
        """
        reports: list[LevelReport] = []
        optima: list[np.ndarray] = []
        level_w: list[np.ndarray] = []
        w_best: np.ndarray | None = None
        total_t, total_it, status = 0.0, 0, "ok"
        for i, st in enumerate(self.solvers):
            lbg, ubg = self._bounds(i, p, optima, level_w)
            res = _solve_level(st, p, self._start(i, guesses, w_best), ubg, lbg)
            total_t += res.solve_time_s
            total_it += res.iterations
            if not res.success:
                reports.append(
                    LevelReport(
                        self.levels[i], np.nan, np.nan, False, res.status, res.iterations,
                        res.solve_time_s,
                    )
                )  # fmt: skip
                status = res.status
                break
            C = st.tr.costs(res.w, p)
            own = C[self.rows[i]].sum(axis=0)
            before = np.nan if w_best is None else float(st.tr.costs(w_best, p)[self.rows[i]].sum())
            reports.append(
                LevelReport(
                    self.levels[i], float(own.sum()), 0.0 if w_best is None else before - own.sum(),
                    True, res.status, res.iterations, res.solve_time_s,
                    objective=float(own.sum() + C[self.reg_rows].sum()),
                )
            )  # fmt: skip
            optima.append(own if self.mode != "total" else np.array([own.sum()]))
            w_best = res.w
            level_w.append(res.w)
        if w_best is None:
            n = self.transcription.w.numel()
            return StrategyResult(
                np.full(n, np.nan), self.transcription, False, status, total_it, total_t, reports
            )
        self._losses(reports, w_best, p)
        partial = len(level_w) < len(self.solvers)
        return StrategyResult(
            w_best, self.transcription, True, f"partial: {status}" if partial else "ok",
            total_it, total_t, reports, level_w,
        )  # fmt: skip

    def _losses(self, reports: list[LevelReport], w: np.ndarray, p: np.ndarray) -> None:
        """Each solved level's cost at the applied solution ``w`` minus at its optimum."""
        C = self.transcription.costs(w, p)
        for rep, rows in zip(reports, self.rows, strict=False):
            if rep.success:
                rep.loss = float(C[rows].sum()) - rep.cost
