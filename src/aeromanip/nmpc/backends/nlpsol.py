"""CasADi ``nlpsol`` backends for a ``Transcription``, with warm start: ``ipopt``, ``fatrop``."""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Mapping
from typing import Any

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.interrupts import deferred, raise_if_interrupted
from aeromanip.nmpc.backends.base import (
    BACKENDS,
    Backend,
    NlpResult,
    SolveRequest,
    casadi_message,
)
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

    @classmethod
    def check_options(cls, options: Mapping[str, Any], horizon: int | None = None) -> None:
        """Options the plugin knows, of the right types: tried on a one-variable NLP
        (cheap: nothing is compiled), errors in one line naming the solver (any horizon)."""
        super().check_options(options, horizon)
        bad = [k for k in options if not isinstance(k, str)]
        if bad:
            raise ConfigError(f"solver_options: keys must be strings, got {bad[0]!r}")
        x0, u0, x1 = (ca.SX.sym(n) for n in ("x0", "u0", "x1"))  # a one-step OCP
        nlp = {"x": ca.vertcat(x0, u0, x1), "f": u0 * u0 + x1 * x1, "g": x1 - x0 - u0}
        defaults = IPOPT_OPTIONS if cls.solver_name == "ipopt" else FATROP_OPTIONS
        solver = _nlpsol(cls.solver_name, nlp, {**defaults, "equality": [True], **dict(options)})
        try:  # some plugins (fatrop) read their options only when they first solve
            solver(x0=[1.0, 0.0, 0.0], lbx=[1.0, -ca.inf, -ca.inf], ubx=[1.0, ca.inf, ca.inf])
        except RuntimeError as e:
            raise ConfigError(
                f"solver_options: {cls.solver_name} rejects the options: {casadi_message(e)}"
            ) from None

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
        self.check_options(options or {})
        opts = {**self.default_options(), **dict(options or {})}
        self.solver = _nlpsol(name, nlp, opts)
        # fatrop does not stop on NaN at its initial point (it spins): look first
        self._check_start = (
            ca.Function("f_g", [nlp["x"], nlp["p"]], [nlp["f"], nlp["g"]])
            if name == "fatrop"
            else None
        )

    def solve(self, request: SolveRequest) -> NlpResult:
        """Solve from the initial guess ``w0`` and, if given, the multipliers of the last
        control step (moved a stage on here, as ``w0`` is by the caller; ``shift=False``:
        multipliers of this very step, used as they are)."""
        w0, p, lbg, ubg = request.w0, request.p, request.lbg, request.ubg
        lam_g0, lam_x0, shift = request.lam_g0, request.lam_x0, request.shift
        lbw, ubw = self.tr.variable_bounds(p)
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
                with deferred():  # a signal ends the run after this solve, not the solve
                    out = self.solver(**args)
            except RuntimeError as e:  # evaluation errors (NaN) end in an exception
                error = str(e).splitlines()[-1] if str(e) else "solver error"
            stats = self.solver.stats()
            if stats.get("return_status") == INTERRUPTED_STATUS:
                _reraise_interrupt()
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
                _iterations(stats),
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
            iterations=_iterations(stats),
            solve_time_s=elapsed,
        )


def _iterations(stats: Mapping[str, Any]) -> int:
    """The iterations a solver's stats count (0 where it reports none)."""
    return int(stats.get("iter_count", 0))


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


INTERRUPTED_STATUS = "NonIpopt_Exception_Thrown"  # what IPOPT reports when CasADi caught a signal


def _reraise_interrupt() -> None:
    """A solve that ended because CasADi caught a signal: raise it again, never treat it
    as a solver failure to fall back from (``aeromanip.interrupts``)."""
    raise_if_interrupted()
    if (
        threading.current_thread() is threading.main_thread()
        and signal.getsignal(signal.SIGINT) is signal.default_int_handler
    ):
        raise KeyboardInterrupt  # Python's own Ctrl-C, swallowed by CasADi


def _nlpsol(name: str, nlp: dict[str, Any], opts: dict[str, Any]) -> ca.Function:
    """``casadi.nlpsol``; a bad option is one ``ConfigError`` line naming the solver."""
    try:
        return ca.nlpsol(f"nmpc_{name}", name, nlp, opts)
    except RuntimeError as e:
        raise ConfigError(
            f"solver_options: {name} rejects the options: {casadi_message(e)}"
        ) from None
