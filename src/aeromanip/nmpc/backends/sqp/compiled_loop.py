"""The condensed model's SQP loop in compiled C: one call per solve.

``condensed_loop.c`` (with ``condensed_qp.c``, ``dense_linalg.c``, ``model_fn.c``) runs the
loop of ``solver.SqpBackend._sqp`` on the condensed model (``condensed_qp``) step for step:
the model's generated Functions (already compiled by ``codegen``) are called through
their C symbols, and the QP is solved by DAQP, as CasADi's own DAQP interface calls it.
DAQP is built with the loop from the sources in ``third_party/daqp`` (DAQP 0.5.1, MIT:
the sources of CasADi's own ``libdaqpstat.a``), so the loop does not depend on the
internals of whichever DAQP a CasADi wheel carries; ``aeromanip export`` ships the same
files. The loop itself is built
once per machine into the compile cache (``<cache>/aeromanip_condensed_loop-<hash>.so``,
checked like every entry); it takes the Python loop's constants from Python (each
stated once). The loop is used where it applies (``solver_options.compiled_loop``, the
condensed model with DAQP, the model compiled); elsewhere the Python loop runs, with the
same answers.
"""

from __future__ import annotations

import ctypes
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from aeromanip.nmpc.backends.c_library import NATIVE_CFLAGS, CSources, entry_of, load
from aeromanip.nmpc.backends.cache import CacheEntry
from aeromanip.nmpc.backends.codegen import library_of
from aeromanip.nmpc.backends.sqp.condensed_qp import CondensedQpModel
from aeromanip.nmpc.backends.sqp.convexify import (
    CONVEXIFY_DECADES,
    EIGEN_FLOOR,
    SHIFT_COUNT,
    SHIFT_FIRST,
    SHIFT_STEP,
)
from aeromanip.nmpc.backends.sqp.dense_qp import CROSS_TOL, SCREEN_ROUNDS, SOLVERS

HERE = Path(__file__).parent
#: DAQP 0.5.1's sources (MIT; the sources of CasADi's ``libdaqpstat.a``), in ``HERE``
THIRD_PARTY = "third_party"
DAQP = Path(THIRD_PARTY) / "daqp"
#: the loop's C sources (compiled together; ``controller_step.c``: a whole controller
#: step around the loop, the exported controller's and the Python controller's) and headers
SOURCES = (
    "condensed_loop.c",
    "condensed_qp.c",
    "dense_linalg.c",
    "model_fn.c",
    "controller_step.c",
)
HEADERS = ("sqp_loop.h", "dense_linalg.h", "model_fn.h", "controller_step.h")
DAQP_SOURCES = tuple(str(DAQP / "src" / f"{name}.c") for name in (
    "api", "auxiliary", "bnb", "daqp", "daqp_prox", "factorization", "utils"))  # fmt: skip
DAQP_HEADERS = tuple(str(DAQP / "include" / "daqp" / f"{name}.h") for name in (
    "api", "auxiliary", "bnb", "constants", "daqp", "daqp_prox", "factorization", "types",
    "utils"))  # fmt: skip
DAQP_INCLUDES = (str(DAQP / "include"), str(DAQP / "include" / "daqp"))
#: the Python loop's constants the C loop takes (``Constants`` in sqp_loop.h), in order
CONSTANTS = (
    "screen_rounds", "cross_tol", "exact_from_iteration", "armijo", "backtrack", "min_step",
    "damping_start", "damping_growth", "penalty_margin", "penalty_floor",
    "convexify_decades", "eigen_floor", "shift_first", "shift_step", "shift_count", "max_soc",
    "kappa_soc", "soc_min_rise",
)  # fmt: skip
#: DAQP settings the loop passes on, in ``sqp_new``'s order (NaN: DAQP's default)
DAQP_SETTINGS = (
    "primal_tol", "dual_tol", "zero_tol", "pivot_tol", "progress_tol",
    "cycle_tol", "iter_limit", "eps_prox", "eta_prox",
)  # fmt: skip
HESSIAN_CODES = {"auto": 0, "exact": 1, "gauss-newton": 2}
#: the loop's return codes -> the Python loop's status words
STATUS = {
    1: "Solve_Succeeded",
    2: "Solved_To_Acceptable_Level",
    3: "Maximum_Iterations_Exceeded",
    4: "Invalid_Number_Detected",
    5: "QP failed",
    6: "RTI step",
    7: "model evaluation failed",
    8: "Feasible_At_Maximum_Iterations",
}


class SqpInfo(ctypes.Structure):
    """``SqpInfo`` of ``condensed_loop.c``."""

    _fields_ = [
        ("f", ctypes.c_double),
        ("iterations", ctypes.c_int),
        ("qp_exitflag", ctypes.c_int),
        ("qp_finite", ctypes.c_int),
        ("qp_excess", ctypes.c_double),
    ]


def daqp_settings(qpsol_options: Mapping[str, Any]) -> np.ndarray | None:
    """The DAQP settings of ``qpsol_options`` (the Python loop's defaults first) in
    ``DAQP_SETTINGS`` order, or ``None`` if they hold anything the C loop cannot pass."""
    if set(qpsol_options) - {"daqp"}:
        return None
    given = {**SOLVERS["daqp"]["daqp"], **dict(qpsol_options.get("daqp", {}))}
    if set(given) - set(DAQP_SETTINGS):
        return None
    return np.array([float(given.get(k, np.nan)) for k in DAQP_SETTINGS])


def loop_settings(
    model: Any, opts: Mapping[str, Any], loop_constants: Mapping[str, float]
) -> tuple[np.ndarray, np.ndarray] | None:
    """The loop's DAQP settings (``DAQP_SETTINGS``) and constants (``CONSTANTS``) for
    ``model`` with the SQP's ``opts`` and ``loop_constants``, or ``None`` where the loop
    does not apply (another model or QP solver, DAQP options it cannot pass)."""
    if not isinstance(model, CondensedQpModel) or model.qp.solver != "daqp":
        return None
    daqp = daqp_settings(opts["qpsol_options"])
    if daqp is None:
        return None
    given = {**loop_constants, "screen_rounds": SCREEN_ROUNDS, "cross_tol": CROSS_TOL,
             "convexify_decades": CONVEXIFY_DECADES, "eigen_floor": EIGEN_FLOOR,
             "shift_first": SHIFT_FIRST, "shift_step": SHIFT_STEP,
             "shift_count": SHIFT_COUNT}  # fmt: skip
    return daqp, np.array([float(given[k]) for k in CONSTANTS])


def _spec(source_dir: Path) -> CSources:
    return CSources("aeromanip_condensed_loop", source_dir, SOURCES + DAQP_SOURCES,
                    HEADERS + DAQP_HEADERS, (), DAQP_INCLUDES, "the compiled SQP loop",
                    NATIVE_CFLAGS)  # fmt: skip


def loop_library(source_dir: Path = HERE) -> ctypes.CDLL | None:
    """The compiled loop (built into the cache on first use from the sources in
    ``source_dir``), or ``None`` (no compiler, or the build failed: one warning)."""
    lib = load(_spec(source_dir))
    if lib is not None:
        _declare(lib)
    return lib


def loop_entry(cc: str, source_dir: Path = HERE) -> CacheEntry:
    """The cache entry of the loop built from the sources in ``source_dir`` by ``cc``."""
    return entry_of(_spec(source_dir), cc)


def _declare(lib: ctypes.CDLL) -> None:
    ptr = ctypes.c_void_p
    lib.sqp_new.restype = ptr
    lib.sqp_new.argtypes = [ptr, ptr, ptr, ptr, ctypes.c_int, ctypes.c_double, ptr, ptr,
                            *[ptr] * 6]  # fmt: skip
    lib.sqp_solve.restype = ctypes.c_int
    lib.sqp_solve.argtypes = [ptr] * 11 + [ctypes.POINTER(SqpInfo)]
    lib.sqp_free.restype = None
    lib.sqp_free.argtypes = [ptr]


class CompiledLoop:
    """The compiled loop for one condensed model (module docstring).

    Build with ``CompiledLoop.for_model``, which says ``None`` where the loop does not
    apply.
    """

    def __init__(self, lib: ctypes.CDLL, model: CondensedQpModel, symbols: list[Any],
                 daqp: np.ndarray, constants: np.ndarray) -> None:  # fmt: skip
        self.lib, self._symbols = lib, symbols  # the model libraries stay loaded
        self.model = model
        self.daqp, self.constants = daqp, constants  # as given to the loop
        qp = model.qp
        dims = np.array([model.nU, model.nc, model.nr, model.nh, model.tr.p.numel()], np.intc)
        sizes = np.array(qp._sizes, dtype=np.intc)
        hier = np.ascontiguousarray(model.hier_elem_row, dtype=np.intc)
        always = np.ascontiguousarray(qp.always, dtype=np.uint8)
        fns = [ctypes.cast(s, ctypes.c_void_p) if s is not None else None for s in symbols]
        self._handle = lib.sqp_new(
            dims.ctypes.data, hier.ctypes.data, always.ctypes.data, sizes.ctypes.data,
            len(sizes), float(qp.screen), daqp.ctypes.data, constants.ctypes.data, *fns,
        )  # fmt: skip
        if not self._handle:
            raise MemoryError("the compiled SQP loop could not allocate its buffers")
        self.info = SqpInfo()
        self._info_ref = ctypes.byref(self.info)

    @classmethod
    def for_model(
        cls, model: Any, opts: Mapping[str, Any], loop_constants: Mapping[str, float]
    ) -> CompiledLoop | None:
        """The compiled loop of ``model``, or ``None`` where it does not apply (another
        model or QP solver, DAQP options it cannot pass, the model not compiled).
        ``loop_constants``: the SQP loop's own constants (``CONSTANTS`` names them)."""
        settings = loop_settings(model, opts, loop_constants)
        if settings is None or not opts["codegen"]:
            return None
        symbols = []
        for f in model.sources[:2] + (model.sources[4:5] or [None]):
            if f is None:
                symbols += [None, None]
                continue
            path = library_of(f)
            if path is None:
                return None
            so = ctypes.CDLL(str(path))
            symbols += [getattr(so, f.name()), getattr(so, f.name() + "_work")]
        lib = loop_library()
        return None if lib is None else cls(lib, model, symbols, *settings)

    def __del__(self) -> None:
        handle = getattr(self, "_handle", None)
        if handle:
            self.lib.sqp_free(handle)
            self._handle = None

    def solve(self, opts: np.ndarray, p: np.ndarray, v: np.ndarray, lam_c: np.ndarray,
              lam_v: np.ndarray) -> str:  # fmt: skip
        """One solve from ``v`` (updated in place, as are the multipliers ``lam_c``,
        ``lam_v`` and the QP's memory of active rows); returns the status word (the
        figures are in ``self.info``)."""
        m, qp = self.model, self.model.qp
        code = self.lib.sqp_solve(
            self._handle, opts.ctypes.data, p.ctypes.data, m.lbc.ctypes.data,
            m.ubc.ctypes.data, m.lbU.ctypes.data, m.ubU.ctypes.data, v.ctypes.data,
            lam_c.ctypes.data, lam_v.ctypes.data, qp.lam_a.ctypes.data, self._info_ref,
        )  # fmt: skip
        return STATUS.get(code, f"unknown status {code}")
