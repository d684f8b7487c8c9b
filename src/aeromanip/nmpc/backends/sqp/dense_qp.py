"""Dense convex QPs for the SQP: a dual active-set solver on the rows that may bind.

``min 1/2 d'Hd + g'd  s.t.  lba <= A d <= uba,  lbx <= d <= ubx`` with ``H`` positive
definite, solved by DAQP (dual active set, through CasADi) or qpOASES. Its cost grows with
the rows, and in an NMPC most rows (state bounds, clearance at every stage) are far from
binding: the solver gets first the rows near their bounds, active at the last solve (moved
one stage on with the horizon: ``shift()``) or always wanted; rows the solution crosses
are added and it is solved again (after ``SCREEN_ROUNDS`` the full QP is solved), so the
result is the full QP's. Multipliers follow
CasADi's sign convention (``> 0`` at an upper bound).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends.base import casadi_message
from aeromanip.nmpc.backends.codegen import Buffered, quiet_stdout

SCREEN_ROUNDS = 4  # solves on screened rows before the full QP is solved
PADDED_SIZES = (8, 16, 24, 32, 48, 64)  # row counts of the prebuilt solvers (and m)
CROSS_TOL = 1e-6  # a row is crossed beyond this, relative to 1 + |d|_inf
# DAQP's primal tolerance: 1e-2 of the SQP's default tol, as the sparse QP's residuals
# (hpipm.QP_TOL_SHARE). At 1e-9 DAQP called a feasible QP of the stress bench's
# ``clearance`` hierarchy infeasible (HiGHS: feasible; DAQP at 3e-9 or looser: solved,
# rows held to 2.3e-9), and the step was partial
DAQP_PRIMAL_TOL = 1e-8
SOLVERS: dict[str, dict[str, Any]] = {
    "daqp": {"daqp": {"primal_tol": DAQP_PRIMAL_TOL, "iter_limit": 2000}},
    "qpoases": {"printLevel": "none", "sparse": False},
}
#: DAQP's exit flags (its ``types.h``), which CasADi reports as the bare number
DAQP_EXIT_FLAGS = {
    1: "optimal",
    2: "soft optimal",
    -1: "infeasible",
    -2: "cycling",
    -3: "unbounded",
    -4: "iteration limit",
    -5: "nonconvex",
    -6: "overdetermined initial active set",
    -7: "time limit",
}


def status_text(solver: str, status: Any) -> str:
    """A QP solver's return status as words: DAQP's exit flag by its name."""
    if solver == "daqp" and status in DAQP_EXIT_FLAGS:
        return f"{DAQP_EXIT_FLAGS[status]} (DAQP exit flag {status})"
    return str(status)


def failure_text(
    solver: str, return_status: Any, success: bool, finite: bool, excess: float
) -> str:
    """Why a QP answer is not taken: the solver's status (if it did not report success)
    or what is wrong with its answer (not finite, or across its bounds by more than
    ``CROSS_TOL``: ill-conditioned data)."""
    status = status_text(solver, return_status)
    if not success:
        return status
    if not finite:
        return f"{status}, but the answer is not finite"
    return f"{status}, but the answer crosses its bounds by {excess:.1e}"


def _failure(solver: str, stats: dict[str, Any], d: np.ndarray, excess: float) -> str:
    """``failure_text`` from a CasADi QP solver's stats."""
    status, success = stats.get("return_status", "?"), bool(stats.get("success"))
    return failure_text(solver, status, success, bool(np.isfinite(d).all()), excess)


@dataclass
class QpResult:
    """Step ``d``, multipliers of the rows and of the bounds, outcome."""

    d: np.ndarray
    lam_a: np.ndarray
    lam_x: np.ndarray
    ok: bool
    status: str


class DenseQp:
    """A reusable solver for QPs of fixed size ``n`` variables, ``m`` rows.

    Args:
        n, m: sizes.
        solver: ``"daqp"`` or ``"qpoases"``; options: its extra options.
        screen: rows whose slack (at d = 0) is this or more are left out of the solver's
            first try.
        always: rows always given to the solver (e.g. those that bind by design).
        shift_rows: for each row, the one that predicts it after the horizon moves a step
            on (``shift()``).
    """

    def __init__(
        self,
        n: int,
        m: int,
        solver: str = "daqp",
        options: dict[str, Any] | None = None,
        screen: float = 0.1,
        always: np.ndarray | None = None,
        shift_rows: np.ndarray | None = None,
    ) -> None:
        if solver not in SOLVERS:
            raise ConfigError(f"solver_options.qpsol: {solver!r} is not one of {list(SOLVERS)}")
        self.n, self.m, self.solver, self.screen = n, m, solver, screen
        self.opts = {"error_on_fail": False, "print_time": False, **SOLVERS[solver]}
        self.opts.update(options or {})
        self.always = np.zeros(m, dtype=bool) if always is None else always
        self.shift_rows = np.arange(m) if shift_rows is None else shift_rows
        self._sizes = sorted({k for k in PADDED_SIZES if k < m} | {m})
        self._solvers: dict[int, Buffered] = {}
        self.lam_a = np.zeros(m)  # the last multipliers: their rows go to the solver
        self._solver(m)

    @staticmethod
    def check_options(solver: str, options: dict[str, Any]) -> None:
        """A QP solver that exists and takes ``options`` (tried on a one-variable QP)."""
        if solver not in SOLVERS:
            raise ConfigError(f"solver_options.qpsol: {solver!r} is not one of {list(SOLVERS)}")
        opts = {"error_on_fail": False, "print_time": False, **SOLVERS[solver], **options}
        try:
            with quiet_stdout():
                qp = ca.conic("aeromanip_check", solver, {"h": ca.Sparsity.dense(1, 1)}, opts)
                qp(h=1.0, g=0.0, lbx=-1.0, ubx=1.0)
        except RuntimeError as e:
            raise ConfigError(
                f"solver_options.qpsol_options: {solver} rejects them: {casadi_message(e)}"
            ) from None

    def reset(self) -> None:
        """Forget the last multipliers."""
        self.lam_a[:] = 0.0

    def shift(self) -> None:
        """Predict the active rows of the next control step (the horizon one step on)."""
        self.lam_a = self.lam_a[self.shift_rows]

    def solve(
        self,
        H: np.ndarray,
        g: np.ndarray,
        A: np.ndarray,
        lba: np.ndarray,
        uba: np.ndarray,
        lbx: np.ndarray,
        ubx: np.ndarray,
    ) -> QpResult:
        """Solve (see module docstring); the working set is kept for the next call."""
        res = self._active_set(H, g, A, lba, uba, lbx, ubx)
        if res.ok:
            self.lam_a = res.lam_a.copy()  # ``reset`` must not change a returned result
        return res

    # -- the active-set solver ----------------------------------------------------------------
    def _solver(self, k: int) -> Buffered:
        """The solver for ``k`` rows (built on first use)."""
        if k not in self._solvers:
            with quiet_stdout():  # qpOASES prints a banner when created
                qp = ca.conic(
                    f"aeromanip_qp{k}",
                    self.solver,
                    {"h": ca.Sparsity.dense(self.n, self.n), "a": ca.Sparsity.dense(k, self.n)},
                    self.opts,
                )
                b = Buffered(qp)
            b.views = {qp.name_in(i): b.args[i] for i in range(qp.n_in())}
            b.views["a"] = b.args[qp.index_in("a")].reshape(k, self.n, order="F")
            b.out = {qp.name_out(i): b.res[i] for i in range(qp.n_out())}
            self._solvers[k] = b
        return self._solvers[k]

    def _active_set(
        self,
        H: np.ndarray,
        g: np.ndarray,
        A: np.ndarray,
        lba: np.ndarray,
        uba: np.ndarray,
        lbx: np.ndarray,
        ubx: np.ndarray,
    ) -> QpResult:
        near = self.always | (self.lam_a != 0.0) | (np.minimum(-lba, uba) < self.screen)
        for _ in range(SCREEN_ROUNDS):
            rows = np.nonzero(near)[0]
            k = next(s for s in self._sizes if s >= rows.size)
            if k == self.m:
                break
            d, lam_r, lam_x, status = self._solve_rows(H, g, A, lba, uba, lbx, ubx, rows, k)
            if status:
                return QpResult(d, np.zeros(self.m), lam_x, False, status)
            tol = CROSS_TOL * (1.0 + np.abs(d).max(initial=0.0))
            Ad = A @ d
            crossed = ((Ad < lba - tol) | (Ad > uba + tol)) & ~near
            if not crossed.any():
                lam = np.zeros(self.m)
                lam[rows] = lam_r[: rows.size]
                return QpResult(d, lam, lam_x, True, "")
            near |= crossed
        # every row: the full QP (screening did not settle, or nothing was left out)
        d, lam, lam_x, status = self._solve_rows(
            H, g, A, lba, uba, lbx, ubx, np.arange(self.m), self.m
        )
        return QpResult(d, np.zeros(self.m) if status else lam, lam_x, not status, status)

    def _solve_rows(
        self,
        H: np.ndarray,
        g: np.ndarray,
        A: np.ndarray,
        lba: np.ndarray,
        uba: np.ndarray,
        lbx: np.ndarray,
        ubx: np.ndarray,
        rows: np.ndarray,
        k: int,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
        """The QP with the rows ``rows`` only (padded with free rows to ``k``)."""
        q = self._solver(k)
        v, r = q.views, rows.size
        v["h"][:] = H.ravel()  # symmetric: either order
        v["g"][:] = g
        Am = v["a"]  # (k, n) Fortran-order view of the argument buffer
        Am[:r] = A[rows]
        Am[r:] = 0.0
        v["lba"][:r], v["uba"][:r] = lba[rows], uba[rows]
        v["lba"][r:], v["uba"][r:] = -np.inf, np.inf
        v["lbx"][:], v["ubx"][:] = lbx, ubx
        q.run()
        d = q.out["x"].copy()
        # a finite, feasible solution means success: cheaper than asking for the stats
        tol = CROSS_TOL * (1.0 + np.abs(d).max(initial=0.0))
        Ad = Am[:r] @ d
        excess = max(
            (lba[rows] - Ad).max(initial=0.0),
            (Ad - uba[rows]).max(initial=0.0),
            (lbx - d).max(initial=0.0),
            (d - ubx).max(initial=0.0),
        )
        ok = bool(np.isfinite(d).all() and excess <= tol)
        status = "" if ok else _failure(self.solver, q.buf.stats(), d, excess)
        return d, q.out["lam_a"].copy(), q.out["lam_x"].copy(), status
