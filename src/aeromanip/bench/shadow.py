"""IPOPT in the shadow of a controller: the same inputs at every step, the answers compared.

Closed loops of two solvers part where the NLP has several local optima; from there on
they solve different problems, so the benchmark also compares, step by step, what each
solver answers to the very same inputs.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from aeromanip.nmpc.backends.base import SolveRequest, make_backend
from aeromanip.nmpc.controller import Command, Controller
from aeromanip.nmpc.strategies import Hierarchical

REF_OPTIONS = {"ipopt.tol": 1e-10}  # the reference answers: IPOPT converged tightly
# restarted at an answer, IPOPT's barrier must start small or it leaves the answer
RESTART = {"ipopt.mu_init": 1e-10, "ipopt.warm_start_bound_push": 1e-10}


class IpoptShadow:
    """IPOPT on the very NLPs a converged weighted controller solves, step by step.

    Closed loops of two solvers can part where the NLP has several local optima (a fast
    reference with binding velocity bounds has): from there on they solve different
    NLPs. The shadow compares answers where the inputs are identical. At each step it
    solves the controller's NLP (same state, previous command, time) with IPOPT
    (``REF_OPTIONS``) twice: from the controller's own initial guess (same answer, or
    another local optimum?), and restarted at the controller's answer with its
    multipliers and a small barrier parameter (``RESTART``): if IPOPT stays there, the
    answer is a local optimum to IPOPT's tolerance too.
    """

    def __init__(self, ctrl: Controller) -> None:
        self.ctrl = ctrl
        self.stage = ctrl.strategy.solvers[0]
        self.ipopt = make_backend(self.stage.tr, "ipopt", REF_OPTIONS)
        # restarted at an answer, IPOPT's barrier must start small or it leaves the answer
        self.restart = make_backend(self.stage.tr, "ipopt", {**REF_OPTIONS, **RESTART})
        self.records: list[tuple[float, float, float, float]] = []
        self.ipopt_failures = 0  # steps where IPOPT did not converge: not compared

    def before(self, x: np.ndarray, t: float) -> tuple[np.ndarray, list]:
        """The NLP's parameters and the controller's initial guesses, before its step."""
        c = self.ctrl
        c.sync_memory()
        p = self.stage.tr.parameters(x, c.u_prev, c.problem.stage_params(t))
        return p, c.initial_guesses(x)

    def after(self, p: np.ndarray, guesses: list, cmd: Command) -> None:
        """Solve with IPOPT and record the differences (commands [rad/s, m/s], costs)."""
        self.ctrl.sync_memory()  # the answer's multipliers, from a compiled step
        tr, ans = self.stage.tr, self.stage.warm
        if ans is None or not ans.success:
            return
        same = self.ipopt.solve(SolveRequest(guesses[0], p, tr.lbg, tr.ubg))
        cert = self.restart.solve(
            SolveRequest(ans.w, p, tr.lbg, tr.ubg, ans.lam_g, ans.lam_x, shift=False)
        )
        if not (same.success and cert.success):
            self.ipopt_failures += 1
            return
        u0 = tr.unpack(ans.w)[1][0]
        self.records.append(
            (
                float(np.abs(tr.unpack(same.w)[1][0] - u0).max()),
                (same.f - ans.f) / max(abs(ans.f), 1e-12),
                float(np.abs(tr.unpack(cert.w)[1][0] - u0).max()),
                (cert.f - ans.f) / max(abs(ans.f), 1e-12),
            )
        )

    def summary(self, tol: float = 1e-4) -> dict[str, Any]:
        """Agreement over the run; an "other optimum" step differs by more than ``tol``."""
        r = np.array(self.records).reshape(-1, 4)
        return _agreement(r[:, 0], r[:, 1] > 0, self.ipopt_failures, tol) | {
            "shadow_certified_max_du": float(r[:, 2].max(initial=0.0)),
            "shadow_certified_max_rel_cost": float(np.abs(r[:, 3]).max(initial=0.0)),
        }


def _agreement(
    du: np.ndarray, ipopt_worse: np.ndarray, failures: int, tol: float
) -> dict[str, Any]:
    """Shadow statistics from each step's command difference ``du`` and whether IPOPT's
    answer was the costlier; a step with ``du > tol`` reached another optimum."""
    other = du > tol
    return {
        "shadow_steps": len(du),
        "shadow_ipopt_failures": failures,
        "shadow_same_guess_max_du": float(du[~other].max(initial=0.0)),
        "shadow_other_optimum_steps": int(other.sum()),
        "shadow_other_optimum_ipopt_cost_higher": int(ipopt_worse[other].sum()),
    }


class IpoptHierarchyShadow:
    """The hierarchy's answer against IPOPT's on the same inputs, step by step.

    At each step the controller's hierarchy (state, previous command, time, the initial
    guess) is solved again by the same strategy with IPOPT (``REF_OPTIONS``, each lower
    level starting from the level above's solution, as IPOPT wants a feasible start): the
    commands are compared, and where they differ, the levels' optimal costs in their
    order of priority say which answer is the better one.
    """

    def __init__(self, ctrl: Controller) -> None:
        h = ctrl.strategy
        self.ctrl = ctrl
        self.ref = Hierarchical(ctrl.problem, h.mode, h.rel_tol, h.abs_tol, "ipopt", REF_OPTIONS)
        self.records: list[tuple[float, float]] = []
        self.ipopt_failures = 0

    def before(self, x: np.ndarray, t: float) -> tuple[np.ndarray, list]:
        """The parameters and the controller's initial guesses, before its step."""
        c = self.ctrl
        c.sync_memory()
        tr = c.strategy.transcription
        return tr.parameters(x, c.u_prev, c.problem.stage_params(t)), c.initial_guesses(x)

    def after(self, p: np.ndarray, guesses: list, cmd: Command) -> None:
        """Solve the hierarchy with IPOPT; record the command difference and which
        answer is better (+1: the controller's, -1: IPOPT's) by the levels in order."""
        mine = cmd.levels
        if cmd.status != "ok" or not all(lv.success for lv in mine):
            return
        ref = self.ref.solve(p, guesses)
        if not ref.success or not all(lv.success for lv in ref.levels):
            self.ipopt_failures += 1
            return
        u_ref = self.ref.transcription.unpack(ref.w)[1][0]
        better = 0.0
        for a, b in zip(mine, ref.levels, strict=True):
            if abs(a.cost - b.cost) > 1e-6 * max(abs(a.cost), abs(b.cost), 1e-9):
                better = 1.0 if a.cost < b.cost else -1.0
                break
        self.records.append((float(np.abs(u_ref - cmd.u).max()), better))

    def summary(self, tol: float = 1e-4) -> dict[str, Any]:
        """Agreement over the run; an "other optimum" step differs by more than ``tol``."""
        r = np.array(self.records).reshape(-1, 2)
        return _agreement(r[:, 0], r[:, 1] > 0, self.ipopt_failures, tol)
