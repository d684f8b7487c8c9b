"""The SQP's sparse QP model: every stage's variables, an OCP-structured QP (HPIPM).

The transcription's variables ``[z0, u0, z1, u1, ..., z_N]`` and rows (per stage: the
gap rows first, then the path and hierarchy rows) are already in the order HPIPM's
Riccati-based interior point needs. Per stage, compiled Functions mapped over the
horizon give the weighted residuals and rows with their Jacobians in the stage's
variables; the Gauss-Newton Hessian is then block diagonal (one block per stage) and
the gap rows are constant. So generated code, build time and memory do not grow with
the horizon, and a QP costs ``O(N)``. The exact Hessian (``hessian="exact"``/``"auto"``)
is per stage too; its blocks may be indefinite (a Riccati recursion only needs the
problem convex on the null space of the dynamics: ``convexify.reduced_convexified``
makes it so where it is not), and where the QP fails with it or its step does not
descend, the step is taken with the Gauss-Newton Hessian instead.
"""

from __future__ import annotations

from dataclasses import replace
from functools import partial
from typing import Any

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends.base import SolveRequest
from aeromanip.nmpc.backends.codegen import Buffered, compiled_all
from aeromanip.nmpc.backends.sqp.convexify import (
    EIGEN_FLOOR,
    active_normals,
    convexified_blocks,
    reduced_convexified,
)
from aeromanip.nmpc.backends.sqp.dense_qp import QpResult
from aeromanip.nmpc.backends.sqp.hpipm import (
    HPIPM_LIMITS,
    hpipm_options,
    hpipm_solver,
    qp_tolerance,
)
from aeromanip.nmpc.backends.sqp.ocp_ipm import CompiledPivots, RiccatiQp
from aeromanip.nmpc.backends.sqp.optimality import complementarity, l1
from aeromanip.nmpc.backends.sqp.qp_model import Linearization
from aeromanip.nmpc.transcription import COUPLING, Transcription

QP_FEASIBILITY = 1e-6  # a QP step keeps its rows and bounds to this (relative to 1 + |d|)
MAX_STEP = 1e3  # [m, rad, m/s, rad/s] a longer step comes from an indefinite, unbounded QP
# the Riccati interior point's least starting slack for the SQP's QPs, HPIPM's ``thr0``:
# their answers are steps, small near convergence. At the general 1.0 the N = 20
# bounds-binding bench's QPs took 9.2 (hierarchical) and 8.4 (weighted) iterations
# against 7.8 and 6.1, the real-time iterations at N = 50 and 100 about 25 % longer
STEP_SLACK_FLOOR = 0.1


def _rows_gauss_newton(cost_rows: list[tuple[int, ca.SX]], s: ca.SX, lam: ca.SX) -> ca.SX:
    """The Gauss-Newton curvature ``sum_j max(lam_j, 0) 2 J_j' J_j`` of cost rows
    ``|r_j|^2`` (``J_j = dr_j/ds``; a row bounded above has ``lam_j >= 0``)."""
    H = ca.SX.zeros(s.numel(), s.numel())
    for i, r in cost_rows:
        J = ca.jacobian(r, s)
        H += 2.0 * ca.fmax(lam[i], 0.0) * (J.T @ J)
    return ca.densify(H)


class SparseQpModel:
    """The multiple-shooting QP model of a transcription (module docstring).

    Args:
        tr: the NLP (mode ``"total"`` couples every stage: not OCP-structured).
        opts: the SQP's options (``codegen``, ``hessian``, ``rti``, ``regularization``,
            ``qpsol_options``).
    """

    #: a second-order correction is a whole interior-point solve (not warm-started): the
    #: line search tries one only where it may turn the trial accepted
    correction_is_a_solve = True

    def __init__(self, tr: Transcription, opts: dict[str, Any]) -> None:
        if COUPLING in tr.g_stage:
            raise ConfigError(
                f"solver_options.qpsol: {opts['qpsol']} needs stage-wise rows; hierarchy mode "
                "'total' couples every stage (use qpsol = 'daqp' or another mode)"
            )
        self.tr, self.opts = tr, opts
        self.N, self.nx, self.nz = tr.N, tr.nx, tr.nz
        self.ns = tr.stride  # variables of a stage: z (2 nx) and u (nx)
        self.nw, self.ng = tr.w.numel(), tr.g.numel()
        self.npk = tr.problem.param_size  # stage parameters per stage
        #: the entries of ``v`` that are ``z[k+1]``, stage after stage (for the gap rows)
        self.next_states = np.concatenate(
            [np.arange((k + 1) * self.ns, (k + 1) * self.ns + self.nz) for k in range(self.N)]
        )
        self._rows()
        self._functions()
        self._pattern()
        self.lbw0, self.ubw0 = tr.lbw.copy(), tr.ubw.copy()
        self._last_qp: tuple[Buffered, tuple[np.ndarray, np.ndarray]] | None = None  # step's
        #: the convexification's Riccati recursion in C, in the Riccati solver's library
        #: (``None``: NumPy's, as with HPIPM, which is what runs without a compiler)
        riccati = isinstance(self.qp, RiccatiQp)
        self._pivots = CompiledPivots.create(EIGEN_FLOOR) if riccati else None

    # -- building ------------------------------------------------------------------------
    def _rows(self) -> None:
        """Per stage, its rows of ``g`` other than the gap rows (in order)."""
        kind, stage = np.asarray(self.tr.g_kind), np.asarray(self.tr.g_stage)
        self.stage_rows = [
            np.flatnonzero((stage == k) & (kind != "gap")) for k in range(self.N + 1)
        ]
        self.gap_rows = np.asarray(self.tr.gap_rows, dtype=int)

    def _functions(self) -> None:
        """Stage Functions (residuals, rows, Jacobians; merit; exact Hessian), mapped over
        stages 0..N-1, and their terminal twins; compiled once."""
        tr, sm, nx = self.tr, self.tr.stage_model, self.nx
        z, u = ca.SX.sym("z", self.nz), ca.SX.sym("u", nx)
        pk = ca.SX.sym("pk", tr.problem.param_size)
        parts = {}
        for name, args, s in (("stage", [z, u, pk], ca.vertcat(z, u)), ("terminal", [z, pk], z)):
            cost = sm.cost if name == "stage" else sm.terminal_cost
            res = (sm.residuals if name == "stage" else sm.terminal_residuals)(*args)
            r = ca.densify(res[0] if isinstance(res, tuple | list) else res)
            accel = sm.accel(z, u) if name == "stage" and sm.accel is not None else ca.SX(0, 1)
            stage_cost = cost(*args)
            rows = ca.vertcat(self._stage_expr(stage_cost, res), accel)
            parts[name] = (args, s, r, ca.densify(rows), self._cost_rows(stage_cost, res))
        n_lam = max(parts["stage"][3].numel(), parts["terminal"][3].numel(), 1)
        lam = ca.SX.sym("lam", n_lam)
        with_exact = self.opts["hessian"] != "gauss-newton" and not self.opts["rti"]
        fs: dict[str, ca.Function] = {}
        for name, (args, s, r, c, cost_rows) in parts.items():
            Jr, Jc = (ca.densify(ca.jacobian(e, s)) for e in (r, c))
            fs[name] = ca.Function(f"aeromanip_ms_{name}", args, [r, Jr, c, Jc])
            fs[f"{name}_merit"] = ca.Function(f"aeromanip_ms_{name}_merit", args, [ca.sumsqr(r), c])
            if with_exact:
                L = ca.sumsqr(r) + (ca.dot(lam[: c.numel()], c) if c.numel() else 0)
                H = ca.densify(ca.hessian(L, s)[0])
                fs[f"{name}_hess"] = ca.Function(f"aeromanip_ms_{name}_hess", [*args, lam], [H])
            if cost_rows:
                gn = _rows_gauss_newton(cost_rows, s, lam)
                fs[f"{name}_rows_gn"] = ca.Function(f"aeromanip_ms_{name}_rgn", [*args, lam], [gn])
        names = list(fs)
        funcs = [
            f.map(f"{f.name()}_map{self.N}", "serial", self.N, [], [])
            if n.startswith("stage")
            else f
            for n, f in fs.items()
        ]
        compiled = compiled_all([*funcs, tr.stage_costs], self.opts["codegen"])  # in parallel
        self.sources = dict(zip(names, funcs, strict=True))  # as generated: their libraries
        built = dict(zip(names, compiled[:-1], strict=True))
        tr.use_stage_costs(compiled[-1])
        self.f_stage, self.f_merit = Buffered(built["stage"]), Buffered(built["stage_merit"])
        self.t_stage, self.t_merit = Buffered(built["terminal"]), Buffered(built["terminal_merit"])
        self.f_hess = Buffered(built["stage_hess"]) if with_exact else None
        self.t_hess = Buffered(built["terminal_hess"]) if with_exact else None
        self.f_rows_gn, self.t_rows_gn = (
            Buffered(built[n]) if n in built else None
            for n in ("stage_rows_gn", "terminal_rows_gn")
        )
        self.n_lam = n_lam
        self.nr, self.nrT = fs["stage"].size1_out(0), fs["terminal"].size1_out(0)
        self.nc, self.ncT = fs["stage"].size1_out(2), fs["terminal"].size1_out(2)
        middle = [len(r) for r in self.stage_rows[1 : self.N]]
        if any(n != self.nc for n in middle) or self.ncT != len(self.stage_rows[self.N]):
            raise ConfigError("solver_options.qpsol: hpipm: the stage rows do not match")

    def _cost_rows(self, cost: Any, res: Any) -> list[tuple[int, ca.SX]]:
        """``stagewise``: each higher level's cost row ``|r_j|^2`` as (its index among the
        stage's rows, ``r_j``); other modes: none (their rows are the residuals)."""
        if self.tr.mode != "stagewise" or not isinstance(res, tuple | list):
            return []
        n_path = cost[2].numel()
        return [(n_path + j, r) for j, r in enumerate(res[1:])]

    def _stage_expr(self, cost: Any, res: Any) -> ca.SX:
        """A stage's path and hierarchy rows as the transcription orders them: path,
        then per higher level its cost (``stagewise``) or its residuals (``strict``/
        ``residual``); the command-rate rows follow."""
        _, hier, path, _ = cost
        groups = list(res[1:]) if isinstance(res, tuple | list) else []
        stagewise = self.tr.mode == "stagewise"
        rows = [hier[j] for j in range(hier.numel())] if stagewise else groups
        return ca.vertcat(path, *rows)

    def _pattern(self) -> None:
        """The QP's sparsity (block-diagonal Hessian; gap rows and stage rows) and the
        maps from per-stage blocks to the solver's nonzeros; the HPIPM solver."""
        N, ns, nz, model = self.N, self.ns, self.nz, self.tr.model
        blocks = [ca.DM.ones(ns, ns)] * N + [ca.DM.ones(nz, nz)]
        self.H_sp = ca.diagcat(*blocks).sparsity()
        rows, cols, vals = [], [], []  # every entry of A, in our fill order
        gap = -np.hstack([model.A, model.B])  # d(gap)/d(z_k, u_k) (the model is linear)
        self.gap_block = gap
        for k in range(N):
            r0, c0 = self.gap_rows[k * nz], k * ns
            for i in range(nz):
                for j in range(ns):
                    rows.append(r0 + i), cols.append(c0 + j), vals.append(gap[i, j])
                rows.append(r0 + i), cols.append(c0 + ns + i), vals.append(1.0)
        self.n_gap_entries = len(vals)
        for k in range(N + 1):
            width = ns if k < N else nz
            for r in self.stage_rows[k]:
                for j in range(width):
                    rows.append(int(r)), cols.append(k * ns + j), vals.append(0.0)
        order = ca.DM.triplet(rows, cols, ca.DM(np.arange(1, len(vals) + 1)), self.ng, self.nw)
        self.A_sp = order.sparsity()
        self.a_perm = np.asarray(order.nonzeros(), dtype=int) - 1  # CCS position -> ours
        self.a_fixed = np.array(vals[: self.n_gap_entries])
        self._row_slots()
        kind = "rti" if self.opts["rti"] else "sqp"
        if self.opts["qpsol"] == "riccati" and self._riccati(kind):
            return
        user = self.opts["qpsol_options"]
        own = hpipm_options(kind, user, self.opts["tol"])
        self.qp = hpipm_solver(self.H_sp, self.A_sp, own, f"{N}")
        # after a line search that nearly failed, the QPs of the solve are solved to the
        # tightest tolerance (``step(accurate=True)``); the same solver if that is its own
        tightest = hpipm_options(kind, user)
        self.qp_accurate = (
            self.qp
            if tightest == own
            else hpipm_solver(self.H_sp, self.A_sp, tightest, f"accurate_{N}")
        )

    def _row_slots(self) -> None:
        """Where each stage row of ``g`` sits among the Riccati solver's rows (``nc`` per
        stage, the last ones used where a stage has fewer, then ``ncT``)."""
        slots, rows = [], []
        for k in range(self.N + 1):
            mine = self.stage_rows[k]
            end = k * self.nc + (self.nc if k < self.N else self.ncT)
            slots.append(np.arange(end - len(mine), end))
            rows.append(mine)
        self.row_slot, self.row_src = np.concatenate(slots), np.concatenate(rows)

    def _riccati(self, kind: str) -> bool:
        """The Riccati interior point as the QP solver (and its accurate twin), at HPIPM's
        tolerances; ``False`` where it cannot be built here (then HPIPM)."""
        model, dims = self.tr.model, (self.N, self.nz, self.nx, self.nc, self.ncT)
        tol, iterations = qp_tolerance(kind, self.opts["tol"]), HPIPM_LIMITS[kind][1]
        qp = RiccatiQp.create(dims, model.A, model.B, tol, iterations, STEP_SLACK_FLOOR)
        if qp is None:
            return False
        tightest = HPIPM_LIMITS[kind][0]
        self.qp = qp
        self.qp_accurate = (
            qp
            if tightest == tol
            else RiccatiQp.create(dims, model.A, model.B, tightest, iterations, STEP_SLACK_FLOOR)
        )
        return True

    # -- evaluation ----------------------------------------------------------------------
    def _split(self, v: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, ...]:
        """The mapped Functions' inputs from ``v`` and ``p`` (stage after stage, as their
        column-major buffers hold them): Z, U, P of stages 0..N-1; z_N, p_N."""
        N, ns, nz = self.N, self.ns, self.nz
        S = v[: N * ns].reshape(N, ns)
        npk = self.npk
        P = p[nz:]
        return S[:, :nz].ravel(), S[:, nz:].ravel(), P[: N * npk], v[N * ns :], P[N * npk :]

    def _gaps(self, v: np.ndarray) -> np.ndarray:
        """The gap rows' values ``z[k+1] - (A z[k] + B u[k])`` (stage-major)."""
        S = v[: self.N * self.ns].reshape(self.N, self.ns)
        return (v[self.next_states].reshape(self.N, self.nz) + S @ self.gap_block.T).ravel()

    def _rows_values(self, c: np.ndarray, cT: np.ndarray, v: np.ndarray) -> np.ndarray:
        """``g(v)`` in the transcription's order from the stage rows and the gaps."""
        g = np.empty(self.ng)
        g[self.gap_rows] = self._gaps(v)
        g[self.row_src] = np.concatenate([c, cT])[self.row_slot]  # stage 0 has no path rows
        return g

    # -- the QpModel interface -------------------------------------------------------------
    def start(self, request: SolveRequest) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The NLP guess (inside the variable bounds, stage 0 as pinned by the NLP's
        parameters at ``linearize``), the row bounds, the multipliers moved a stage on."""
        w0, lbg, ubg = request.w0, request.lbg, request.ubg
        lam_g0, lam_x0, shift = request.lam_g0, request.lam_x0, request.shift
        self.lbg, self.ubg = np.asarray(lbg, dtype=float), np.asarray(ubg, dtype=float)
        lam_c, lam_v = np.zeros(self.ng), np.zeros(self.nw)
        if lam_g0 is not None and lam_x0 is not None:
            lam_c, lam_v = np.asarray(lam_g0, dtype=float), np.asarray(lam_x0, dtype=float)
            if shift:
                lam_c, lam_v = lam_c[self.tr.shift_g], lam_v[self.tr.shift_w]
        return np.asarray(w0, dtype=float).copy(), lam_c, lam_v

    def bounds(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The variables' bounds at parameters ``p`` (stage 0 pinned to the state)."""
        return self.tr.variable_bounds(p)

    def linearize(self, v: np.ndarray, p: np.ndarray) -> Linearization:
        """Stage residuals, rows and Jacobians; cost, gradient and ``g`` assembled."""
        lbw, ubw = self.bounds(p)
        v = np.clip(v, lbw, ubw)  # stage 0 pinned to the measured state
        Z, U, P, zN, pN = self._split(v, p)
        r, Jr, c, Jc = (a.copy() for a in self.f_stage(Z, U, P))
        rT, JrT, cT, JcT = (a.copy() for a in self.t_stage(zN, pN))
        N, ns, nz, nr, nrT = self.N, self.ns, self.nz, self.nr, self.nrT
        R = r.reshape(N, nr)
        J = Jr.reshape(N, ns, nr).transpose(0, 2, 1)  # (N, nr, ns): each stage's Jacobian
        JT = JrT.reshape(nz, nrT).T
        grad = np.concatenate([2.0 * (R[:, None, :] @ J).ravel(), 2.0 * JT.T @ rT])
        f = float(np.sum(r * r) + rT @ rT)
        g = self._rows_values(c, cT, v)
        data = {"v": v, "J": J, "JT": JT, "Jc": Jc, "JcT": JcT, "lbw": lbw, "ubw": ubw}
        return Linearization(f, grad, g, self.lbg, self.ubg, data)

    def _a_values(self, lin: Linearization) -> np.ndarray:
        """The nonzeros of ``A`` in our fill order (gap constants, then stage rows)."""
        N, ns, nz = self.N, self.ns, self.nz
        Jc = lin.data["Jc"].reshape(N, ns, self.nc).transpose(0, 2, 1)  # (N, nc, ns)
        parts = [self.a_fixed]
        for k in range(N):
            parts.append(Jc[k, self.nc - len(self.stage_rows[k]) :].ravel())
        parts.append(lin.data["JcT"].reshape(nz, self.ncT).T.ravel())
        return np.concatenate(parts)

    def _blocks(self, lin: Linearization) -> tuple[np.ndarray, np.ndarray]:
        """The stage rows' Jacobians: (N, nc, ns) and the terminal (ncT, nz)."""
        N, ns, nz = self.N, self.ns, self.nz
        Jc = lin.data["Jc"].reshape(N, ns, self.nc).transpose(0, 2, 1)
        return Jc, lin.data["JcT"].reshape(nz, self.ncT).T

    def _a_times(self, lin: Linearization, d: np.ndarray) -> np.ndarray:
        """``A d`` (the rows' linearisation applied to a step), by blocks."""
        N, ns, nz = self.N, self.ns, self.nz
        Jc, JcT = self._blocks(lin)
        S = d[: N * ns].reshape(N, ns)
        nxt = np.vstack([d[ns : N * ns].reshape(N - 1, ns)[:, :nz], d[N * ns :][None]])
        out = np.empty(self.ng)
        out[self.gap_rows] = (S @ self.gap_block.T + nxt).ravel()
        rows_d = (Jc @ S[:, :, None])[:, :, 0]
        out[self.row_src] = np.concatenate([rows_d.ravel(), JcT @ d[N * ns :]])[self.row_slot]
        return out

    def _at_lam(self, lin: Linearization, lam_c: np.ndarray) -> np.ndarray:
        """``A^T lam``, by blocks."""
        N, ns, nz = self.N, self.ns, self.nz
        Jc, JcT = self._blocks(lin)
        lam_gap = lam_c[self.gap_rows].reshape(N, nz)
        flat = self._rows_flat(lam_c)
        lam_rows = flat[: N * self.nc].reshape(N, self.nc)
        out = np.zeros(self.nw)
        S = lam_gap @ self.gap_block + (lam_rows[:, None, :] @ Jc)[:, 0, :]
        out[: N * ns] = S.ravel()
        nxt = out[ns : N * ns].reshape(N - 1, ns)
        nxt[:, :nz] += lam_gap[:-1]
        out[N * ns :] += lam_gap[-1] + JcT.T @ flat[N * self.nc :]
        return out

    def _rows_flat(self, lam_c: np.ndarray) -> np.ndarray:
        """The stage rows' entries of ``lam_c`` per stage (``nc`` each, the last used
        where a stage has fewer; zeros elsewhere), then the terminal ``ncT``."""
        flat = np.zeros(self.N * self.nc + self.ncT)
        flat[self.row_slot] = lam_c[self.row_src]
        return flat

    def kkt_error(
        self, v: np.ndarray, lin: Linearization, lam_c: np.ndarray, lam_v: np.ndarray
    ) -> float:
        """The larger of complementarity (rows and bounds) and stationarity."""
        d = lin.data
        stat = lin.grad + self._at_lam(lin, lam_c) + lam_v
        free = d["lbw"] < d["ubw"]  # pinned variables carry any multiplier
        return max(
            complementarity(lin.c, lin.lbc, lin.ubc, lam_c),
            complementarity(d["v"][free], d["lbw"][free], d["ubw"][free], lam_v[free]),
            float(np.abs(stat[free]).max(initial=0.0)),
        )

    def _hessian_blocks(
        self, lin: Linearization, lam_c: np.ndarray, p: np.ndarray, exact: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per stage: ``2 J'J`` (Gauss-Newton) or the exact Hessian of ``||r||^2 + lam'c``
        (symmetrised, possibly indefinite: ``step`` falls back on Gauss-Newton where its
        QP fails), plus the regularisation."""
        d, N, ns, nz = lin.data, self.N, self.ns, self.nz
        if exact and self.f_hess is not None and self.t_hess is not None:
            Z, U, P, zN, pN = self._split(d["v"], p)
            lam = self._stage_lams(lam_c)
            Hs = self.f_hess(Z, U, P, lam[:, :N].ravel(order="F"))[0].reshape(N, ns, ns)
            HT = self.t_hess(zN, pN, lam[:, N])[0].reshape(nz, nz)
            Hs = 0.5 * (Hs + Hs.transpose(0, 2, 1))  # blocks may be indefinite: HPIPM only
            HT = 0.5 * (HT + HT.T)  # needs the problem on the dynamics' null space convex
        else:
            J = d["J"]
            Hs = 2.0 * (J.transpose(0, 2, 1) @ J)  # batched: ~7x faster than einsum
            HT = 2.0 * d["JT"].T @ d["JT"]
            if self.f_rows_gn is not None or self.t_rows_gn is not None:
                self._add_cost_rows(Hs, HT, d["v"], lam_c, p)
        reg = self.opts["regularization"]
        Hs[:, np.arange(ns), np.arange(ns)] += reg
        HT[np.arange(nz), np.arange(nz)] += reg
        return Hs, HT

    def _add_cost_rows(
        self, Hs: np.ndarray, HT: np.ndarray, v: np.ndarray, lam_c: np.ndarray, p: np.ndarray
    ) -> None:
        """Add to the Gauss-Newton blocks (in place) the curvature of the stagewise
        hierarchy's cost rows, as ``CondensedQpModel._hessian`` does."""
        N, ns, nz = self.N, self.ns, self.nz
        Z, U, P, zN, pN = self._split(v, p)
        lam = self._stage_lams(lam_c)
        if self.f_rows_gn is not None:
            Hs += self.f_rows_gn(Z, U, P, lam[:, :N].ravel(order="F"))[0].reshape(N, ns, ns)
        if self.t_rows_gn is not None:
            HT += self.t_rows_gn(zN, pN, lam[:, N])[0].reshape(nz, nz)

    def _stage_lams(self, lam_c: np.ndarray) -> np.ndarray:
        """The stage rows' multipliers as the stage Functions' ``lam`` input (per column)."""
        out = np.zeros((self.n_lam, self.N + 1))
        flat = self._rows_flat(lam_c)
        out[: self.nc, : self.N] = flat[: self.N * self.nc].reshape(self.N, self.nc).T
        out[: self.ncT, self.N] = flat[self.N * self.nc :]
        return out

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
        """The sparse QP (with the exact Hessian, convexified, if asked and it gives a
        descending step, else with the Gauss-Newton one), to its tightest residuals if
        ``accurate`` (``qp_tolerance``); ``damping`` times the blocks' largest diagonal
        entry is added to their diagonals (a Levenberg-Marquardt step)."""
        qp = self.qp_accurate if accurate else self.qp
        Hs, HT = self._hessian_blocks(lin, lam_c, p, exact)
        if exact:  # convex on the dynamics' null space (convexify.reduced_convexified)
            dynamics = (self.tr.model.A, self.tr.model.B)
            Hs, HT = reduced_convexified(
                Hs, HT, dynamics, partial(self._active, lin, lam_c, lam_v), self._pivots
            )  # the active rows' normals are computed only where the pivots need them
            if not isinstance(qp, RiccatiQp):  # HPIPM's square-root Riccati recursion
                Hs, HT = convexified_blocks(Hs, HT)  # factors each block: PSD ones only
        if damping:
            diagonal = np.concatenate([np.diagonal(Hs, axis1=1, axis2=2).ravel(), np.diag(HT)])
            top = damping * float(diagonal.max())
            Hs = Hs + top * np.eye(self.ns)
            HT = HT + top * np.eye(self.nz)
        blocks = (Hs, HT)
        res = self._qp(qp, lin, *blocks)
        huge = np.abs(res.d).max(initial=0.0) > MAX_STEP  # unbounded: an indefinite QP
        if exact and (not res.ok or huge or float(lin.grad @ res.d) > 0.0):
            blocks = self._hessian_blocks(lin, lam_c, p, False)
            res = self._qp(qp, lin, *blocks)
        self._last_qp = (qp, blocks)
        res.d += lin.data["v"] - v  # the step is taken from the clipped iterate
        return res

    def _active(
        self, lin: Linearization, lam_c: np.ndarray, lam_v: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """``convexify.active_normals`` of the rows and bounds active at the last QP."""
        N, ns, nc = self.N, self.ns, self.nc
        flat = self._rows_flat(lam_c)
        return active_normals(
            self._blocks(lin),
            (flat[: N * nc].reshape(N, nc), flat[N * nc :]),
            (lam_v[: N * ns].reshape(N, ns), lam_v[N * ns :]),
        )

    def correction(
        self, v: np.ndarray, d: np.ndarray, lin: Linearization, p: np.ndarray
    ) -> QpResult:
        """The step ``d`` with a second-order correction: the last QP again, its rows'
        values taken at ``v + d`` (``c(v + d) - A d``), so that curved rows (the
        hierarchy's residuals, the clearance) hold to second order, as
        ``CondensedQpModel.correction`` (the gap rows are linear: unchanged)."""
        assert self._last_qp is not None, "correction() follows step()"
        qp, blocks = self._last_qp
        base = lin.data["v"]
        step = v + d - base  # the QP's own step, from the clipped iterate
        rows = self._cost_and_rows(base + step, p)[1] - self._a_times(lin, step)
        res = self._qp(qp, replace(lin, c=rows), *blocks)
        res.d += base - v
        return res

    def _qp(self, qp: Buffered | RiccatiQp, lin: Linearization, Hs: np.ndarray,
            HT: np.ndarray) -> QpResult:  # fmt: skip
        """One QP with the given Hessian blocks, solved by ``qp``."""
        d = lin.data
        if isinstance(qp, RiccatiQp):
            return self._qp_riccati(qp, lin, Hs, HT)
        x, lam_a, lam_x, _ = qp(
            np.concatenate([Hs.transpose(0, 2, 1).ravel(), HT.T.ravel()]),
            self._a_values(lin)[self.a_perm],
            lin.grad,
            lin.lbc - lin.c,
            lin.ubc - lin.c,
            d["lbw"] - d["v"],
            d["ubw"] - d["v"],
        )
        step = x.copy()
        ok, status = self._solved(lin, step)
        return QpResult(step, lam_a.copy(), lam_x.copy(), ok, status)

    def _qp_riccati(
        self, qp: RiccatiQp, lin: Linearization, Hs: np.ndarray, HT: np.ndarray
    ) -> QpResult:
        """One QP by the Riccati interior point: the blocks as ``ocp_ipm`` takes them."""
        d, nz = lin.data, self.nz
        lba, uba = lin.lbc - lin.c, lin.ubc - lin.c
        n_rows = self.N * self.nc + self.ncT
        lg, ug = np.full(n_rows, -np.inf), np.full(n_rows, np.inf)
        lg[self.row_slot], ug[self.row_slot] = lba[self.row_src], uba[self.row_src]
        Jc, JcT = self._blocks(lin)
        lb, ub = d["lbw"] - d["v"], d["ubw"] - d["v"]
        sol = qp.solve(
            np.concatenate([Hs.ravel(), HT.ravel()]),
            lin.grad,
            np.ascontiguousarray(lba[self.gap_rows]),
            np.concatenate([Jc.ravel(), JcT.ravel()]),
            (lg, ug),
            (lb, ub),
            np.ascontiguousarray(lb[:nz]),  # stage 0's state: pinned
        )
        lam_a = np.zeros(self.ng)
        lam_a[self.gap_rows] = sol.lam_dyn
        lam_a[self.row_src] = sol.lam_c[self.row_slot]
        if sol.status == "solved":  # its residuals (<= 1e-8) are within QP_FEASIBILITY
            ok, status = True, ""
        else:
            ok, status = self._solved(lin, sol.y) if sol.usable else (False, sol.status)
        return QpResult(sol.y, lam_a, sol.lam_y, ok, status)

    def _solved(self, lin: Linearization, step: np.ndarray) -> tuple[bool, str]:
        """A finite step that keeps the linearised rows and the bounds (to
        ``QP_FEASIBILITY``): HPIPM's own status is not reachable through CasADi here."""
        if not np.isfinite(step).all():
            return False, "not finite"
        d = lin.data
        tol = QP_FEASIBILITY * (1.0 + np.abs(step).max(initial=0.0))
        row = lin.c + self._a_times(lin, step)
        var = d["v"] + step
        bad = (
            np.any(row < lin.lbc - tol)
            or np.any(row > lin.ubc + tol)
            or np.any(var < d["lbw"] - tol)
            or np.any(var > d["ubw"] + tol)
        )
        return (False, "infeasible or not converged") if bad else (True, "")

    def merit(self, v: np.ndarray, p: np.ndarray) -> tuple[float, float]:
        """Cost and l1 row violation at ``v``."""
        f, g = self._cost_and_rows(v, p)
        return f, l1(g, self.lbg, self.ubg)

    def _cost_and_rows(self, v: np.ndarray, p: np.ndarray) -> tuple[float, np.ndarray]:
        """Cost and rows ``g`` at ``v`` clipped into the variable bounds."""
        lbw, ubw = self.bounds(p)
        v = np.clip(v, lbw, ubw)
        Z, U, P, zN, pN = self._split(v, p)
        f, c = (a.copy() for a in self.f_merit(Z, U, P))
        fT, cT = self.t_merit(zN, pN)
        return float(f.sum() + fT[0]), self._rows_values(c, cT, v)

    def result(
        self, v: np.ndarray, p: np.ndarray, lam_c: np.ndarray, lam_v: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The iterate is the NLP's variable vector (stage 0 pinned); multipliers as they are."""
        lbw, ubw = self.bounds(p)
        return np.clip(v, lbw, ubw), lam_c, lam_v
