"""A real-time iteration on the sparse model in one call of compiled C (``sparse_rti.c``).

What ``SparseQpModel.linearize`` and ``.step`` do for an RTI with the Riccati interior
point (the model's generated stage Functions through their C symbols, the Gauss-Newton
blocks, the gaps and the rows' bounds, the QP), without the Python between them. It
applies where the RTI takes the Gauss-Newton Hessian alone (not ``stagewise``, whose
cost rows add their curvature), the model is compiled and the Riccati solver is there;
a step whose QP is not solved is taken again by the Python path, which checks it. Built
once per machine into the compile cache with the solver (``c_library``).
"""

from __future__ import annotations

import ctypes
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from aeromanip.nmpc.backends.c_library import NATIVE_CFLAGS, CSources, load
from aeromanip.nmpc.backends.codegen import library_of
from aeromanip.nmpc.backends.sqp.ocp_ipm import RiccatiQp
from aeromanip.nmpc.backends.sqp.sparse_qp import SparseQpModel

HERE = Path(__file__).parent
SPEC = CSources(
    "aeromanip_sparse_rti",
    HERE,
    ("sparse_rti.c", "ocp_ipm.c", "model_fn.c"),
    ("ocp_ipm.h", "model_fn.h"),
    purpose="the compiled real-time iteration",
    cflags=NATIVE_CFLAGS,
)
SOLVED = 0  # ocp_ipm.h's OCP_IPM_SOLVED


class RtiInfo(ctypes.Structure):
    """``RtiInfo`` of ``sparse_rti.c``."""

    _fields_ = [
        ("f", ctypes.c_double),
        ("qp_status", ctypes.c_int),
        ("qp_iterations", ctypes.c_int),
    ]


def _library() -> ctypes.CDLL | None:
    lib = load(SPEC)
    if lib is None:
        return None
    ptr = ctypes.c_void_p
    lib.rti_new.restype = ptr
    lib.rti_new.argtypes = [ptr, ctypes.c_double, ptr, ptr, ptr, ptr, ptr, ctypes.c_int,
                            ptr, ptr, ptr, ptr]  # fmt: skip
    lib.rti_free.restype = None
    lib.rti_free.argtypes = [ptr]
    lib.rti_step.restype = ctypes.c_int
    lib.rti_step.argtypes = [ptr] * 11 + [ctypes.POINTER(RtiInfo)]
    return lib


class CompiledRti:
    """The compiled RTI of one sparse model; build with ``CompiledRti.for_model``."""

    def __init__(self, lib: ctypes.CDLL, model: SparseQpModel, symbols: list[Any],
                 regularization: float) -> None:  # fmt: skip
        self.lib, self.model, self._symbols = lib, model, symbols  # the libraries stay loaded
        tr = model.tr
        sizes = (model.N, model.nz, model.nx, model.nr, model.nc, model.nrT, model.ncT,
                 tr.problem.param_size, model.nw, model.ng)  # fmt: skip
        dims = np.array(sizes, dtype=np.intc)
        self._A = np.ascontiguousarray(tr.model.A, dtype=float)  # kept: C reads them
        self._B = np.ascontiguousarray(tr.model.B, dtype=float)
        gaps = np.ascontiguousarray(model.gap_rows, dtype=np.intc)
        slot = np.ascontiguousarray(model.row_slot, dtype=np.intc)
        src = np.ascontiguousarray(model.row_src, dtype=np.intc)
        fns = [ctypes.cast(s, ctypes.c_void_p) for s in symbols]
        self._handle = lib.rti_new(
            dims.ctypes.data, float(regularization), self._A.ctypes.data, self._B.ctypes.data,
            gaps.ctypes.data, slot.ctypes.data, src.ctypes.data, len(slot), *fns,
        )  # fmt: skip
        if not self._handle:
            raise MemoryError("the compiled real-time iteration could not allocate its buffers")
        self.info = RtiInfo()
        self.v = np.zeros(model.nw)
        self.lam_g, self.lam_x = np.zeros(model.ng), np.zeros(model.nw)

    @classmethod
    def for_model(cls, model: Any, opts: Mapping[str, Any]) -> CompiledRti | None:
        """The compiled RTI of ``model``, or ``None`` where it does not apply (not an RTI,
        not the sparse model with the Riccati solver, cost rows' curvature, the model not
        compiled, no library)."""
        if not opts["rti"] or not isinstance(model, SparseQpModel):
            return None
        if not isinstance(model.qp, RiccatiQp) or model.f_rows_gn is not None:
            return None
        if model.t_rows_gn is not None or not opts["codegen"]:
            return None
        symbols = []
        for f in (model.sources["stage"], model.sources["terminal"]):
            path = library_of(f)
            if path is None:
                return None
            so = ctypes.CDLL(str(path))
            symbols += [getattr(so, f.name()), getattr(so, f.name() + "_work")]
        lib = _library()
        return None if lib is None else cls(lib, model, symbols, opts["regularization"])

    def __del__(self) -> None:
        handle = getattr(self, "_handle", None)
        if handle:
            self.lib.rti_free(handle)
            self._handle = None

    def step(self, v: np.ndarray, p: np.ndarray) -> bool:
        """One RTI from ``v`` at parameters ``p`` (the model's row bounds, as ``start`` set
        them): ``self.v`` the new iterate, ``self.lam_g``, ``self.lam_x`` its multipliers,
        ``self.info`` the cost at ``v`` and the QP's figures; whether the QP was solved."""
        m = self.model
        lbw, ubw = m.bounds(p)
        arrays = [np.ascontiguousarray(a, dtype=float) for a in
                  (v, p, lbw, ubw, m.lbg, m.ubg, m.qp.settings)]  # fmt: skip
        code = self.lib.rti_step(
            self._handle, *(a.ctypes.data for a in arrays), self.v.ctypes.data,
            self.lam_g.ctypes.data, self.lam_x.ctypes.data, ctypes.byref(self.info),
        )  # fmt: skip
        return code == SOLVED and bool(np.isfinite(self.info.f))
