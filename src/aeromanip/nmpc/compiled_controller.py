"""``Controller.step`` in one compiled call, where the step can be compiled whole.

For the weighted or strict hierarchical strategy on ``sqp``/``sqp-rti`` with the
condensed model and DAQP (short horizons), the step (parameters, guesses, every level's
SQP loop, plan, fallback) runs in C (``backends.sqp.compiled_step``): Python only checks
the input and reads the answer, its task costs and the levels' reports. The answers are
the Python path's: the same loop, the same rules.

The C controller keeps the memory (plans, each level's answer, multipliers and active
rows). A step it leaves to Python (a level to be seeded by IPOPT: a cold start, a warm
solve that failed, an answer far costlier than the last; ``SqpBackend.solve``) is taken
by the Python path: the memory moves to Python first (``to_python``) and back after
(``from_python``).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from aeromanip.nmpc.backends.base import NlpResult
from aeromanip.nmpc.backends.sqp.compiled_step import CompiledStep, compilable
from aeromanip.nmpc.backends.sqp.solver import SOLVED as LOOP_SOLVED
from aeromanip.nmpc.command import Command
from aeromanip.nmpc.strategies import Hierarchical, LevelReport

log = logging.getLogger(__name__)
SOLVED = ("ok", "partial")
#: the loop's status words of a successful solve (``SqpBackend``): the RTI's included
SOLVER_SOLVED = (*LOOP_SOLVED, "RTI step")


class StepInC:
    """A controller's compiled step and the moves of its memory (module docstring);
    ``for_controller`` says ``None`` where the step cannot be compiled whole. ``ctrl``:
    the ``Controller`` it steps for (its memory is the Python path's)."""

    def __init__(self, ctrl: Any, step: CompiledStep) -> None:
        self.ctrl, self.step_c = ctrl, step
        strategy = ctrl.strategy
        self.hierarchical = isinstance(strategy, Hierarchical)
        n = len(ctrl.problem.entries)
        self.rows = strategy.rows if self.hierarchical else [list(range(n))]
        self.reg_rows = strategy.reg_rows if self.hierarchical else []
        self.level_names = strategy.levels if self.hierarchical else [0]
        self.entry_names = [e.name for e in ctrl.problem.entries]
        self.models = [lv.model for lv in step.parts.levels]
        first = self.models[0]
        self.box_low = first.tr.lbw[first.state_idx]
        self.box_high = first.tr.ubw[first.state_idx]
        self.last_in_c = False  # the last step was the compiled one (its discard is C's)

    @classmethod
    def for_controller(cls, ctrl: Any) -> StepInC | None:
        """The compiled step of ``ctrl``, or ``None`` (it does not apply or cannot be
        built: the Python path runs, with the same answers)."""
        parts = compilable(ctrl.strategy, ctrl.problem, ctrl.time_budget_s)
        if parts is None:
            return None
        opts = parts.levels[0].backend.opts
        if not opts.get("compiled_step", True):
            return None
        ratio = None if opts["seed"] == "none" else float(opts["seed_ratio"])
        step = CompiledStep.build(parts, ctrl.latency_s, ratio)
        return None if step is None else cls(ctrl, step)

    # -- the step ----------------------------------------------------------------------
    def step(self, x: np.ndarray, t: float, rates: np.ndarray | None) -> Command | None:
        """The step in C, or ``None`` where it is Python's (nothing changed then). No
        task measures or feeds a force forward (``compilable``): none is asked to."""
        sc = self.step_c
        word = sc.run(x, rates, t)
        if word == "host":
            return None
        self.last_in_c = True
        ctrl, out, p = self.ctrl, sc.out, sc.p
        X, U = sc.out_x.copy(), sc.out_u.copy()
        # every task's cost at the answer that flies (the last level solved's)
        applied = sc.costs[-1](U.ravel(), p)[0].copy() if out.levels else None
        reports, status = self._reports(out.levels, applied)
        message = ("" if status == "ok" else status) + self._widened()
        if applied is not None:
            names = self.entry_names
            task_costs = {n: float(c) for n, c in zip(names, applied, strict=True)}
        else:
            message += ctrl._outside_bounds(p[: ctrl.nx])
            task_costs = dict.fromkeys(self.entry_names, float("nan"))
            log.warning("t=%.3f s: solve failed (%s); %s", t, message, word)
        ctrl.u_prev = sc.u.copy()
        seconds = sum(ls.seconds for ls, _ in sc.levels)
        return Command(
            sc.u.copy(), X, U, task_costs, word, message, out.iterations, seconds, reports,
            observations=ctrl.problem.observations(t),
        )  # fmt: skip

    def _widened(self) -> str:
        """``Controller._widened`` where the first level's state rows are off the box
        (the rows hold the widened bounds; on the box nothing was widened)."""
        arrays, nk = self.step_c.levels[0][1], self.models[0].nk
        low, high = arrays["lbc"][nk:], arrays["ubc"][nk:]
        if np.array_equal(low, self.box_low) and np.array_equal(high, self.box_high):
            return ""
        return self.ctrl._widened(self.step_c.p.copy())

    def _reports(self, solved: int, applied: np.ndarray | None) -> tuple[list[LevelReport], str]:
        """Each level's report as ``Weighted.solve``/``Hierarchical.solve`` writes it,
        and the strategy's status word; ``applied``: every task's cost at the answer
        that flies (the last level's Functions)."""
        sc, p, last = self.step_c, self.step_c.p, len(self.step_c.levels) - 1
        reports: list[LevelReport] = []
        status, previous = "ok", None
        for i, (ls, arrays) in enumerate(sc.levels):
            if ls.status == 0:
                break
            word = sc.level_status(i)
            if i >= solved:  # as Weighted.solve and Hierarchical.solve write a failed level
                gain, objective = (np.nan, np.nan) if self.hierarchical else (0.0, np.nan)
                reports.append(LevelReport(self.level_names[i], np.nan, gain, False, word,
                                           ls.iterations, ls.seconds, objective))  # fmt: skip
                status = word if i == 0 else f"partial: {word}"
                break
            # the buffer is the Function's: copied; the last level's answer is the applied
            C = applied if i == last else sc.costs[i](arrays["U"], p)[0].copy()
            own = float(C[self.rows[i]].sum())
            gain = 0.0
            if previous is not None:
                gain = float(sc.costs[i](previous, p)[0][self.rows[i]].sum()) - own
            objective = own + float(C[self.reg_rows].sum()) if self.hierarchical else own
            reports.append(LevelReport(self.level_names[i], own, gain, True, word, ls.iterations,
                                       ls.seconds, objective=objective))  # fmt: skip
            previous = arrays["U"]
        if applied is not None:
            for rep, rows in zip(reports, self.rows, strict=False):
                if rep.success:
                    rep.loss = float(applied[rows].sum()) - rep.cost if self.hierarchical else 0.0
        return reports, status

    # -- the memory --------------------------------------------------------------------
    def to_python(self) -> None:
        """The C controller's memory into the Python path's (``Controller``: the command
        in flight, the plan, the first level's answer; each level's warm start, its
        QP's active rows and the seed's promise)."""
        ctrl, sc = self.ctrl, self.step_c
        st, nx, N = sc.state, ctrl.nx, ctrl.problem.horizon
        ctrl.u_prev = sc.u_prev.copy()
        X, U = sc.plan_x.reshape(N + 1, nx).copy(), sc.plan_u.reshape(N, nx).copy()
        ctrl._plan = (X, U, st.plan_age) if st.has_plan else None
        m0 = self.models[0]
        ctrl._level_w = (
            [m0.result(sc.first.copy(), sc.p, *self._zero_multipliers(m0))[0]]
            if st.has_first
            else []
        )
        for solver, model, (ls, arrays) in zip(
            ctrl.strategy.solvers, self.models, sc.levels, strict=True
        ):
            model.qp.lam_a[:] = arrays["memory"]
            backend = solver.backend
            if not ls.warm:
                solver.warm, backend._promise = None, None
                continue
            w, lam_g, lam_x = model.result(
                arrays["U"].copy(), sc.p, arrays["lam_c"].copy(), arrays["lam_u"].copy()
            )
            solver.warm = NlpResult(w, lam_g, lam_x, ls.f, True, "Solve_Succeeded", 0, 0.0)
            backend._promise = ls.f

    def hand_over(self) -> None:
        """The solves of the step the C controller left to Python, for the Python path
        to take instead of solving again (``SqpBackend.precomputed``)."""
        sc, p = self.step_c, self.step_c.p
        for i, (solver, model, (ls, arrays)) in enumerate(
            zip(self.ctrl.strategy.solvers, self.models, sc.levels, strict=True)
        ):
            t = ls.tried
            if not t.valid:
                continue
            U = arrays["tried_U"].copy()
            w, lam_g, lam_x = model.result(U, p.copy(), arrays["tried_lam_c"].copy(),
                                           arrays["tried_lam_u"].copy())  # fmt: skip
            word = sc.level_status(i, tried=True)
            ok = word in SOLVER_SOLVED and bool(np.all(np.isfinite(w)))
            res = NlpResult(w, lam_g, lam_x, t.f, ok, word, t.iterations, t.seconds)
            solver.backend.precomputed = (res, arrays["tried_memory"].copy())

    @staticmethod
    def _zero_multipliers(model: object) -> tuple[np.ndarray, np.ndarray]:
        return np.zeros(model.nc), np.zeros(model.nU)  # type: ignore[attr-defined]

    def from_python(self) -> None:
        """The Python path's memory into the C controller's (``to_python``'s reverse)."""
        ctrl, sc = self.ctrl, self.step_c
        st = sc.state
        self.last_in_c = False
        for solver in ctrl.strategy.solvers:  # a solve handed over and not taken
            solver.backend.precomputed = None
        sc.u_prev[:] = ctrl.u_prev
        st.has_plan = int(ctrl._plan is not None)
        if ctrl._plan is not None:
            X, U, age = ctrl._plan
            sc.plan_x[:], sc.plan_u[:], st.plan_age = X.ravel(), U.ravel(), age
        else:
            st.plan_age = 0
        st.has_first = int(bool(ctrl._level_w))
        if ctrl._level_w:
            sc.first[:] = np.asarray(ctrl._level_w[0])[self.models[0].u_idx]
        for solver, model, (ls, arrays) in zip(
            ctrl.strategy.solvers, self.models, sc.levels, strict=True
        ):
            arrays["memory"][:] = model.qp.lam_a
            res = solver.warm
            ls.warm = int(res is not None and res.success)
            if not ls.warm:
                continue
            arrays["U"][:] = np.asarray(res.w)[model.u_idx]
            arrays["lam_c"][: model.nk] = np.asarray(res.lam_g)[model.keep]
            arrays["lam_c"][model.nk :] = np.asarray(res.lam_x)[model.state_idx]
            arrays["lam_u"][:] = np.asarray(res.lam_x)[model.u_idx]
            ls.f = float(res.f)
