"""The receding-horizon controller: one verb, ``step(state, t) -> Command``.

On a failed or over-budget solve it never raises: it applies the next command of the
last valid plan (shifted by the steps elapsed since it was computed, clipped to the
bounds) or, without one, stops (zero rates), and flags it in ``Command.status``.

Latency compensation: a command computed from the state measured at ``t`` takes effect
at ``t + latency`` (the solve, the link); until then the previous one flies. With
``latency_s > 0`` the controller plans from the state its model predicts at that time,
under the previous command, and against the references of that time.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

import numpy as np

from aeromanip.errors import ConfigError, StateError
from aeromanip.nmpc.command import Command
from aeromanip.nmpc.compiled_controller import StepInC
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.strategies import STRATEGIES, Strategy, StrategyResult

log = logging.getLogger(__name__)

STATUSES = ("ok", "partial", "fallback", "stopped")


class Controller:
    """NMPC controller for a ``Problem``.

    Args:
        problem: tasks, constraints, horizon.
        strategy: ``"weighted"`` or ``"hierarchical"`` (``STRATEGIES``), or a ``Strategy``
            subclass as ``"package.module:Class"``.
        backend: NLP solver: ``"ipopt"``, ``"fatrop"``, ``"sqp"`` (Gauss-Newton SQP, fast) or
            ``"sqp-rti"`` (one SQP iteration per step), or a ``Backend`` subclass as
            ``"package.module:Class"``; see ``aeromanip.nmpc.backends``.
        solver_options: extra options for the backend.
        hierarchy: options of ``Hierarchical`` (``mode``, ``rel_tol``, ``abs_tol``,
            ``regularizer_scale``).
        time_budget_s: a solve slower than this is treated as failed (None: no budget).
        latency_s: the time from measuring the state to the command taking effect [s],
            compensated by prediction (module docstring); 0: none.
    """

    def __init__(
        self,
        problem: Problem,
        strategy: str = "weighted",
        backend: str = "ipopt",
        solver_options: Mapping[str, Any] | None = None,
        hierarchy: Mapping[str, Any] | None = None,
        time_budget_s: float | None = None,
        latency_s: float = 0.0,
    ) -> None:
        self.problem = problem
        if not (0.0 <= latency_s < problem.dt):
            raise ConfigError(f"latency: must be in [0, dt = {problem.dt:g}) s, got {latency_s!r}")
        self.latency_s = float(latency_s)
        cls = STRATEGIES.get(strategy, "strategy")
        self.strategy: Strategy = cls.build(problem, backend, solver_options, hierarchy or {})
        self.time_budget_s = time_budget_s
        self.nx = problem.kin.nx
        self._in_c: StepInC | None = None
        self.reset()
        self._in_c = StepInC.for_controller(self)

    @property
    def compiled_step(self) -> bool:
        """Whether the step runs in one compiled call (``nmpc.compiled_controller``)."""
        return self._in_c is not None

    def sync_memory(self) -> None:
        """Bring the Python path's memory (the plan, each level's warm start) up to date
        with the compiled step's, e.g. before reading ``initial_guesses``."""
        if self._in_c is not None and self._in_c.last_in_c:
            self._in_c.to_python()

    def reset(self, u_prev: np.ndarray | None = None) -> None:
        """Forget plans and warm starts; ``u_prev`` is the command applied so far (default 0)."""
        self.u_prev = np.zeros(self.nx) if u_prev is None else self._vector(u_prev, "u_prev")
        self._rates: np.ndarray | None = None  # the actual rates at the plan's start
        self._plan: tuple[np.ndarray, np.ndarray, int] | None = None  # X, U, steps since
        self._level_w: list[np.ndarray] = []  # each level's last solution (warm starts)
        #: the memory before the last step (``discard``): u_prev, the plan, level solutions
        self._before: tuple[np.ndarray, Any, list[np.ndarray]] | None = None
        self.strategy.reset()
        self.problem.reset_tasks()
        if self._in_c is not None:
            self._in_c.step_c.reset(self.u_prev)
            self._in_c.last_in_c = False

    def _vector(self, v: Any, what: str) -> np.ndarray:
        """``v`` as nx finite floats, or a ``StateError`` naming what is wrong."""
        try:
            a = np.asarray(v, dtype=float).ravel()
        except (TypeError, ValueError):
            raise StateError(f"{what}: expected {self.nx} numbers, got {v!r:.60}") from None
        if a.shape != (self.nx,):
            names = ", ".join(self.problem.robot.state_names)
            raise StateError(f"{what}: expected {self.nx} values ({names}), got {a.size}")
        bad = np.nonzero(~np.isfinite(a))[0]
        if bad.size:
            name = self.problem.robot.state_names[bad[0]]
            raise StateError(f"{what}: {name} is not finite ({a[bad[0]]})")
        return a

    def _initial_guess(self, x0: np.ndarray) -> np.ndarray:
        """The last plan moved on to now, or (without one) rest at ``x0``."""
        if self._plan is not None:
            return self._shifted(x0, *self._plan[:2])
        N = self.problem.horizon
        X, U = np.repeat(x0[None, :], N + 1, axis=0), np.zeros((N, self.nx))
        return self.strategy.transcription.pack(X, U, self.u_prev, self._rates)

    def _shifted(self, x0: np.ndarray, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """A plan of the last flown solve moved on to now (last command repeated),
        starting from ``x0``: one step, or more after fallbacks and discards (the plan's
        age: it has flown ``age`` steps more since)."""
        steps = 1 + self._plan[2]  # a solution is kept only while its plan flies
        X = np.vstack([X[steps:], np.repeat(X[-1:], steps, axis=0)])
        U = np.vstack([U[steps:], np.repeat(U[-1:], steps, axis=0)])
        X[0] = x0
        return self.strategy.transcription.pack(X, U, self.u_prev, self._rates)

    def initial_guesses(self, x0: np.ndarray) -> list[np.ndarray | None]:
        """Per level: its own last solution moved on to now, if any (level 0: else the
        last plan)."""
        tr = self.strategy.transcription
        n = len(self.strategy.solvers)
        own = [self._shifted(x0, *tr.unpack(w)) for w in self._level_w[:n]]
        guesses: list[np.ndarray | None] = own + [None] * (n - len(own))
        if guesses[0] is None:
            guesses[0] = self._initial_guess(x0)
        return guesses

    def _start(self, x: np.ndarray, rates: np.ndarray | None) -> np.ndarray:
        """The plan's start: the measured state, or with latency the model's prediction
        of it when the command takes effect (the previous command flying until then)."""
        model = self.problem.model
        z0 = model.predict(model.initial(x, self.u_prev, rates), self.u_prev, self.latency_s)
        self._rates = model.rates_of(z0) if model.has_response else None
        return z0[: self.nx]

    def step(
        self, state: Any, t: float, rates: Any = None, wrench: Any = None, attitude: Any = None
    ) -> Command:
        """Solve the NMPC at time ``t`` [s] from ``state`` and return the command to apply.

        ``rates``: the measured actual rates ``dx/dt`` (used by a model with rate
        responses; default: the last command, as if followed at once). ``wrench``: the
        wrist force/torque sensor's reading ``[f, tau]`` [N, N m, world], received like
        the state and handed to the tasks (``Task.observe``); ``None``: no sensor.
        ``attitude``: the platform's measured ``(roll, pitch)`` [rad], for tasks that
        correct the NMPC's untilted kinematics with it; ``None``: not measured.
        """
        x_meas = self._vector(state, "state")
        if isinstance(t, bool) or not isinstance(t, int | float | np.number) or not np.isfinite(t):
            raise StateError(f"t: must be a finite number of seconds, got {t!r}")
        r0 = None if rates is None else self._vector(rates, "rates")
        tilt = None if attitude is None else tuple(float(a) for a in attitude)
        wrench = self._wrench(wrench)
        if self._in_c is None:
            self.problem.observe(x_meas, wrench, t, tilt)  # type: ignore[arg-type]
            return self._python_step(x_meas, t, r0)
        cmd = self._in_c.step(x_meas, t, r0)  # no task of it measures (``compilable``)
        if cmd is not None:
            return cmd
        self.sync_memory()  # the step is Python's (a seed): the memory comes from C
        self._in_c.hand_over()  # with the solves C made in it
        cmd = self._python_step(x_meas, t, r0)
        self._in_c.from_python()
        return cmd

    def _python_step(self, x_meas: np.ndarray, t: float, r0: np.ndarray | None) -> Command:
        """The step in Python (``step``'s inputs checked)."""
        self._before = (self.u_prev.copy(), self._plan, self._level_w)
        x0 = self._start(x_meas, r0)
        tr = self.strategy.transcription
        t_plan = t + self.latency_s
        p = tr.parameters(x0, self.u_prev, self.problem.stage_params(t_plan), self._rates)
        res: StrategyResult = self.strategy.solve(p, self.initial_guesses(x0))
        message = ("" if res.status == "ok" else res.status) + self._widened(p)
        ok = res.success
        if ok and self.time_budget_s is not None and res.solve_time_s > self.time_budget_s:
            ok = False
            message = (
                f"over budget: {1e3 * res.solve_time_s:.1f} ms > {1e3 * self.time_budget_s:.1f} ms"
            )
        if ok:
            X, U = tr.unpack(res.w)
            costs = tr.costs(res.w, p).sum(axis=1)
            task_costs = {
                e.name: float(c) for e, c in zip(self.problem.entries, costs, strict=True)
            }
            status = "partial" if res.status.startswith("partial") else "ok"
            self._plan = (X, U, 0)
            self._level_w = list(res.level_w)
            u = U[0].copy()
        else:
            message += self._outside_bounds(x0)
            u, X, U, status = self._fallback(x0)
            self._level_w = []
            task_costs = {e.name: float("nan") for e in self.problem.entries}
            log.warning("t=%.3f s: solve failed (%s); %s", t, message, status)
        self.u_prev = u
        return Command(
            u, X, U, task_costs, status, message, res.iterations, res.solve_time_s, res.levels,
            force_ff=self.problem.force_feedforward(X[0], X[min(1, len(X) - 1)]),
            observations=self.problem.observations(t),
        )  # fmt: skip

    @staticmethod
    def _wrench(wrench: Any) -> np.ndarray | None:
        """The sensor's reading as 6 finite floats, or a ``StateError`` naming it."""
        if wrench is None:
            return None
        try:
            w = np.asarray(wrench, dtype=float).ravel()
        except (TypeError, ValueError):
            raise StateError(f"wrench: expected 6 numbers, got {wrench!r:.60}") from None
        if w.shape != (6,) or not np.all(np.isfinite(w)):
            raise StateError(f"wrench: expected 6 finite numbers [f, tau], got {w.tolist()}")
        return w

    def discard(self) -> None:
        """Forget the last step's command and plan (e.g. it came too late to be flown):
        the previous plan flies on, one step older, and its command for now is taken as
        the command in flight (for the control-rate cost, the command-rate bounds, the
        latency prediction and the fallback)."""
        if self._in_c is not None and self._in_c.last_in_c:
            self._in_c.step_c.discard()
            self.u_prev = self._in_c.step_c.u_prev.copy()
            return
        self._python_discard()
        if self._in_c is not None:
            self._in_c.from_python()

    def _python_discard(self) -> None:
        if self._before is None:
            return
        u_prev, plan, self._level_w = self._before
        self._before = None
        self.u_prev, self._plan = u_prev, None
        if plan is not None and plan[2] + 1 < len(plan[1]):
            Xp, Up, age = plan
            self._plan = (Xp, Up, age + 1)
            self.u_prev = Up[age + 1].copy()
        else:  # no plan flies: none of its solutions is a guess either
            self._level_w = []

    def _widened(self, p: np.ndarray) -> str:
        """Which DoFs' state box this solve widened to keep a plan feasible, and by how
        much (``Transcription.variable_bounds``); empty when none."""
        wide = self.strategy.transcription.box_widening(p)
        names = self.problem.robot.state_names
        out = [f"{n} +{v:.3g}" for n, v in zip(names, wide, strict=True) if v > 0]
        return f" (state box widened: {', '.join(out)})" if out else ""

    def _outside_bounds(self, x0: np.ndarray) -> str:
        """Why a solve may fail that no solver can help: the state beyond its hard bounds."""
        b, names = self.problem.bounds, self.problem.robot.state_names
        out = [
            f"{n} = {v:.4g} outside [{lo:.4g}, {hi:.4g}]"
            for n, v, lo, hi in zip(names, x0, b.x_lower, b.x_upper, strict=True)
            if not lo <= v <= hi
        ]
        return f" (state {'; '.join(out)})" if out else ""

    def _fallback(self, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
        b = self.problem.bounds
        N = self.problem.horizon
        if self._plan is not None:
            Xp, Up, age = self._plan
            age += 1
            if age < N:
                self._plan = (Xp, Up, age)
                u = np.clip(Up[age], b.u_lower, b.u_upper)
                return u, Xp, Up, "fallback"
            self._plan = None
        X = np.repeat(x0[None, :], N + 1, axis=0)
        return np.zeros(self.nx), X, np.zeros((N, self.nx)), "stopped"
