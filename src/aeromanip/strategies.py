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
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.ocp import Problem, TaskEntry, Transcription
from aeromanip.solvers import NlpBackend, NlpResult


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


@dataclass
class _Stage:
    entries: list[TaskEntry]
    tr: Transcription
    backend: NlpBackend
    warm: NlpResult | None = None


def _level_cost(tr: Transcription, w: np.ndarray, p: np.ndarray, rows: list[int]) -> np.ndarray:
    C = np.asarray(tr.stage_costs(w, p))
    return C[rows].sum(axis=0)


class Weighted:
    """One optimisation of the weighted sum of every task (levels ignored)."""

    def __init__(
        self, problem: Problem, backend: str = "ipopt", options: Mapping[str, Any] | None = None
    ) -> None:
        if not problem.entries:
            raise ConfigError("tasks: the problem has no task")
        tr = Transcription(problem, problem.entries)
        self.stages = [_Stage(problem.entries, tr, NlpBackend(tr, backend, options))]
        self.problem = problem

    @property
    def transcription(self) -> Transcription:
        """The transcription whose variable layout results use."""
        return self.stages[-1].tr

    def solve(self, p: np.ndarray, guesses: list[np.ndarray]) -> StrategyResult:
        """Solve from the primal guess ``guesses[0]`` (duals are reused from the last solve)."""
        st = self.stages[0]
        res = _solve_stage(st, p, guesses[0], st.tr.ubg)
        C = np.asarray(st.tr.stage_costs(res.w, p)).sum()
        rep = LevelReport(
            0, float(C), 0.0, res.success, res.status, res.iterations, res.solve_time_s
        )
        return StrategyResult(
            res.w, st.tr, res.success, res.status, res.iterations, res.solve_time_s, [rep]
        )


def _solve_stage(st: _Stage, p: np.ndarray, w0: np.ndarray, ubg: np.ndarray) -> NlpResult:
    lam_g = lam_x = None
    if st.warm is not None and st.warm.success:
        lam_g, lam_x = st.warm.lam_g, st.warm.lam_x
    res = st.backend.solve(w0, p, st.tr.lbg, ubg, lam_g, lam_x)
    if not res.success and lam_g is not None:  # stale multipliers can mislead: retry cold
        cold = st.backend.solve(w0, p, st.tr.lbg, ubg)
        cold.solve_time_s += res.solve_time_s
        cold.iterations += res.iterations
        res = cold
    st.warm = res
    return res


class Hierarchical:
    """Nested optimisations over ``problem.levels`` (see module docstring).

    Args:
        problem: tasks with their levels; at least one level.
        mode: ``"stagewise"`` (default, the paper's) or ``"total"``.
        rel_tol, abs_tol: the relaxation of each higher level's optimal cost.
        backend, options: NLP solver for every level.
    """

    def __init__(
        self,
        problem: Problem,
        mode: str = "stagewise",
        rel_tol: float = 1e-3,
        abs_tol: float = 1e-6,
        backend: str = "ipopt",
        options: Mapping[str, Any] | None = None,
    ) -> None:
        if not problem.levels:
            raise ConfigError("tasks: a hierarchy needs at least one task with a level")
        if rel_tol < 0 or abs_tol <= 0:
            raise ConfigError("hierarchy: rel_tol must be >= 0 and abs_tol > 0")
        self.problem, self.mode = problem, mode
        self.rel_tol, self.abs_tol = rel_tol, abs_tol
        reg = [e for e in problem.entries if e.level is None]
        self.levels = problem.levels
        self.stages: list[_Stage] = []
        for i, lvl in enumerate(self.levels):
            own = [e for e in problem.entries if e.level == lvl]
            higher = [[e for e in problem.entries if e.level == h] for h in self.levels[:i]]
            tr = Transcription(problem, own + reg, higher, mode)
            self.stages.append(_Stage(own, tr, NlpBackend(tr, backend, options)))
        idx = {e.name: i for i, e in enumerate(problem.entries)}
        self.rows = [[idx[e.name] for e in st.entries] for st in self.stages]

    @property
    def transcription(self) -> Transcription:
        """The transcription whose variable layout results use (all levels share it)."""
        return self.stages[-1].tr

    def solve(self, p: np.ndarray, guesses: list[np.ndarray]) -> StrategyResult:
        """Solve level by level; a failed lower level keeps the last successful solution."""
        reports: list[LevelReport] = []
        optima: list[np.ndarray] = []
        w_best: np.ndarray | None = None
        total_t, total_it, status = 0.0, 0, "ok"
        for i, st in enumerate(self.stages):
            ubg = st.tr.ubg.copy()
            for j, c_star in enumerate(optima):
                bound = c_star + np.maximum(self.abs_tol, self.rel_tol * np.abs(c_star))
                ubg[st.tr.hier_rows[j]] = bound if self.mode == "stagewise" else bound.sum()
            w0 = guesses[i] if w_best is None else w_best
            res = _solve_stage(st, p, w0, ubg)
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
            optima.append(own if self.mode == "stagewise" else np.array([own.sum()]))
            w_best = res.w
        if w_best is None:
            n = self.transcription.w.numel()
            return StrategyResult(
                np.full(n, np.nan), self.transcription, False, status, total_it, total_t, reports
            )
        partial = len(optima) < len(self.stages)
        return StrategyResult(
            w_best,
            self.transcription,
            True,
            f"partial: {status}" if partial else "ok",
            total_it,
            total_t,
            reports,
        )
