"""What the SQP loop (``nmpc.backends.sqp.solver``) needs from a QP model of the NLP.

Two models: ``CondensedQpModel`` (the commands only, a dense QP: fastest for short
horizons) and ``SparseQpModel`` (every stage's variables, a sparse OCP-structured
QP solved by HPIPM: cost and generated code linear in the horizon). The loop sees a
vector of variables ``v``, the constraint rows ``c(v)`` with bounds, multipliers of the
rows (``lam_c``) and of the variable bounds (``lam_v``), CasADi's sign convention.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from aeromanip.nmpc.backends.base import SolveRequest
from aeromanip.nmpc.backends.sqp.dense_qp import QpResult


@dataclass
class Linearization:
    """The NLP at an iterate: cost ``f``, its gradient, the rows ``c`` and their bounds,
    and whatever the model needs to build its QP there (``data``)."""

    f: float
    grad: np.ndarray
    c: np.ndarray
    lbc: np.ndarray
    ubc: np.ndarray
    data: Any = None


class QpModel(Protocol):
    """A QP model of one transcription (see the module docstring)."""

    def start(self, request: SolveRequest) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The first iterate ``v`` (from the NLP guess ``w0``, inside the variable bounds)
        and multipliers ``lam_c``, ``lam_v`` (the last step's, moved a stage on with
        ``shift``); the row bounds ``lbg, ubg`` and the variable bounds for the
        parameters ``p`` are kept for this solve."""
        ...

    def linearize(self, v: np.ndarray, p: np.ndarray) -> Linearization:
        """Cost, gradient and rows at ``v``."""
        ...

    def kkt_error(
        self, v: np.ndarray, lin: Linearization, lam_c: np.ndarray, lam_v: np.ndarray
    ) -> float:
        """The larger of stationarity and complementarity at ``v``."""
        ...

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
        """The QP step from ``v`` (Gauss-Newton Hessian, or the exact one made positive
        definite, plus ``damping`` times its largest diagonal entry on the diagonal: a model
        may ignore it, the sparse one does), its multipliers and whether the QP solver
        succeeded. ``accurate``: solve the QP to the solver's tightest tolerance (a model
        whose QP solver is an interior point, the sparse one, otherwise solves it only as
        tightly as the SQP's tolerance needs; an active-set solver is exact anyway)."""
        ...

    def merit(self, v: np.ndarray, p: np.ndarray) -> tuple[float, float]:
        """Cost and l1 row violation at ``v`` (for the line search)."""
        ...

    def result(
        self, v: np.ndarray, p: np.ndarray, lam_c: np.ndarray, lam_v: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The NLP's variables and multipliers (``w, lam_g, lam_x``) of an iterate."""
        ...
