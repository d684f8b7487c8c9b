"""HPIPM for the SQP's sparse QP (``sparse_qp``): its options (the residual
tolerance and iterations by the kind of SQP, the user's options over them), a check
that HPIPM takes them, and the solver called on a QP's nonzeros."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import casadi as ca

from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends.base import casadi_message
from aeromanip.nmpc.backends.codegen import Buffered, quiet_stdout

# HPIPM (robust mode) reaches residuals of 1e-8 on these QPs in ~8 iterations, but rarely
# 1e-9 or below: then it runs all its iterations (at N = 50 ~1 ms each). A converged SQP
# needs its QPs solved well below its own tolerance: residuals of QP_TOL_SHARE times it,
# between the limits below. At the default tol = 1e-6 that is 1e-8 (5-7x faster steps than
# 1e-10 at N = 20-50, the same SQP iterations); at tol = 1e-9 (the backend matrix test's)
# it is 1e-10, as the SQP stalls there on steps solved to 1e-8 (flight-rates/20hz from
# rest). A real-time iteration takes one QP per control step: 1e-7 is plenty there
# (flight-rates' hierarchical RTI at 10 Hz, N = 50, in physics: 6 interior-point
# iterations a level where 1e-8 took 7, the step 14 % shorter, EE RMSE 1.155 mm against
# 1.154, the CoG offset 0.75 against 0.72 mm; 1e-6 took 5 and the CoG offset 0.93 mm).
# per kind of SQP: (the tightest residual tolerance asked of HPIPM, its iterations)
HPIPM_LIMITS = {"sqp": (1e-10, 50), "rti": (1e-7, 25)}
QP_TOL_SHARE = 1e-2  # a converged SQP's QP residuals: this times its own tol, ...
QP_TOL_LOOSEST = 1e-8  # ... at most this (and at least the "sqp" limit above)


def qp_tolerance(kind: str, sqp_tol: float) -> float:
    """HPIPM's residual tolerance in an SQP of tolerance ``sqp_tol`` (``kind``: ``"sqp"``
    for a converged one, ``"rti"`` for real-time iterations)."""
    tightest = HPIPM_LIMITS[kind][0]
    if kind == "rti":
        return tightest
    return min(QP_TOL_LOOSEST, max(tightest, QP_TOL_SHARE * sqp_tol))


def hpipm_options(
    kind: str, user: Mapping[str, Any] | None = None, sqp_tol: float = 0.0
) -> dict[str, Any]:
    """CasADi's ``conic`` options for HPIPM in a converged SQP (``"sqp"``) of tolerance
    ``sqp_tol`` or an RTI (``"rti"``), quiet, with the user's ``qpsol_options`` over them
    (inside ``"hpipm"`` key by key: one option given keeps the others' limits)."""
    iterations = HPIPM_LIMITS[kind][1]
    tol = qp_tolerance(kind, sqp_tol)
    residuals = ("res_g_max", "res_b_max", "res_d_max", "res_m_max")
    own = {"mode": "robust", "iter_max": iterations, **dict.fromkeys(residuals, tol)}
    user = dict(user or {})
    given = user.pop("hpipm", {})
    inner = {**own, **given} if isinstance(given, Mapping) else given  # HPIPM names a bad one
    return {"error_on_fail": False, "print_time": False, **user, "hpipm": inner}


def check_hpipm_options(options: dict[str, Any]) -> None:
    """HPIPM takes ``options`` (tried on a one-step OCP QP); a refused key inside
    ``hpipm = {...}`` is named (HPIPM's own message does not name it)."""
    refusal = _hpipm_refusal(options)
    if refusal is None:
        return
    inner = options.get("hpipm")
    if isinstance(inner, Mapping):
        for key, value in inner.items():
            if _hpipm_refusal({"hpipm": {key: value}}) is not None:
                refusal += f" (hpipm.{key} = {value!r})"
                break
    raise ConfigError(f"solver_options.qpsol_options: hpipm rejects them: {refusal}")


def _hpipm_refusal(options: dict[str, Any]) -> str | None:
    """HPIPM's message if it refuses ``options`` on a one-step OCP QP, else ``None``."""
    opts = hpipm_options("sqp", options)
    H = ca.DM.eye(3)
    A = ca.DM([[-1.0, -1.0, 1.0]])  # x1 = x0 + u0
    try:
        with quiet_stdout():
            qp = ca.conic("aeromanip_check", "hpipm", {"h": H.sparsity(), "a": A.sparsity()}, opts)
            qp(h=H, g=0.0, a=A, lba=0.0, uba=0.0, lbx=-1.0, ubx=1.0)
    except RuntimeError as e:
        return casadi_message(e)
    return None


def hpipm_solver(H_sp: ca.Sparsity, A_sp: ca.Sparsity, opts: dict[str, Any], tag: str) -> Buffered:
    """An HPIPM solver of the QP with Hessian and row sparsities ``H_sp``, ``A_sp`` and
    CasADi ``conic`` options ``opts``, called through an MX Function of the nonzeros
    (CasADi's buffer interface would keep feeding HPIPM the first call's data); ``tag``
    names it. Outputs: x, lam_a, lam_x, cost."""
    nw, ng = H_sp.size1(), A_sp.size1()
    with quiet_stdout():
        qp = ca.conic(f"aeromanip_hpipm_{tag}", "hpipm", {"h": H_sp, "a": A_sp}, opts)
    hn, an = ca.MX.sym("h", H_sp.nnz()), ca.MX.sym("a", A_sp.nnz())
    vec = {n: ca.MX.sym(n, m) for n, m in (("g", nw), ("lba", ng), ("uba", ng),
           ("lbx", nw), ("ubx", nw))}  # fmt: skip
    out = qp(h=ca.MX(H_sp, hn), a=ca.MX(A_sp, an), **vec)
    f = ca.Function(
        f"aeromanip_hpipm_call_{tag}",
        [hn, an, *vec.values()],
        [out["x"], out["lam_a"], out["lam_x"], out["cost"]],
    )
    return Buffered(f)
