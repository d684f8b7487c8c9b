"""NLP solver backends (CasADi ``nlpsol``) for a ``Transcription``, with warm start.

* ``ipopt``: the robust reference (interior point, exact Hessian, MUMPS).
* ``fatrop``: a structure-exploiting interior-point method for optimal control
  (Riccati-based linear algebra over the stage-wise variable/constraint order).
* ``sqp``: Gauss-Newton SQP with exact condensing and DAQP (or qpOASES), compiled model Functions
  (``aeromanip.sqp``); ``sqp-rti``: the same, one QP per call (real-time iteration).

``make_backend`` picks one by name.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.ocp import Transcription

BACKENDS = ("ipopt", "fatrop", "sqp", "sqp-rti")


@dataclass
class NlpResult:
    """One NLP solve: primal/dual solution, status and statistics."""

    w: np.ndarray
    lam_g: np.ndarray
    lam_x: np.ndarray
    f: float
    success: bool
    status: str
    iterations: int
    solve_time_s: float


class Backend(Protocol):
    """What strategies need from a solver backend."""

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
        """Solve from a primal guess and the last control step's multipliers (moved a
        stage on unless ``shift`` is False)."""
        ...


def _options(name: str, tr: Transcription, user: Mapping[str, Any]) -> dict[str, Any]:
    if name == "ipopt":
        opts: dict[str, Any] = {
            "print_time": False,
            "ipopt.print_level": 0,
            "ipopt.sb": "yes",
            "ipopt.max_iter": 300,
            "ipopt.warm_start_init_point": "yes",
            "ipopt.warm_start_bound_push": 1e-6,
            "ipopt.warm_start_mult_bound_push": 1e-6,
            "ipopt.mu_init": 1e-3,
        }
    elif name == "fatrop":
        opts = {
            "print_time": False,
            "structure_detection": "auto",
            "equality": tr.equality,
            "fatrop.print_level": 0,
            "fatrop.max_iter": 300,
            "fatrop.mu_init": 1e-3,
        }
    else:
        raise ConfigError(f"solver.backend: unknown backend {name!r} (choose from {BACKENDS})")
    opts.update(user)
    return opts


class NlpBackend:
    """A compiled-once ``nlpsol`` for one transcription.

    Args:
        transcription: the NLP.
        name: ``"ipopt"`` or ``"fatrop"``.
        options: extra CasADi/solver options overriding the defaults (e.g. ``{"ipopt.tol": 1e-6}``).
    """

    def __init__(
        self,
        transcription: Transcription,
        name: str = "ipopt",
        options: Mapping[str, Any] | None = None,
    ) -> None:
        self.tr = transcription
        self.name = name
        nlp = {
            "x": transcription.w,
            "p": transcription.p,
            "f": transcription.f,
            "g": transcription.g,
        }
        opts = _options(name, transcription, options or {})
        try:
            self.solver = ca.nlpsol(f"nmpc_{name}", name, nlp, opts)
        except RuntimeError as e:
            raise ConfigError(f"solver.backend: {name} could not be set up: {e}") from None
        # fatrop does not stop on NaN at its initial point (it spins): look first
        self._check_start = (
            ca.Function("f_g", [nlp["x"], nlp["p"]], [nlp["f"], nlp["g"]])
            if name == "fatrop"
            else None
        )

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
        """Solve from the initial guess ``w0`` and, if given, the multipliers of the last
        control step (moved a stage on here, as ``w0`` is by the caller; ``shift=False``:
        multipliers of this very step, used as they are)."""
        nx = self.tr.nx
        lbw, ubw = self.tr.variable_bounds(p[:nx], p[nx : 2 * nx])
        args: dict[str, Any] = {"x0": w0, "p": p, "lbx": lbw, "ubx": ubw, "lbg": lbg, "ubg": ubg}
        if lam_g0 is not None:
            args["lam_g0"] = np.asarray(lam_g0)[self.tr.shift_g] if shift else lam_g0
        if lam_x0 is not None:
            args["lam_x0"] = np.asarray(lam_x0)[self.tr.shift_w] if shift else lam_x0
        t0 = time.perf_counter()
        out, error, stats = None, "", {}
        if self._check_start is not None and not all(
            np.isfinite(np.asarray(v, dtype=float)).all() for v in self._check_start(w0, p)
        ):
            error = "Invalid_Number_Detected: cost or constraints not finite at the initial guess"
        else:
            try:
                out = self.solver(**args)
            except RuntimeError as e:  # evaluation errors (NaN) end in an exception
                error = str(e).splitlines()[-1] if str(e) else "solver error"
            stats = self.solver.stats()
        elapsed = time.perf_counter() - t0
        if out is None:
            n = self.tr.w.numel()
            return NlpResult(
                np.full(n, np.nan),
                np.zeros(self.tr.g.numel()),
                np.zeros(n),
                np.nan,
                False,
                error,
                int(stats.get("iter_count", 0)),
                elapsed,
            )
        w = np.asarray(out["x"]).ravel()
        ok = bool(stats.get("success", False)) and bool(np.all(np.isfinite(w)))
        return NlpResult(
            w=w,
            lam_g=np.asarray(out["lam_g"]).ravel(),
            lam_x=np.asarray(out["lam_x"]).ravel(),
            f=float(out["f"]),
            success=ok,
            status=_status_text(stats),
            iterations=int(stats.get("iter_count", -1)),
            solve_time_s=elapsed,
        )


def _status_text(stats: Mapping[str, Any]) -> str:
    """The solver's return status as text (fatrop reports a number: add CasADi's name)."""
    status = stats.get("return_status", "unknown")
    if isinstance(status, str):
        return status
    unified = stats.get("unified_return_status", "SOLVER_RET_UNKNOWN")
    return f"{unified} (code {status})"


def make_backend(
    transcription: Transcription, name: str = "ipopt", options: Mapping[str, Any] | None = None
) -> Backend:
    """The backend called ``name`` (one of ``BACKENDS``) for ``transcription``.

    ``sqp-rti`` is ``sqp`` with ``{"rti": True}``. Every backend has
    ``solve(w0, p, lbg, ubg, lam_g0=None, lam_x0=None) -> NlpResult``.
    """
    if name in ("sqp", "sqp-rti"):
        from aeromanip.sqp import SqpBackend

        opts = dict(options or {})
        if name == "sqp-rti":
            opts.setdefault("rti", True)
        return SqpBackend(transcription, opts)
    return NlpBackend(transcription, name, options)
