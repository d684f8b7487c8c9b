"""The sparse QP by a Riccati-based interior point in compiled C (``ocp_ipm.c``).

The QP of ``sparse_qp.SparseQpModel`` is an optimal control problem: per stage a dense
Hessian block, the model's constant dynamics ``z[k+1] = A z[k] + B u[k] + b[k]``, bounds
on the stage's variables and rows ``C[k] y[k]`` between bounds, stage 0's state pinned.
``ocp_ipm.c`` solves it as HPIPM does (Mehrotra's predictor-corrector, one Riccati
factorisation per iteration, ``O(N)``), with the zeros of ``A`` and ``B`` skipped, and
without HPIPM's conversion from CasADi's sparse matrices on every call: at N = 50 it is
several times faster than HPIPM as CasADi's wheel builds it (BLASFEO's generic target).
It takes the same residual tolerances and iteration limits as HPIPM (``hpipm``). Built
once per machine into the compile cache (``c_library``); without a compiler the sparse
model uses HPIPM.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from aeromanip.nmpc.backends.c_library import NATIVE_CFLAGS, CSources, load

HERE = Path(__file__).parent
SPEC = CSources(
    "aeromanip_ocp_ipm",
    HERE,
    ("ocp_ipm.c", "riccati_pivots.c"),
    ("ocp_ipm.h",),
    purpose="the Riccati QP solver",
    cflags=NATIVE_CFLAGS,
    follows_codegen=False,
)
#: ``ocp_ipm_solve``'s status codes (``ocp_ipm.h``)
STATUS = {0: "solved", 1: "maximum iterations", 2: "stalled", 3: "not finite", 4: "not convex"}
USABLE = (0, 1, 2)  # statuses whose iterate is returned (the caller checks it)
# the slacks' least value at the start (and the bound multipliers' most), for a QP of
# unknown scale; an SQP's QPs are steps, small near convergence, and start nearer their
# bounds (``sparse_qp.STEP_SLACK_FLOOR``)
SLACK_FLOOR = 1.0


class OcpIpmInfo(ctypes.Structure):
    """``OcpIpmInfo`` of ``ocp_ipm.h``."""

    _fields_ = [
        ("iterations", ctypes.c_int),
        ("status", ctypes.c_int),
        ("res_stat", ctypes.c_double),
        ("res_eq", ctypes.c_double),
        ("res_ineq", ctypes.c_double),
        ("res_comp", ctypes.c_double),
    ]


def riccati_library() -> ctypes.CDLL | None:
    """The compiled solver (built into the cache on first use), or ``None``."""
    lib = load(SPEC)
    if lib is None:
        return None
    ptr = ctypes.c_void_p
    lib.ocp_ipm_new.restype = ptr
    lib.ocp_ipm_new.argtypes = [ctypes.c_int] * 5 + [ptr, ptr]
    lib.ocp_ipm_free.restype = None
    lib.ocp_ipm_free.argtypes = [ptr]
    lib.ocp_ipm_solve.restype = ctypes.c_int
    lib.ocp_ipm_solve.argtypes = [ptr] * 15 + [ctypes.POINTER(OcpIpmInfo)]
    lib.riccati_pivots.restype = ctypes.c_int
    lib.riccati_pivots.argtypes = [ctypes.c_int] * 3 + [ptr] * 3 + [ctypes.c_int,
                                                                 ctypes.c_double, ptr]  # fmt: skip
    return lib


class CompiledPivots:
    """``convexify.riccati_pivots`` in C (``riccati_pivots.c``, the same steps), for
    ``reduced_convexified``'s ``pivots``: about 10x faster at N = 20 (NumPy's calls on
    7 x 7 matrices cost more than their arithmetic)."""

    def __init__(self, lib: ctypes.CDLL, floor_share: float) -> None:
        self.lib, self.floor_share = lib, floor_share

    @classmethod
    def create(cls, floor_share: float) -> CompiledPivots | None:
        """The compiled recursion, or ``None`` where the library cannot be built here."""
        lib = riccati_library()
        return None if lib is None else cls(lib, floor_share)

    def __call__(self, stage_blocks: np.ndarray, terminal_block: np.ndarray, AB: np.ndarray,
                 reflect: bool) -> np.ndarray | None:  # fmt: skip
        """The stage blocks (a changed copy if ``reflect``), or ``None`` at a pivot that
        is not positive definite if not."""
        N, ns = stage_blocks.shape[:2]
        nx = AB.shape[0]
        nu = ns - nx
        H = (  # written only when reflecting
            np.array(stage_blocks, dtype=float, order="C", copy=True)
            if reflect
            else np.ascontiguousarray(stage_blocks, dtype=float)
        )
        HT = np.ascontiguousarray(terminal_block, dtype=float)
        AB = np.ascontiguousarray(AB, dtype=float)
        work = np.empty(nx * nx + nx * ns + ns * ns + 2 * nu * nu + nu + nx * nu)
        ok = self.lib.riccati_pivots(
            N, nx, nu, AB.ctypes.data, H.ctypes.data, HT.ctypes.data, int(reflect),
            self.floor_share, work.ctypes.data,
        )  # fmt: skip
        if not ok:
            return None
        return H if reflect else stage_blocks


@dataclass
class OcpSolution:
    """A QP's answer: ``y`` (stage-major ``[z0, u0, ..., zN]``), the multipliers in
    CasADi's convention (``lam_dyn`` of the rows ``z[k+1] - A z[k] - B u[k]``, ``lam_c``
    of the rows ``C[k] y[k]``, ``lam_y`` of the bounds; positive on an upper bound), the
    status word, whether the iterate may be used, and the iterations."""

    y: np.ndarray
    lam_dyn: np.ndarray
    lam_c: np.ndarray
    lam_y: np.ndarray
    status: str
    usable: bool
    iterations: int


class RiccatiQp:
    """The solver for one problem shape (``N`` stages, ``nx`` states, ``nu`` inputs,
    ``nc`` rows per stage and ``ncT`` at the end, dynamics ``A``, ``B``), to residuals
    ``tol`` in at most ``iter_max`` iterations, starting its slacks at ``slack_floor`` or
    more. Build with ``RiccatiQp.create``."""

    def __init__(self, lib: ctypes.CDLL, dims: tuple[int, int, int, int, int],
                 A: np.ndarray, B: np.ndarray, tol: float, iter_max: int,
                 slack_floor: float = SLACK_FLOOR) -> None:  # fmt: skip
        self.lib = lib
        self.N, self.nx, self.nu, self.nc, self.ncT = dims
        A = np.ascontiguousarray(A, dtype=float)
        B = np.ascontiguousarray(B, dtype=float)
        self._handle = lib.ocp_ipm_new(*dims, A.ctypes.data, B.ctypes.data)
        if not self._handle:
            raise MemoryError("the Riccati QP solver could not allocate its buffers")
        self.settings = np.array([tol, tol, tol, tol, float(iter_max), slack_floor])
        N, nv = self.N, self.nx + self.nu
        self._y = np.zeros(N * nv + self.nx)
        self._lam_dyn = np.zeros(N * self.nx)
        self._lam_c = np.zeros(N * self.nc + self.ncT)
        self._lam_y = np.zeros_like(self._y)
        self.info = OcpIpmInfo()
        #: the addresses of the arrays every call passes (settings, then the outputs)
        self._fixed = tuple(a.ctypes.data for a in (self.settings, self._y, self._lam_dyn,
                                                     self._lam_c, self._lam_y))  # fmt: skip
        self._info_ref = ctypes.byref(self.info)

    @classmethod
    def create(cls, dims: tuple[int, int, int, int, int], A: np.ndarray, B: np.ndarray,
               tol: float, iter_max: int, slack_floor: float = SLACK_FLOOR,
               ) -> RiccatiQp | None:  # fmt: skip
        """The solver, or ``None`` where the C library cannot be built here."""
        lib = riccati_library()
        return None if lib is None else cls(lib, dims, A, B, tol, iter_max, slack_floor)

    def __del__(self) -> None:
        handle = getattr(self, "_handle", None)
        if handle:
            self.lib.ocp_ipm_free(handle)
            self._handle = None

    def solve(
        self,
        H: np.ndarray,
        g: np.ndarray,
        b: np.ndarray,
        C: np.ndarray,
        row_bounds: tuple[np.ndarray, np.ndarray],
        bounds: tuple[np.ndarray, np.ndarray],
        x0: np.ndarray,
    ) -> OcpSolution:
        """Solve: ``H`` the Hessian blocks (``N`` of ``nv x nv``, then ``nx x nx``), ``g``
        the gradient, ``b`` the dynamics' offsets (``N x nx``), ``C`` the rows' blocks
        (``N`` of ``nc x nv``, then ``ncT x nx``), their bounds (``-inf``/``inf``: none),
        the variables' bounds and ``x0`` (stage 0's state); arrays C-contiguous, float."""
        lg, ug = row_bounds
        lb, ub = bounds
        given = (H, g, b, C, lg, ug, lb, ub, x0)
        code = self.lib.ocp_ipm_solve(
            self._handle, *[a.ctypes.data for a in given], *self._fixed, self._info_ref
        )
        return OcpSolution(
            self._y.copy(), self._lam_dyn.copy(), self._lam_c.copy(), self._lam_y.copy(),
            STATUS.get(code, f"status {code}"), code in USABLE, self.info.iterations,
        )  # fmt: skip
