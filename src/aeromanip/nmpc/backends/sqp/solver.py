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
  that active set (Newton's convergence kept); where that fails (the problem curves down
  along the active set), the eigenvalues are reflected, or in a bounded solve
  (``accept_at_max_iter``) a shift ``delta I`` makes it so (IPOPT's inertia correction:
  a few Cholesky factorisations instead of an eigendecomposition,
  ``convexify.convexified``). On the sparse model
  the test is on the Riccati recursion's pivots, not the blocks: blocks may be
  indefinite where the problem is convex on the dynamics' null space
  (``convexify.reduced_convexified``).
* **The QP by the horizon's length.** Short horizons: the model ``x[k+1] = x[k] + dt u[k]``
  is linear, so the NLP is condensed exactly onto the commands (``condensed_qp``: a dense
  QP, DAQP on the rows that may bind). Long horizons: every stage keeps its variables
  and the sparse OCP-structured QP is solved by HPIPM's Riccati-based interior point
  (``sparse_qp``: stage Functions mapped over the horizon, so generated code,
  build time and memory do not grow with N). ``qpsol="auto"`` picks the first up to
  ``condense_max_horizon`` steps. An interior point solves a QP only to a tolerance:
  HPIPM's residuals are 1e-2 of the SQP's ``tol`` (1e-8 at the default), and its
  tightest (1e-10, ~5x the iterations) for the rest of a solve once a line search has
  nearly failed on an inexact step.
* **Hierarchy rows** ``c_r = ||R_r||^2 <= b_r`` (stage-wise, ``Hierarchical``) are
  linearised, and their curvature enters the Hessian as ``2 lam_r J_r^T J_r`` (the
  Gauss-Newton part of the constraint's Hessian, positive semi-definite since
  ``lam_r >= 0``), ``lam_r`` from the last QP: the linearisation of a squared norm alone
  says nothing near its minimum, and with this term the QP sees the ball it must stay in.
  Each level starts from its own previous solution, shifted (no feasible start needed).
* **Globalisation:** an l1 merit function with Armijo backtracking; a rejected full step
  that raised the rows' violation is retried with up to four second-order corrections
  in a row, as IPOPT's (the rows taken at the end of the last corrected step: curved
  rows, the Maratos effect; both QP models), and after a shortened step the Hessian is
  damped (Levenberg-Marquardt).
* **Seeding** (``seed="ipopt"``): on a cold start (no multipliers: the first step, a
  reset, a retry) IPOPT solves first and the SQP polishes its answer; an answer costing
  more than ``seed_ratio`` times the last one's is solved so too, the cheaper kept (not
  in real-time iterations, whose steps must keep their bounded cost). From
  rest with the clearance binding the SQP alone stopped in a local optimum ~4x IPOPT's.
* **Stopping:** stationarity ``||grad f + A^T lam||_inf``, constraint violation and
  complementarity all ``<= tol`` (default ``1e-6``), at each new iterate with the last
  QP's multipliers; or, as IPOPT's acceptable level, stationarity and complementarity
  ``<= acceptable_tol`` (violation ``<= constr_viol_tol``) for ``acceptable_iter``
  iterations in a row (the hierarchy's cost bounds are degenerate where a higher
  level's optimum is ~0: convergence there is linear). With ``accept_at_max_iter``, a
  solve that reaches ``max_iter`` with its rows held (violation ``<= constr_viol_tol``)
  ends with that iterate (``Feasible_At_Maximum_Iterations``, as acados' SQP returns its
  last iterate): a step of bounded cost for real time, the next step going on from it.
* **Real-time iteration** (``rti=True``): one Gauss-Newton QP and a full step per call,
  from the shifted previous solution; successful if the QP is. Iterated, it converges to
  the same optimum.

The model Functions are compiled to C once and cached (``nmpc.backends.codegen``). The
loop below works on either model through ``qp_model.QpModel``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any, ClassVar

import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends.base import (
    BACKENDS,
    Backend,
    NlpResult,
    SolveRequest,
    make_backend,
)
from aeromanip.nmpc.backends.codegen import limit_blas_threads
from aeromanip.nmpc.backends.sqp.compiled_loop import HESSIAN_CODES, CompiledLoop
from aeromanip.nmpc.backends.sqp.condensed_qp import CondensedQpModel
from aeromanip.nmpc.backends.sqp.dense_qp import SOLVERS as QP_SOLVERS
from aeromanip.nmpc.backends.sqp.dense_qp import DenseQp, QpResult, failure_text
from aeromanip.nmpc.backends.sqp.hpipm import check_hpipm_options
from aeromanip.nmpc.backends.sqp.optimality import l1, violation
from aeromanip.nmpc.backends.sqp.qp_model import Linearization, QpModel
from aeromanip.nmpc.backends.sqp.sparse_qp import SparseQpModel
from aeromanip.nmpc.backends.sqp.sparse_rti import CompiledRti
from aeromanip.nmpc.transcription import Transcription

DEFAULTS: dict[str, Any] = {
    "max_iter": 50,  # QPs per solve
    "tol": 1e-6,  # KKT tolerance (stationarity, complementarity, constraint violation)
    # as IPOPT's "acceptable level": stationarity and complementarity <= acceptable_tol
    # and violation <= constr_viol_tol for acceptable_iter iterations in a row (or at
    # max_iter) end a solve successfully
    "acceptable_tol": 1e-5,
    "constr_viol_tol": 1e-6,
    "acceptable_iter": 5,
    # at max_iter, an iterate whose rows hold is the answer (a bounded step for real
    # time); False: the solve failed (the controller's fallback)
    "accept_at_max_iter": False,
    "rti": False,  # one QP per solve
    "codegen": True,  # compile the model Functions to C (cached on disk)
    # run the whole loop in compiled C where it applies (the condensed model with DAQP,
    # compiled; ``compiled_loop``), and a real-time iteration on the sparse model with the
    # Riccati solver (``sparse_rti``): same answers, a fraction of the time
    "compiled_loop": True,
    # with the compiled loop: the whole controller step in one compiled call where it
    # applies (the weighted or strict hierarchical strategy on the condensed model with
    # DAQP, no time budget; ``nmpc.compiled_controller``): same answers
    "compiled_step": True,
    # "gauss-newton", "exact" (made positive definite), or "auto": Gauss-Newton,
    # exact from the first shortened step or the 7th iteration of a solve on
    "hessian": "auto",
    "regularization": 1e-9,  # added to the Hessian's diagonal
    # "auto": "daqp" up to condense_max_horizon steps, else "riccati"; "daqp" or
    # "qpoases": the condensed dense QP; "riccati" (aeromanip's compiled Riccati interior
    # point, HPIPM where it cannot be built) or "hpipm": the sparse multiple-shooting QP
    "qpsol": "auto",
    "condense_max_horizon": 12,  # steps
    "qpsol_options": {},  # extra options of the QP solver
    "screen": 0.1,  # QP rows farther than this from their bounds are left out at first
    "blas_threads": 1,  # OpenBLAS threads in this process (None: leave as is)
    # a robust first guess (module docstring): "ipopt" solves the NLP with IPOPT first on
    # a cold start, and when an answer costs more than seed_ratio times what the last
    # one promised; "none": never. At 3 the stress bench's `clearance` hierarchy was
    # re-seeded every time its reference rose to the base (p95 18.6 ms over 60 s, IPOPT
    # ~20 ms a seed) for the same closed-loop cost to 6 digits, as in every other case
    "seed": "ipopt",
    "seed_ratio": 10.0,
    # IPOPT's iterations in a seed: a strict hierarchy's higher level, lightly
    # regularised, took it 110 from a cold start in `waypoints` (50 stopped the first steps)
    "seed_max_iter": 200,
}
HESSIANS = ("auto", "exact", "gauss-newton")
SEEDS = ("ipopt", "none")
#: the sparse model's QP solvers: aeromanip's Riccati interior point, or HPIPM
SPARSE_QP_SOLVERS = ("riccati", "hpipm")
SEED_FLOOR = 1e-6  # [cost units] an answer within this of the promise is never re-seeded


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
    "accept_at_max_iter": lambda v: "" if isinstance(v, bool) else "true or false",
    "rti": lambda v: "" if isinstance(v, bool) else "true or false",
    "codegen": lambda v: "" if isinstance(v, bool) else "true or false",
    "compiled_loop": lambda v: "" if isinstance(v, bool) else "true or false",
    "compiled_step": lambda v: "" if isinstance(v, bool) else "true or false",
    "hessian": _one_of(HESSIANS),
    "regularization": _number(positive=False),
    "qpsol": _one_of(("auto", *QP_SOLVERS, *SPARSE_QP_SOLVERS)),
    "condense_max_horizon": _int_at_least(1),
    "qpsol_options": lambda v: "" if isinstance(v, Mapping) else "a table",
    "screen": _number(positive=False),
    "blas_threads": lambda v: "" if v is None or _int_at_least(1)(v) == "" else "an integer >= 1",
    "seed": _one_of(SEEDS),
    "seed_ratio": lambda v: "" if _number(True)(v) == "" and v >= 1 else "a finite number >= 1",
    "seed_max_iter": _int_at_least(1),
}
EXACT_FROM_ITERATION = 6  # "auto": the exact Hessian from this (0-based) iteration on
ARMIJO = 1e-4  # sufficient decrease of the l1 merit, per unit of its directional derivative
BACKTRACK = 0.5  # step-length factor per rejected trial
MIN_STEP = 1e-3  # the shortest step tried; taken as it is
# a step shorter than this share of the QP's (the line search nearly failed: the QP's
# inexact answer may not descend) makes the solve's later QPs exact (``accurate``)
ACCURATE_QPS_BELOW = 0.01
# Levenberg-Marquardt damping (relative to the Hessian's largest diagonal entry) after
# the first shortened step of a solve, and its factor per shortened (up) or full (down) one
DAMPING_START = 1e-3
DAMPING_GROWTH = 10.0
PENALTY_MARGIN = 1.1  # the merit's penalty exceeds the largest multiplier by this factor
PENALTY_FLOOR = 1e-8  # and by at least this
# second-order corrections of a rejected full step (IPOPT's max_soc and kappa_soc): at
# most this many in a row, each while the last cut the rows' violation by this factor
MAX_SOC = 4
KAPPA_SOC = 0.99
# a bounded solve, which counts its corrections, tries one where the full step raised the
# rows' l1 violation by more than this: rounding (~1e-15 a row) must not decide its QPs.
# A converged solve tries them at any rise (in the stress bench's ``clearance`` case 20
# of 32 corrections at rises below 1e-12 were accepted; without them two steps took 50 QPs)
SOC_MIN_RISE = 1e-10
#: the compiled loop's options, in the order of ``OPT_*`` in sqp_loop.h (``warm``: the
#: multipliers are given, set per solve)
LOOP_OPTIONS = ("max_iter", "tol", "acceptable_tol", "constr_viol_tol", "acceptable_iter",
                "rti", "hessian", "regularization", "warm", "accept_at_max_iter")  # fmt: skip
WARM_OPTION = LOOP_OPTIONS.index("warm")
#: the loop's successful ends
SOLVED = ("Solve_Succeeded", "Solved_To_Acceptable_Level", "Feasible_At_Maximum_Iterations")
#: the constants above, for the compiled loop
LOOP_CONSTANTS = {
    "exact_from_iteration": EXACT_FROM_ITERATION, "armijo": ARMIJO, "backtrack": BACKTRACK,
    "min_step": MIN_STEP, "damping_start": DAMPING_START, "damping_growth": DAMPING_GROWTH,
    "penalty_margin": PENALTY_MARGIN, "penalty_floor": PENALTY_FLOOR,
    "max_soc": MAX_SOC, "kappa_soc": KAPPA_SOC, "soc_min_rise": SOC_MIN_RISE,
}  # fmt: skip


@BACKENDS.register("sqp")
class SqpBackend(Backend):
    """SQP with Gauss-Newton (or exact) Hessians on a condensed or a multiple-shooting QP
    model (module docstring).

    Args:
        transcription: the NLP (its layout is kept for inputs and results).
        options: keys of ``DEFAULTS``.
    """

    name = "sqp"
    defaults: ClassVar[dict[str, Any]] = DEFAULTS
    needs_feasible_start: ClassVar[bool] = False

    def __init__(
        self, transcription: Transcription, options: Mapping[str, Any] | None = None
    ) -> None:
        self.opts = self.checked_options(options, transcription.N)
        self.bounded_iterations = bool(self.opts["accept_at_max_iter"])
        self.tr = transcription
        self.qpsol = self.pick_qp(self.opts, transcription.N)
        if self.qpsol in SPARSE_QP_SOLVERS:
            self.model: QpModel = SparseQpModel(transcription, {**self.opts, "qpsol": self.qpsol})
        else:
            self.model = CondensedQpModel(transcription, {**self.opts, "qpsol": self.qpsol})
        compiled = self.opts["compiled_loop"]
        self.loop = (
            CompiledLoop.for_model(self.model, self.opts, LOOP_CONSTANTS) if compiled else None
        )
        self.rti = CompiledRti.for_model(self.model, self.opts) if compiled else None
        coded = {"hessian": HESSIAN_CODES[self.opts["hessian"]], "warm": 0.0}
        self._loop_opts = np.array(
            [coded.get(k, self.opts.get(k)) for k in LOOP_OPTIONS], dtype=float
        )
        if self.opts["blas_threads"] is not None:  # every OpenBLAS loaded by now
            limit_blas_threads(int(self.opts["blas_threads"]))
        self._ipopt: Backend | None = None  # the seed, built on first use
        #: the next warm solve's answer, already computed (by the compiled controller
        #: step, which left the step to Python: ``nmpc.compiled_controller``), with the
        #: QP's memory of active rows after it; taken once instead of solving again
        self.precomputed: tuple[NlpResult, np.ndarray] | None = None
        self._promise: float | None = None  # the last answer's cost
        self.seeds = 0  # IPOPT seeds so far

    @staticmethod
    def pick_qp(opts: Mapping[str, Any], horizon: int) -> str:
        """The QP solver ``qpsol`` names, or for ``"auto"`` the one for ``horizon``."""
        if opts["qpsol"] != "auto":
            return str(opts["qpsol"])
        return "daqp" if horizon <= opts["condense_max_horizon"] else "riccati"

    @classmethod
    def checked_options(
        cls, options: Mapping[str, Any] | None, horizon: int | None = None
    ) -> dict[str, Any]:
        """The defaults updated with ``options``; an unknown key or a bad value is a
        ``ConfigError`` naming the key, the value and what is allowed (checked before
        anything is built). ``qpsol_options`` must suit the QP solver ``qpsol`` picks at
        ``horizon`` steps (with ``"auto"`` and no horizon: both it may pick)."""
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
        horizons = (1, 10**6) if horizon is None else (horizon,)
        for qpsol in dict.fromkeys(cls.pick_qp(opts, n) for n in horizons):  # in order
            if qpsol == "hpipm":
                check_hpipm_options(opts["qpsol_options"])
            elif qpsol == "riccati":
                if opts["qpsol_options"]:
                    given = ", ".join(map(str, opts["qpsol_options"]))
                    raise ConfigError(
                        f"solver_options.qpsol_options: {given}: qpsol 'riccati' takes no "
                        "options (its tolerances follow solver_options.tol)"
                    )
            else:
                DenseQp.check_options(qpsol, opts["qpsol_options"])
        return opts

    @classmethod
    def check_options(cls, options: Mapping[str, Any], horizon: int | None = None) -> None:
        """See ``checked_options``."""
        cls.checked_options(options, horizon)

    def solve(self, request: SolveRequest) -> NlpResult:
        """Solve from the primal guess ``w0`` and multipliers: the last control step's,
        moved a stage on here (``shift=False``: this step's); seeded by IPOPT on a cold
        start (no multipliers) or an answer far above the last one's cost (``seed``)."""
        seeded = self.opts["seed"] != "none"
        precomputed, self.precomputed = self.precomputed, None
        if seeded and request.cold:
            res = self._seeded(request)
        else:
            res = self._sqp(request) if precomputed is None else self._taken(precomputed)
            promise = self._promise
            if (
                seeded
                and not self.opts["rti"]  # an RTI step keeps its bounded cost
                and promise is not None
                and res.f > self.opts["seed_ratio"] * promise + SEED_FLOOR
            ):
                res = _cheaper(res, self._seeded(request))
        self._promise = res.f if res.success else None
        return res

    def _taken(self, precomputed: tuple[NlpResult, np.ndarray]) -> NlpResult:
        """The precomputed answer (``precomputed``), the QP's memory set as after it."""
        res, memory = precomputed
        self.model.qp.lam_a[:] = memory  # type: ignore[attr-defined]
        return res

    def _seeded(self, request: SolveRequest) -> NlpResult:
        """IPOPT from ``w0`` (at most ``seed_max_iter`` iterations), then the SQP from its
        answer and multipliers (the SQP alone from ``w0`` if IPOPT fails). The time of
        both is counted; ``iterations`` counts the QPs only."""
        self.seeds += 1
        if self._ipopt is None:
            # IPOPT relaxes every bound by 1e-8 by default; from an answer outside its box a
            # strict hierarchy's lower level found its first QP infeasible (the higher
            # level's rows pinned, a state just beyond its bound) and fell back on IPOPT
            opts = {"ipopt.max_iter": int(self.opts["seed_max_iter"]),
                    "ipopt.bound_relax_factor": 0.0}  # fmt: skip
            self._ipopt = make_backend(self.tr, "ipopt", opts)
        cold = request.cold_from(request.w0)
        first = self._ipopt.solve(cold)
        if not first.success:
            res = self._sqp(cold)
        else:
            res = self._sqp(
                replace(cold, w0=first.w, lam_g0=first.lam_g, lam_x0=first.lam_x, shift=False)
            )
        res.solve_time_s += first.solve_time_s
        return res

    def _sqp(self, request: SolveRequest) -> NlpResult:
        """The SQP loop (module docstring), compiled where it can be."""
        if self.loop is not None:
            return self._compiled_sqp(request)
        if self.rti is not None:
            return self._compiled_rti(request)
        return self._python_sqp(request)

    def _compiled_rti(self, request: SolveRequest) -> NlpResult:
        """A real-time iteration in C (``sparse_rti``): one call; a QP it did not solve is
        taken again by the Python loop, which checks its answer."""
        t0 = time.perf_counter()
        assert self.rti is not None
        p = np.ascontiguousarray(request.p, dtype=float)
        v, _, _ = self.model.start(replace(request, p=p))
        if not self.rti.step(v, p):
            return self._python_sqp(request)
        rti = self.rti
        w, lam_g, lam_x = self.model.result(rti.v.copy(), p, rti.lam_g.copy(), rti.lam_x.copy())
        ok = bool(np.all(np.isfinite(w)))
        return NlpResult(w, lam_g, lam_x, rti.info.f, ok, "RTI step", 1, time.perf_counter() - t0)

    def _compiled_sqp(self, request: SolveRequest) -> NlpResult:
        """The loop in C (``compiled_loop``): one call."""
        t0 = time.perf_counter()
        assert self.loop is not None
        p = np.ascontiguousarray(request.p, dtype=float)
        v, lam_c, lam_v = self.model.start(replace(request, p=p))
        self._loop_opts[WARM_OPTION] = 0.0 if request.cold else 1.0
        status = self.loop.solve(self._loop_opts, p, v, lam_c, lam_v)
        info = self.loop.info
        if status == "QP failed":
            flag = info.qp_exitflag
            why = failure_text("daqp", flag, flag == 1, bool(info.qp_finite), info.qp_excess)
            status = f"QP failed: {why}"
        ok = status in (*SOLVED, "RTI step")
        w, lam_g, lam_x = self.model.result(v, p, lam_c, lam_v)
        ok = ok and bool(np.all(np.isfinite(w)))
        return NlpResult(
            w, lam_g, lam_x, info.f, ok, status, info.iterations, time.perf_counter() - t0
        )

    def _python_sqp(self, request: SolveRequest) -> NlpResult:
        """The loop in Python: every model and QP solver."""
        t0 = time.perf_counter()
        o, model = self.opts, self.model
        request = replace(request, p=np.asarray(request.p, dtype=float))
        p = request.p
        v, lam_c, lam_v = model.start(request)
        mu, it, status, ok, f = 0.0, 0, "", False, np.nan
        exact = o["hessian"] == "exact"
        max_iter = 1 if o["rti"] else int(o["max_iter"])
        acceptable = 0  # iterations in a row at the acceptable level
        damping = 0.0  # Levenberg-Marquardt: grows after each shortened step
        accurate = False  # QPs to the tightest tolerance: after a line search nearly failed
        while True:
            lin = model.linearize(v, p)
            f = lin.f
            if not np.isfinite(f):  # NaN in derivatives shows in the QP's solution
                status = "Invalid_Number_Detected"
                break
            warm = not request.cold
            status, acceptable = self._verdict(v, lin, lam_c, lam_v, it, warm, acceptable, max_iter)
            if status:
                ok = status in SOLVED
                break
            qp = model.step(v, lin, lam_c, lam_v, p, exact, damping, accurate=accurate)
            it += 1
            if not qp.ok:
                status = f"QP failed: {qp.status}"
                break
            d, lam_c, lam_v = qp.d, qp.lam_a, qp.lam_x
            if o["rti"]:  # f stays the cost at the linearisation point
                v = v + d
                ok, status = True, "RTI step"
                break
            mu = max(mu, PENALTY_MARGIN * np.abs(lam_c).max(initial=0.0) + PENALTY_FLOOR)
            bounded = bool(o["accept_at_max_iter"])  # corrections count as QPs
            max_soc = min(MAX_SOC, max_iter - it) if bounded else MAX_SOC
            min_rise = SOC_MIN_RISE if bounded else 0.0
            alpha, soc, corrections = _line_search(model, v, d, p, lin, mu, max_soc, min_rise)
            it += corrections if bounded else 0
            if soc is not None:
                d, lam_c, lam_v = soc.d, soc.lam_a, soc.lam_x
            v = v + alpha * d
            damping = _damping(damping, alpha)
            accurate = accurate or alpha < ACCURATE_QPS_BELOW
            exact = o["hessian"] == "exact" or (
                o["hessian"] == "auto" and _go_exact(exact, alpha, it)
            )
        w, lam_g, lam_x = model.result(v, p, lam_c, lam_v)
        ok = ok and bool(np.all(np.isfinite(w)))
        return NlpResult(w, lam_g, lam_x, f, ok, status, it, time.perf_counter() - t0)

    def _verdict(
        self,
        v: np.ndarray,
        lin: Linearization,
        lam_c: np.ndarray,
        lam_v: np.ndarray,
        it: int,
        warm: bool,
        acceptable: int,
        max_iter: int,
    ) -> tuple[str, int]:
        """The loop's stopping test at an iterate: the status to stop with (``""``: go on)
        and the count of iterations in a row at the acceptable level. The KKT error is
        measured once the rows hold (not in RTI, nor before the first QP of a cold start,
        whose multipliers are not yet the iterate's)."""
        o = self.opts
        viol = 0.0 if o["rti"] else violation(lin.c, lin.lbc, lin.ubc)
        kkt = np.inf  # the larger of stationarity and complementarity
        if not o["rti"] and (it > 0 or warm) and viol <= o["constr_viol_tol"]:
            kkt = self.model.kkt_error(v, lin, lam_c, lam_v)
            if kkt <= o["tol"] and viol <= o["tol"]:
                return "Solve_Succeeded", acceptable
        acceptable = acceptable + 1 if kkt <= o["acceptable_tol"] else 0
        if acceptable >= o["acceptable_iter"] or (it >= max_iter and acceptable):
            return "Solved_To_Acceptable_Level", acceptable
        if it >= max_iter:
            if o["accept_at_max_iter"] and viol <= o["constr_viol_tol"]:
                return "Feasible_At_Maximum_Iterations", acceptable
            return "Maximum_Iterations_Exceeded", acceptable
        return "", acceptable


def _cheaper(a: NlpResult, b: NlpResult) -> NlpResult:
    """The successful answer of lower cost (``a`` if neither succeeded), with the effort
    of both."""
    best = b if b.success and (not a.success or b.f < a.f) else a
    other = a if best is b else b
    best.iterations += other.iterations
    best.solve_time_s += other.solve_time_s
    return best


def _go_exact(exact: bool, alpha: float, it: int) -> bool:
    """``hessian="auto"``: whether the next iteration uses the exact Hessian.

    Gauss-Newton converges slowly where residuals are large, so go exact at the first
    shortened step or the ``EXACT_FROM_ITERATION``-th iteration, and stay: both QP
    models convexify it on the reduced problem (the condensed Hessian, or the Riccati
    recursion's pivots of the per-stage blocks); ``SparseQpModel.step`` falls back to
    Gauss-Newton for an exact QP that fails or does not descend.
    """
    return exact or alpha < 1.0 or it >= EXACT_FROM_ITERATION


def _damping(damping: float, alpha: float) -> float:
    """The next iteration's Levenberg-Marquardt damping (relative to the Hessian's
    largest diagonal entry): up after a shortened step, down after a full one.

    Where the QP model is flat along a direction the rows curve away from (a null motion
    of the tasks, kept only by a small regulariser), its step is long and the merit
    takes a sliver of it, again and again; damping shortens the steps instead."""
    if alpha < 1.0:
        return max(DAMPING_GROWTH * damping, DAMPING_START)
    damping /= DAMPING_GROWTH
    return damping if damping >= DAMPING_START else 0.0


def _line_search(
    model: QpModel,
    v: np.ndarray,
    d: np.ndarray,
    p: np.ndarray,
    lin: Linearization,
    mu: float,
    max_soc: int = MAX_SOC,
    min_rise: float = 0.0,
) -> tuple[float, QpResult | None, int]:
    """Armijo backtracking on the l1 merit ``f + mu * sum(violations)``: the step length,
    the corrected QP step if the full step was accepted only with second-order
    corrections (a model's ``correction``, when it has one; at most ``max_soc`` in a
    row), and the count of corrections solved.

    The corrections follow IPOPT (Wachter and Biegler 2006, Sec. 2.4): tried only when
    the rejected full step raised the rows' violation (beyond ``min_rise``; they fix
    the rows' curvature, so a step rejected for the cost alone gains nothing from them:
    in the bench's ``fast`` case, 47 of 73 corrections of the weighted loop were such
    QPs, none accepted), each taking the rows at the end of the last corrected step, up
    to ``max_soc`` in a row while each cuts the violation by ``KAPPA_SOC``. Where a
    strict hierarchy's lower level moves along the higher level's curved rows, one
    correction left 1/20 of a long step's violation and the line search cut the step to
    a sliver, 50 times in a row; repeated, the corrections hold the rows and the level
    converges in 8-9 QPs. Where each correction is a whole solve (an interior point's:
    ``model.correction_is_a_solve``), one is tried only while the trial's rows' rise
    (times ``mu``) is at least what it misses the acceptance level by otherwise: a
    correction moves the rows, not the cost (at N = 20 in the bench's ``fast`` case, a
    quarter of the sparse hierarchy's corrections, none of them accepted, went)."""
    viol = l1(lin.c, lin.lbc, lin.ubc)
    phi0 = lin.f + mu * viol
    slope = float(lin.grad @ d) - mu * viol

    target = phi0 + ARMIJO * min(slope, 0.0)  # the full step's acceptance level
    solve_each = bool(getattr(model, "correction_is_a_solve", False))

    def trial(step: np.ndarray, alpha: float) -> tuple[bool, float, float]:
        """Whether ``v + step`` is accepted, its rows' violation and its cost."""
        f1, viol1 = model.merit(v + step, p)
        return f1 + mu * viol1 <= phi0 + ARMIJO * alpha * min(slope, 0.0), viol1, f1

    def worth(viol_step: float, f_step: float) -> bool:
        """Whether a correction may turn the rejected trial accepted, where it costs a
        whole solve (``model.correction_is_a_solve``): the rows' rise over the
        iterate's violation is at least what the trial misses the target by otherwise."""
        rise = mu * (viol_step - viol)
        return not solve_each or rise >= f_step + mu * viol - target

    full, viol_full, f_full = trial(d, 1.0)
    if full:
        return 1.0, None, 0
    correct = getattr(model, "correction", None)
    solved = 0
    if correct is not None and viol_full > viol + min_rise and worth(viol_full, f_full):
        step, viol_step = d, viol_full
        while solved < max_soc:
            soc = correct(v, step, lin, p)
            solved += 1
            if not soc.ok:
                break
            accepted, viol_soc, f_soc = trial(soc.d, 1.0)
            if accepted:
                return 1.0, soc, solved
            if viol_soc > KAPPA_SOC * viol_step or not worth(viol_soc, f_soc):
                break
            step, viol_step = soc.d, viol_soc
    alpha = BACKTRACK
    while not (trial(alpha * d, alpha)[0] or alpha < MIN_STEP):
        alpha *= BACKTRACK
    return alpha, None, solved


@BACKENDS.register("sqp-rti")
class SqpRtiBackend(SqpBackend):
    """``sqp`` with one Gauss-Newton QP and a full step per call (real-time iteration)."""

    name = "sqp-rti"
    defaults: ClassVar[dict[str, Any]] = {**DEFAULTS, "rti": True}
