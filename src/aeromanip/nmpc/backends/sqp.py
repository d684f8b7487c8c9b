"""SQP backend ``sqp`` (and real-time iterations ``sqp-rti``) for a ``Transcription``.

How it is built, and why:

* **Gauss-Newton first.** Every cost is a weighted sum of squared residuals
  ``f = ||R(w)||^2``, so ``2 J^T J`` (``J = dR/dw``) is a positive semi-definite Hessian
  that needs no second derivatives; the gradient ``2 J^T R`` is exact, so the fixed points
  are the NLP's KKT points (the optimum IPOPT finds). Where residuals are large (a
  reference faster than the velocity bounds allow) Gauss-Newton converges slowly or
  zig-zags: with ``hessian="auto"`` a solve switches to the exact Hessian of ``f`` at
  its first shortened step or 7th iteration. Where it is indefinite, a penalty on the
  active constraints' normals makes it positive definite without changing the step on
  that active set (Newton's convergence kept); only where that fails are the
  eigenvalues reflected.
* **Exact condensing.** The model ``x[k+1] = x[k] + dt u[k]``, ``v[k+1] = u[k]`` is linear,
  so the states are affine in the commands ``U``: the multiple-shooting NLP is solved in
  ``U`` alone (``N nx`` variables), the gap rows holding exactly. For N = 10 the dense QP
  is as cheap as a Riccati-based one, and it is solved by a dual active-set method
  (``nmpc.backends.qp``: DAQP on the rows that may bind).
* **Hierarchy rows** ``c_r = ||R_r||^2 <= b_r`` (stage-wise, ``Hierarchical``) are
  linearised, and their curvature enters the Hessian as ``2 lam_r J_r^T J_r`` (the
  Gauss-Newton part of the constraint's Hessian, positive semi-definite since
  ``lam_r >= 0``), ``lam_r`` from the last QP: the linearisation of a squared norm alone
  says nothing near its minimum, and with this term the QP sees the ball it must stay in.
  Each level starts from its own previous solution, shifted (no feasible start needed).
* **Globalisation:** an l1 merit function with Armijo backtracking.
* **Stopping:** stationarity ``||grad f + A^T lam||_inf``, constraint violation and
  complementarity all ``<= tol`` (default ``1e-6``), at each new iterate with the last
  QP's multipliers; or, as IPOPT's acceptable level, stationarity and complementarity
  ``<= acceptable_tol`` (violation ``<= constr_viol_tol``) for ``acceptable_iter``
  iterations in a row (the hierarchy's cost bounds are degenerate where a higher
  level's optimum is ~0: convergence there is linear).
* **Real-time iteration** (``rti=True``): one Gauss-Newton QP and a full step per call,
  from the shifted previous solution; successful if the QP is. Iterated, it converges to
  the same optimum.

The model Functions are compiled to C once and cached (``nmpc.backends.codegen``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends.base import BACKENDS, Backend, NlpResult
from aeromanip.nmpc.backends.codegen import Buffered, compiled_all, limit_blas_threads
from aeromanip.nmpc.backends.kkt import complementarity, convexified, l1, violation
from aeromanip.nmpc.backends.qp import SOLVERS as QP_SOLVERS
from aeromanip.nmpc.backends.qp import DenseQp
from aeromanip.nmpc.transcription import Transcription, shift_map

DEFAULTS: dict[str, Any] = {
    "max_iter": 50,  # QPs per solve
    "tol": 1e-6,  # KKT tolerance (stationarity, complementarity, constraint violation)
    # as IPOPT's "acceptable level": stationarity and complementarity <= acceptable_tol
    # and violation <= constr_viol_tol for acceptable_iter iterations in a row (or at
    # max_iter) end a solve successfully
    "acceptable_tol": 1e-5,
    "constr_viol_tol": 1e-6,
    "acceptable_iter": 5,
    "rti": False,  # one QP per solve
    "codegen": True,  # compile the model Functions to C (cached on disk)
    # "gauss-newton", "exact" (made positive definite), or "auto": Gauss-Newton,
    # exact from the first shortened step or the 7th iteration of a solve on
    "hessian": "auto",
    "regularization": 1e-9,  # added to the Hessian's diagonal
    "qpsol": "daqp",  # dense QP solver: "daqp" (dual active set) or "qpoases"
    "qpsol_options": {},  # extra options of the QP solver
    "screen": 0.1,  # QP rows farther than this from their bounds are left out at first
    "blas_threads": 1,  # OpenBLAS threads in this process (None: leave as is)
}
HESSIANS = ("auto", "exact", "gauss-newton")


def _int_at_least(low: int) -> Callable[[Any], str]:
    def check(v: Any) -> str:
        ok = isinstance(v, int) and not isinstance(v, bool) and v >= low
        return "" if ok else f"an integer >= {low}"

    return check


def _number(positive: bool) -> Callable[[Any], str]:
    def check(v: Any) -> str:
        ok = isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
        ok = ok and (v > 0 if positive else v >= 0)
        return "" if ok else ("a finite number > 0" if positive else "a finite number >= 0")

    return check


def _one_of(choices: Sequence[Any]) -> Callable[[Any], str]:
    return lambda v: "" if v in choices else f"one of {list(choices)}"


#: per option: what it must be ("" when the value is fine)
OPTION_CHECKS: dict[str, Callable[[Any], str]] = {
    "max_iter": _int_at_least(1),
    "tol": _number(positive=False),  # 0: only the acceptable level ends a solve
    "acceptable_tol": _number(positive=True),
    "constr_viol_tol": _number(positive=True),
    "acceptable_iter": _int_at_least(1),
    "rti": lambda v: "" if isinstance(v, bool) else "true or false",
    "codegen": lambda v: "" if isinstance(v, bool) else "true or false",
    "hessian": _one_of(HESSIANS),
    "regularization": _number(positive=False),
    "qpsol": _one_of(tuple(QP_SOLVERS)),
    "qpsol_options": lambda v: "" if isinstance(v, Mapping) else "a table",
    "screen": _number(positive=False),
    "blas_threads": lambda v: "" if v is None or _int_at_least(1)(v) == "" else "an integer >= 1",
}
EXACT_FROM_ITERATION = 6  # "auto": the exact Hessian from this (0-based) iteration on
ARMIJO = 1e-4  # sufficient decrease of the l1 merit, per unit of its directional derivative
BACKTRACK = 0.5  # step-length factor per rejected trial
MIN_STEP = 1e-3  # the shortest step tried; taken as it is
PENALTY_MARGIN = 1.1  # the merit's penalty exceeds the largest multiplier by this factor
PENALTY_FLOOR = 1e-8  # and by at least this


@BACKENDS.register("sqp")
class SqpBackend(Backend):
    """SQP with Gauss-Newton (or exact) Hessians and exact condensing (module docstring).

    Args:
        transcription: the NLP (its layout is kept for inputs and results).
        options: keys of ``DEFAULTS``.
    """

    name = "sqp"
    defaults: ClassVar[dict[str, Any]] = DEFAULTS

    def __init__(
        self, transcription: Transcription, options: Mapping[str, Any] | None = None
    ) -> None:
        self.opts = self.checked_options(options)
        self.tr = tr = transcription
        self.nU = tr.N * tr.nx
        U, p = ca.SX.sym("U", self.nU), ca.SX.sym("p", tr.p.numel())
        R, gc, Rh = self._condensed(U, p)
        self._compile(U, p, R, gc, Rh)
        self._qp_setup()
        if self.opts["blas_threads"] is not None:
            limit_blas_threads(int(self.opts["blas_threads"]))

    @classmethod
    def checked_options(cls, options: Mapping[str, Any] | None) -> dict[str, Any]:
        """The defaults updated with ``options``; an unknown key or a bad value is a
        ``ConfigError`` naming the key, the value and what is allowed (checked before
        anything is built)."""
        if options is not None and not isinstance(options, Mapping):
            raise ConfigError(f"solver_options: must be a table, got {options!r}")
        unknown = set(options or {}) - set(DEFAULTS)
        if unknown:
            raise ConfigError(
                f"solver_options.{sorted(unknown)[0]}: unknown sqp option "
                f"(known: {', '.join(DEFAULTS)})"
            )
        opts = {**cls.defaults, **dict(options or {})}
        for key, check in OPTION_CHECKS.items():
            allowed = check(opts[key])
            if allowed:
                raise ConfigError(f"solver_options.{key}: {opts[key]!r} is not {allowed}")
        DenseQp.check_options(opts["qpsol"], opts["qpsol_options"])
        return opts

    @classmethod
    def check_options(cls, options: Mapping[str, Any]) -> None:
        """See ``checked_options``."""
        cls.checked_options(options)

    def _condensed(self, U: ca.SX, p: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX]:
        """The NLP in the commands ``U`` alone: objective residuals ``R``, the rows that
        may bind ``gc`` (path and hierarchy rows, then the state bounds as rows of ``U``)
        and the hierarchy rows' residuals ``Rh``. Sets the index maps between layouts."""
        tr, N, nx = self.tr, self.tr.N, self.tr.nx
        x, v, parts = p[:nx], p[nx : 2 * nx], []
        for k in range(N + 1):  # the model is linear: the states are affine in U
            parts += [x, v]
            if k < N:
                uk = U[k * nx : (k + 1) * nx]
                parts.append(uk)
                x, v = x + tr.problem.dt * uk, uk
        wU = ca.vertcat(*parts)
        hier = [r for _, r in tr.hier_residuals]
        ms = ca.Function("ms", [tr.w, tr.p], [tr.residuals, tr.g, ca.vertcat(*hier)])
        # dense: a zero weight makes a residual entry a structural zero, and the buffers
        # hold nonzeros only
        R, g, Rh = (ca.densify(e) for e in ms(wU, p))
        gap = set(tr.gap_rows)
        self.keep = np.array([i for i in range(tr.g.numel()) if i not in gap], dtype=int)
        # state bounds become linear rows of U (stage 0 is the measured state: not bounded)
        lbw, ubw, s = tr.lbw, tr.ubw, tr.stride
        sidx = [
            k * s + i
            for k in range(1, N + 1)
            for i in range(nx)
            if np.isfinite(lbw[k * s + i]) or np.isfinite(ubw[k * s + i])
        ]
        self.state_idx = np.array(sidx, dtype=int)
        self.u_idx = np.array([k * s + tr.nz + i for k in range(N) for i in range(nx)], dtype=int)
        self.nk = len(self.keep)
        self.lb_state, self.ub_state = lbw[self.state_idx], ubw[self.state_idx]
        return R, ca.vertcat(g[self.keep.tolist()], wU[sidx]), Rh

    def _compile(self, U: ca.SX, p: ca.SX, R: ca.SX, gc: ca.SX, Rh: ca.SX) -> None:
        """Build the model Functions (data, merit, exact Hessian) and compile them to C."""
        tr = self.tr
        tag = f"{len(tr.hier_residuals)}h{tr.N}x{tr.nx}"
        J, A, Jh = (ca.densify(ca.jacobian(e, U)) for e in (R, gc, Rh))
        with_exact = self.opts["hessian"] != "gauss-newton" and not self.opts["rti"]
        data = ca.Function(f"aeromanip_sqp_data_{tag}", [U, p], [R, J, gc, A, Jh])
        merit = ca.Function(f"aeromanip_sqp_merit_{tag}", [U, p], [ca.sumsqr(R), gc])
        fs = [data, merit, tr.stage_costs]
        if with_exact:
            Hf = ca.densify(ca.hessian(ca.sumsqr(R), U)[0])
            fs.append(ca.Function(f"aeromanip_sqp_hess_{tag}", [U, p], [Hf]))
        fs = compiled_all(fs, self.opts["codegen"])  # built in parallel, once, cached
        self.data, self.merit = Buffered(fs[0]), Buffered(fs[1])
        tr.use_stage_costs(fs[2])
        self.hess = Buffered(fs[3]) if with_exact else None
        self.nr, self.nc, self.nh = R.numel(), gc.numel(), Rh.numel()

    def _qp_setup(self) -> None:
        """Command bounds, the rows that bind by design, shift maps and the QP solver."""
        tr, nx, nU = self.tr, self.tr.nx, self.nU
        self.lbU = np.tile(tr.problem.bounds.u_lower, tr.N)
        self.ubU = np.tile(tr.problem.bounds.u_upper, tr.N)
        row_of = {r: i for i, r in enumerate(self.keep)}
        self.hier_elem_row = np.concatenate(
            [np.full(r.numel(), row_of[row], dtype=int) for row, r in tr.hier_residuals]
            or [np.zeros(0, dtype=int)]
        )
        always = np.zeros(self.nc, dtype=bool)
        always[[row_of[r] for rows in tr.hier_rows for r in rows]] = True  # bind by design
        # which row predicts each one when the horizon moves a step on (as the NLP's)
        shift_rows = shift_map(
            [(tr.g_kind[r], tr.g_stage[r]) for r in self.keep]
            + [(f"state{i % tr.stride}", i // tr.stride) for i in self.state_idx]
        )
        self.shift_vars = np.arange(nU) + nx
        self.shift_vars[self.shift_vars >= nU] -= nx  # the last command predicts itself
        o = self.opts
        self.qp = DenseQp(
            nU, self.nc, o["qpsol"], o["qpsol_options"], o["screen"], always, shift_rows
        )

    # -- layout conversions --------------------------------------------------------------
    def _to_w(self, Uv: np.ndarray, p: np.ndarray) -> np.ndarray:
        tr, nx, N = self.tr, self.tr.nx, self.tr.N
        Um = Uv.reshape(N, nx)
        X = np.vstack([p[:nx], p[:nx] + tr.problem.dt * np.cumsum(Um, axis=0)])
        return tr.pack(X, Um, p[nx : 2 * nx])

    def _duals_out(self, lam_c: np.ndarray, lam_u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lam_g = np.zeros(self.tr.g.numel())
        lam_g[self.keep] = lam_c[: self.nk]
        lam_x = np.zeros(self.tr.w.numel())
        lam_x[self.state_idx] = lam_c[self.nk :]
        lam_x[self.u_idx] = lam_u
        return lam_g, lam_x

    def _duals_in(
        self, lam_g: np.ndarray | None, lam_x: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        lam_c, lam_u = np.zeros(self.nc), np.zeros(self.nU)
        if lam_g is not None and lam_x is not None:
            lam_c[: self.nk] = np.asarray(lam_g)[self.keep]
            lam_c[self.nk :] = np.asarray(lam_x)[self.state_idx]
            lam_u[:] = np.asarray(lam_x)[self.u_idx]
        return lam_c, lam_u

    # -- the solve ----------------------------------------------------------------------
    def solve(
        self,
        w0: np.ndarray,
        p: np.ndarray,
        lbg: np.ndarray,
        ubg: np.ndarray,
        lam_g0: np.ndarray | None = None,
        lam_x0: np.ndarray | None = None,
        shift: bool = True,
    ) -> NlpResult:
        """Solve from the primal guess ``w0`` (its commands are used) and multipliers: the
        last control step's, moved a stage on here (``shift=False``: this step's). The
        multipliers returned leave the model rows at 0 (condensed away)."""
        t0 = time.perf_counter()
        o = self.opts
        Uv = np.clip(np.asarray(w0, dtype=float)[self.u_idx], self.lbU, self.ubU)
        lbc = np.concatenate([lbg[self.keep], self.lb_state])
        ubc = np.concatenate([ubg[self.keep], self.ub_state])
        lam_c, lam_u = self._initial_duals(lam_g0, lam_x0, shift)
        p = np.asarray(p, dtype=float)
        reg = o["regularization"]
        mu, it, status, ok, f = 0.0, 0, "", False, np.nan
        exact = o["hessian"] == "exact"
        max_iter = 1 if o["rti"] else int(o["max_iter"])
        acceptable = 0  # iterations in a row at the acceptable level
        while True:
            R, J, gc, A, Jh = self.data(Uv, p)
            J = J.reshape(self.nr, self.nU, order="F")
            A = A.reshape(self.nc, self.nU, order="F")
            f = float(R @ R)
            grad = 2.0 * (J.T @ R)
            if not np.isfinite(f):  # NaN in derivatives shows in the QP's solution
                status = "Invalid_Number_Detected"
                break
            viol = 0.0 if o["rti"] else violation(gc, lbc, ubc)
            kkt = np.inf  # the larger of stationarity and complementarity
            if not o["rti"] and (it > 0 or lam_g0 is not None) and viol <= o["constr_viol_tol"]:
                kkt = self._kkt_error(Uv, gc, lbc, ubc, grad, A, lam_c, lam_u)
                if kkt <= o["tol"] and viol <= o["tol"]:
                    ok, status = True, "Solve_Succeeded"
                    break
            acceptable = acceptable + 1 if kkt <= o["acceptable_tol"] else 0
            if acceptable >= o["acceptable_iter"] or (it >= max_iter and acceptable):
                ok, status = True, "Solved_To_Acceptable_Level"
                break
            if it >= max_iter:
                status = "Maximum_Iterations_Exceeded"
                break
            Hf = self.hess(Uv, p)[0] if (exact and self.hess is not None) else None
            H = self._hessian(J, Jh, Hf, lam_c, lam_u, A)
            H.flat[:: self.nU + 1] += reg
            qp = self.qp.solve(H, grad, A, lbc - gc, ubc - gc, self.lbU - Uv, self.ubU - Uv)
            it += 1
            if not qp.ok:
                status = f"QP failed: {qp.status}"
                break
            d, lam_c, lam_u = qp.d, qp.lam_a, qp.lam_x
            if o["rti"]:  # f stays the cost at the linearisation point
                Uv = Uv + d
                ok, status = True, "RTI step"
                break
            mu = max(mu, PENALTY_MARGIN * np.abs(lam_c).max(initial=0.0) + PENALTY_FLOOR)
            alpha = self._line_search(Uv, d, p, f, grad, l1(gc, lbc, ubc), mu, lbc, ubc)
            Uv = Uv + alpha * d
            # Gauss-Newton converges slowly where residuals are large: then go exact
            exact = o["hessian"] == "exact" or (
                o["hessian"] == "auto" and (exact or alpha < 1.0 or it >= EXACT_FROM_ITERATION)
            )
        lam_g, lam_x = self._duals_out(lam_c, lam_u)
        w = self._to_w(Uv, p)
        ok = ok and bool(np.all(np.isfinite(w)))
        return NlpResult(w, lam_g, lam_x, f, ok, status, it, time.perf_counter() - t0)

    def _initial_duals(
        self, lam_g0: np.ndarray | None, lam_x0: np.ndarray | None, shift: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        """The starting multipliers (rows, command bounds) in the condensed layout, and
        the QP's memory of active rows: forgotten on a cold start, moved a stage on with
        the last control step's multipliers."""
        lam_c, lam_u = self._duals_in(lam_g0, lam_x0)
        if lam_g0 is None:
            self.qp.reset()
        elif shift:
            lam_c, lam_u = lam_c[self.qp.shift_rows], lam_u[self.shift_vars]
            self.qp.shift()
        return lam_c, lam_u

    def _kkt_error(
        self,
        Uv: np.ndarray,
        gc: np.ndarray,
        lbc: np.ndarray,
        ubc: np.ndarray,
        grad: np.ndarray,
        A: np.ndarray,
        lam_c: np.ndarray,
        lam_u: np.ndarray,
    ) -> float:
        """The larger of complementarity (rows and bounds) and stationarity."""
        return max(
            complementarity(gc, lbc, ubc, lam_c),
            complementarity(Uv, self.lbU, self.ubU, lam_u),
            float(np.abs(grad + A.T @ lam_c + lam_u).max(initial=0.0)),
        )

    def _hessian(
        self,
        J: np.ndarray,
        Jh: np.ndarray,
        Hf: np.ndarray | None,
        lam_c: np.ndarray,
        lam_u: np.ndarray,
        A: np.ndarray,
    ) -> np.ndarray:
        """The objective's Gauss-Newton Hessian, or its exact one ``Hf`` (if given) made
        positive definite; plus the Gauss-Newton curvature of the hierarchy rows.

        At a constrained minimum the full-space Hessian may be indefinite along directions
        the active constraints block. Adding ``rho C'C`` (``C``: the active rows and
        bounds) makes it positive definite without changing the QP's step on that active
        set, so Newton's fast convergence is kept; only where that fails (negative
        curvature on the constraints' null space too) are the eigenvalues reflected.
        """
        Hh = None
        if self.nh:
            lam_h = np.maximum(lam_c[self.hier_elem_row], 0.0)
            Jw = Jh.reshape(self.nh, self.nU, order="F") * np.sqrt(lam_h)[:, None]
            Hh = 2.0 * (Jw.T @ Jw)
        if Hf is not None:
            H = Hf.reshape(self.nU, self.nU, order="F").copy()
            if Hh is not None:
                H += Hh
            return convexified(H, A[lam_c != 0.0], np.flatnonzero(lam_u != 0.0))
        H = J.T @ J
        H *= 2.0
        if Hh is not None:
            H += Hh
        return H

    def _line_search(
        self,
        Uv: np.ndarray,
        d: np.ndarray,
        p: np.ndarray,
        f: float,
        grad: np.ndarray,
        viol: float,
        mu: float,
        lbc: np.ndarray,
        ubc: np.ndarray,
    ) -> float:
        """Armijo backtracking on the l1 merit ``f + mu * sum(violations)``: the step length."""
        phi0 = f + mu * viol
        slope = float(grad @ d) - mu * viol
        alpha = 1.0
        while True:
            f1, gc1 = self.merit(Uv + alpha * d, p)
            phi = float(f1[0]) + mu * l1(gc1, lbc, ubc)
            if phi <= phi0 + ARMIJO * alpha * min(slope, 0.0) or alpha < MIN_STEP:
                return alpha
            alpha *= BACKTRACK


@BACKENDS.register("sqp-rti")
class SqpRtiBackend(SqpBackend):
    """``sqp`` with one Gauss-Newton QP and a full step per call (real-time iteration)."""

    name = "sqp-rti"
    defaults: ClassVar[dict[str, Any]] = {**DEFAULTS, "rti": True}
