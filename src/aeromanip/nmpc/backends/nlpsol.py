"""CasADi ``nlpsol`` backends for a ``Transcription``, with warm start: ``ipopt``, ``fatrop``."""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.nmpc.backends.base import BACKENDS, Backend, NlpResult
from aeromanip.nmpc.transcription import Transcription

IPOPT_OPTIONS: dict[str, Any] = {
    "print_time": False,
    "ipopt.print_level": 0,
    "ipopt.sb": "yes",
    "ipopt.max_iter": 300,
    "ipopt.warm_start_init_point": "yes",
    "ipopt.warm_start_bound_push": 1e-6,
    "ipopt.warm_start_mult_bound_push": 1e-6,
    "ipopt.mu_init": 1e-3,
}
FATROP_OPTIONS: dict[str, Any] = {
    "print_time": False,
    "structure_detection": "auto",
    "fatrop.print_level": 0,
    "fatrop.max_iter": 300,
    "fatrop.mu_init": 1e-3,
}


class NlpBackend(Backend):
    """A built-once ``nlpsol`` for one transcription (``solver`` names the plugin).

    Args:
        transcription: the NLP.
        options: extra CasADi/solver options overriding the defaults (e.g. ``{"ipopt.tol": 1e-6}``).
    """

    solver_name = "ipopt"

    def default_options(self) -> dict[str, Any]:
        """The plugin's options before the user's."""
        return dict(IPOPT_OPTIONS)

    def __init__(
        self, transcription: Transcription, options: Mapping[str, Any] | None = None
    ) -> None:
        self.tr = transcription
        name = self.name = self.solver_name
        nlp = {
            "x": transcription.w,
            "p": transcription.p,
            "f": transcription.f,
            "g": transcription.g,
        }
        opts = {**self.default_options(), **dict(options or {})}
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


@BACKENDS.register("ipopt")
class IpoptBackend(NlpBackend):
    """IPOPT: interior point, exact Hessian, MUMPS (the robust reference)."""

    solver_name = "ipopt"


@BACKENDS.register("fatrop")
class FatropBackend(NlpBackend):
    """fatrop: interior point with Riccati-based linear algebra over the stage structure."""

    solver_name = "fatrop"

    def default_options(self) -> dict[str, Any]:
        """fatrop's options, with the equality rows it needs to detect the structure."""
        return {**FATROP_OPTIONS, "equality": self.tr.equality}
