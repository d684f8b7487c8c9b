"""The SQP's condensed model: the NLP in the commands ``U`` alone, a dense QP (DAQP).

The model ``z[k+1] = A z[k] + B u[k]`` (``nmpc.model``) is linear, so the states are
affine in the commands: the multiple-shooting NLP is solved in ``U`` (``N nx``
variables), the gap rows holding exactly. The state bounds become linear rows of ``U``.
The dense residuals, rows and their Jacobians in ``U`` are one compiled Function: fast
for short horizons, but its code grows like ``N^2`` (use ``SparseQpModel``
beyond a dozen steps). The QP is solved by a dual active-set method on the rows that may
bind (``dense_qp``).
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from aeromanip.nmpc.backends.base import SolveRequest
from aeromanip.nmpc.backends.codegen import Buffered, compiled_all
from aeromanip.nmpc.backends.sqp.convexify import convexified
from aeromanip.nmpc.backends.sqp.dense_qp import DenseQp, QpResult
from aeromanip.nmpc.backends.sqp.optimality import complementarity, l1
from aeromanip.nmpc.backends.sqp.qp_model import Linearization
from aeromanip.nmpc.transcription import Transcription, shift_map


def condensed_variables(tr: Transcription, U: ca.SX, p: ca.SX) -> ca.SX:
    """The NLP's variables as expressions of the commands ``U`` and the parameters ``p``
    (the model is linear: the states are affine in ``U``)."""
    N, nx = tr.N, tr.nx
    z, parts = p[: tr.nz], []
    for k in range(N + 1):
        parts.append(z)
        if k < N:
            uk = U[k * nx : (k + 1) * nx]
            parts.append(uk)
            z = tr.model.next_sx(z, uk)
    return ca.vertcat(*parts)


class CondensedQpModel:
    """The condensed QP model of a transcription (module docstring; ``qp_model.QpModel``).

    Args:
        tr: the NLP.
        opts: the SQP's options (``codegen``, ``hessian``, ``rti``, ``regularization``,
            ``qpsol``, ``qpsol_options``, ``screen``).
    """

    def __init__(self, tr: Transcription, opts: dict[str, Any]) -> None:
        self.tr, self.opts = tr, opts
        self.nU = tr.N * tr.nx
        self.nw, self.ng = tr.w.numel(), tr.g.numel()  # the NLP's variables and rows
        U, p = ca.SX.sym("U", self.nU), ca.SX.sym("p", tr.p.numel())
        R, gc, Rh = self._condensed(U, p)
        self._compile(U, p, R, gc, Rh)
        self._qp_setup()

    # -- building ------------------------------------------------------------------------
    def _condensed(self, U: ca.SX, p: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX]:
        """Objective residuals ``R``, the rows that may bind ``gc`` (path and hierarchy
        rows, then the state bounds as rows of ``U``) and the hierarchy rows' residuals
        ``Rh``, as expressions of ``U``. Sets the index maps between layouts."""
        tr, N, nx = self.tr, self.tr.N, self.tr.nx
        wU = condensed_variables(tr, U, p)
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
        return R, ca.vertcat(g[self.keep.tolist()], wU[sidx]), Rh

    def _compile(self, U: ca.SX, p: ca.SX, R: ca.SX, gc: ca.SX, Rh: ca.SX) -> None:
        """Build the model Functions (data, merit, exact Hessian) and compile them to C."""
        tr = self.tr
        tag = f"{len(tr.hier_residuals)}h{tr.N}x{tr.nx}"
        J, A, Jh = (ca.densify(ca.jacobian(e, U)) for e in (R, gc, Rh))
        with_exact = self.opts["hessian"] != "gauss-newton" and not self.opts["rti"]
        data = ca.Function(f"aeromanip_sqp_data_{tag}", [U, p], [R, J, gc, A, Jh])
        merit = ca.Function(f"aeromanip_sqp_merit_{tag}", [U, p], [ca.sumsqr(R), gc])
        lam_g = ca.SX.sym("lam_g", self.ng)  # the NLP's Lagrangian, for its multipliers
        grad_l = ca.gradient(tr.f + ca.dot(lam_g, tr.g), tr.w)
        lagr = ca.Function(f"aeromanip_sqp_lagw_{tag}", [tr.w, tr.p, lam_g], [grad_l])
        fs = [data, merit, tr.stage_costs, lagr]
        if with_exact:  # of the Lagrangian: the rows' curvature (clearance, hierarchy) too
            lam = ca.SX.sym("lam", gc.numel())
            Hf = ca.densify(ca.hessian(ca.sumsqr(R) + ca.dot(lam, gc), U)[0])
            fs.append(ca.Function(f"aeromanip_sqp_hessl_{tag}", [U, p, lam], [Hf]))
        self.sources = fs  # as generated: the compiled loop finds their libraries by them
        fs = compiled_all(fs, self.opts["codegen"])  # built in parallel, once, cached
        self.data, self.merit_f = Buffered(fs[0]), Buffered(fs[1])
        tr.use_stage_costs(fs[2])
        self.lagr_grad = Buffered(fs[3])
        self.hess = Buffered(fs[4]) if with_exact else None
        self.nr, self.nc, self.nh = R.numel(), gc.numel(), Rh.numel()
        self._sweep: np.ndarray | None = None  # built by _model_multipliers when first used

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

    # -- the QpModel interface -------------------------------------------------------------
    def start(self, request: SolveRequest) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The commands of ``w0`` (clipped to their bounds), the row bounds of this
        solve, and the starting multipliers with the QP's memory of active rows:
        forgotten on a cold start, moved a stage on with the last step's multipliers."""
        w0, p, lbg, ubg = request.w0, request.p, request.lbg, request.ubg
        lam_g0, lam_x0, shift = request.lam_g0, request.lam_x0, request.shift
        lbw, ubw = self.tr.variable_bounds(p)  # the state box, widened where it must be
        self.lbc = np.concatenate([lbg[self.keep], lbw[self.state_idx]])
        self.ubc = np.concatenate([ubg[self.keep], ubw[self.state_idx]])
        lam_c, lam_u = np.zeros(self.nc), np.zeros(self.nU)
        if lam_g0 is not None and lam_x0 is not None:
            lam_c[: self.nk] = np.asarray(lam_g0)[self.keep]
            lam_c[self.nk :] = np.asarray(lam_x0)[self.state_idx]
            lam_u[:] = np.asarray(lam_x0)[self.u_idx]
        if lam_g0 is None:
            self.qp.reset()
        elif shift:
            lam_c, lam_u = lam_c[self.qp.shift_rows], lam_u[self.shift_vars]
            self.qp.shift()
        Uv = np.clip(np.asarray(w0, dtype=float)[self.u_idx], self.lbU, self.ubU)
        return Uv, lam_c, lam_u

    def linearize(self, v: np.ndarray, p: np.ndarray) -> Linearization:
        """Residuals, rows and their (dense) Jacobians in ``U``."""
        R, J, gc, A, Jh = self.data(v, p)
        J = J.reshape(self.nr, self.nU, order="F")
        A = A.reshape(self.nc, self.nU, order="F")
        return Linearization(float(R @ R), 2.0 * (J.T @ R), gc, self.lbc, self.ubc, (J, A, Jh))

    def kkt_error(
        self, v: np.ndarray, lin: Linearization, lam_c: np.ndarray, lam_v: np.ndarray
    ) -> float:
        """The larger of complementarity (rows and bounds) and stationarity."""
        A = lin.data[1]
        return max(
            complementarity(lin.c, lin.lbc, lin.ubc, lam_c),
            complementarity(v, self.lbU, self.ubU, lam_v),
            float(np.abs(lin.grad + A.T @ lam_c + lam_v).max(initial=0.0)),
        )

    def step(
        self,
        v: np.ndarray,
        lin: Linearization,
        lam_c: np.ndarray,
        lam_v: np.ndarray,
        p: np.ndarray,
        exact: bool,
        damping: float = 0.0,
        accurate: bool = False,
    ) -> QpResult:
        """The dense QP on the rows that may bind; ``damping`` times the Hessian's largest
        diagonal entry is added to its diagonal (a Levenberg-Marquardt step). The
        active-set solver's answer is exact: ``accurate`` changes nothing."""
        J, A, Jh = lin.data
        Hf = self.hess(v, p, lam_c)[0] if (exact and self.hess is not None) else None
        H = self._hessian(J, Jh, Hf, lam_c, lam_v, A)
        diag = H.flat[:: self.nU + 1]
        H.flat[:: self.nU + 1] += self.opts["regularization"] + damping * float(diag.max())
        self._last_H = H
        gc = lin.c
        return self.qp.solve(H, lin.grad, A, lin.lbc - gc, lin.ubc - gc, self.lbU - v, self.ubU - v)

    def correction(
        self, v: np.ndarray, d: np.ndarray, lin: Linearization, p: np.ndarray
    ) -> QpResult:
        """The step ``d`` with a second-order correction: the last QP again, its rows'
        values taken at ``v + d`` (``c(v + d) - A d``), so that curved rows (the
        hierarchy's residuals, the clearance) hold to second order: the full step the
        l1 merit rejects near a curved boundary (Maratos effect) is accepted corrected."""
        A = lin.data[1]
        c = self.merit_f(v + d, p)[1] - A @ d
        return self.qp.solve(
            self._last_H, lin.grad, A, lin.lbc - c, lin.ubc - c, self.lbU - v, self.ubU - v
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
        positive definite (``convexify.convexified``: a penalty on the active rows' normals,
        which keeps the step on that active set, else a shift); plus the Gauss-Newton
        curvature of the hierarchy's cost rows."""
        Hh = None
        if self.nh and Hf is None:  # the exact Hessian has the rows' curvature already
            lam_h = np.maximum(lam_c[self.hier_elem_row], 0.0)
            Jw = Jh.reshape(self.nh, self.nU, order="F") * np.sqrt(lam_h)[:, None]
            Hh = 2.0 * (Jw.T @ Jw)
        if Hf is not None:
            H = Hf.reshape(self.nU, self.nU, order="F").copy()
            fixed = np.flatnonzero(lam_u != 0.0)
            return convexified(H, A[lam_c != 0.0], fixed, self.opts["accept_at_max_iter"])
        H = J.T @ J
        H *= 2.0
        if Hh is not None:
            H += Hh
        return H

    def merit(self, v: np.ndarray, p: np.ndarray) -> tuple[float, float]:
        """Cost and l1 row violation at ``v``."""
        f, gc = self.merit_f(v, p)
        return float(f[0]), l1(gc, self.lbc, self.ubc)

    def result(
        self, v: np.ndarray, p: np.ndarray, lam_c: np.ndarray, lam_v: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The NLP's variables (states rolled out from the commands) and multipliers:
        the QP's, and the model rows' (condensed away) from the NLP's stationarity in
        the states."""
        tr, nx, N = self.tr, self.tr.nx, self.tr.N
        Um = v.reshape(N, nx)
        w = np.empty(self.nw)
        w[tr.index_z] = tr.model.rollout(p[: tr.nz], Um)
        w[tr.index_u] = Um
        lam_g = np.zeros(self.ng)
        lam_g[self.keep] = lam_c[: self.nk]
        lam_x = np.zeros(self.nw)
        lam_x[self.state_idx] = lam_c[self.nk :]
        lam_x[self.u_idx] = lam_v
        lam_g[tr.gap_rows] = self._model_multipliers(w, p, lam_g, lam_x)
        return w, lam_g, lam_x

    def _model_multipliers(
        self, w: np.ndarray, p: np.ndarray, lam_g: np.ndarray, lam_x: np.ndarray
    ) -> np.ndarray:
        """The multipliers ``mu[k]`` of the model rows ``z[k+1] - A z[k] - B u[k] = 0``
        (gap rows in stage order) that make the NLP stationary in the states ``z[1..N]``:
        ``r[k] + mu[k-1] - A^T mu[k] = 0`` with ``mu[N] = 0``, where ``r[k]`` is the
        gradient in ``z[k]`` of the Lagrangian without the model rows (``lam_g`` holds 0
        there), plus the bound multipliers. Solved backwards from ``k = N``:
        ``mu[k-1] = -sum_{j>=k} (A^T)^(j-k) r[j]``, one product with a matrix built once."""
        tr, nz = self.tr, self.tr.nz
        if self._sweep is None:
            powers = [np.eye(nz)]
            for _ in range(tr.N - 1):
                powers.append(tr.model.A.T @ powers[-1])
            self._sweep = np.zeros((tr.N * nz, tr.N * nz))
            for k in range(tr.N):
                for j in range(k, tr.N):
                    self._sweep[k * nz : (k + 1) * nz, j * nz : (j + 1) * nz] = -powers[j - k]
        r = self.lagr_grad(w, p, lam_g)[0] + lam_x
        return self._sweep @ r[tr.index_z[1:]].ravel()
