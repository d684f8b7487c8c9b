"""What every NLP solver backend is: the result type, the base class, the registry.

Built-in backends (one module each, registered by name in ``BACKENDS``):

* ``ipopt``: the robust reference (interior point, exact Hessian, MUMPS);
* ``fatrop``: a structure-exploiting interior-point method for optimal control
  (Riccati-based linear algebra over the stage-wise variable/constraint order);
* ``sqp``: Gauss-Newton SQP with exact condensing and dense QPs (DAQP), compiled model
  Functions; ``sqp-rti``: the same, one QP per call (real-time iteration).

``make_backend(transcription, name, options)`` builds one; a backend of your own is a
``Backend`` subclass named ``"package.module:Class"``.
"""

from __future__ import annotations

import re
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any, ClassVar

import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.nmpc.transcription import Transcription
from aeromanip.registry import Registry


@dataclass(frozen=True)
class SolveRequest:
    """One NLP solve's inputs: the primal guess ``w0``, the parameters ``p``, the row
    bounds ``lbg <= g <= ubg`` and the last control step's multipliers (``None``: a cold
    start), moved a stage on by the backend unless ``shift`` is False (this very step's)."""

    w0: np.ndarray
    p: np.ndarray
    lbg: np.ndarray
    ubg: np.ndarray
    lam_g0: np.ndarray | None = None
    lam_x0: np.ndarray | None = None
    shift: bool = True

    @property
    def cold(self) -> bool:
        """No multipliers given."""
        return self.lam_g0 is None

    def cold_from(self, w0: np.ndarray) -> SolveRequest:
        """The same NLP from ``w0`` without multipliers."""
        return replace(self, w0=w0, lam_g0=None, lam_x0=None, shift=True)


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


class Backend(ABC):
    """An NLP solver for one ``Transcription``, built once and called at every step.

    Args:
        transcription: the NLP (its variable and row layout is kept for inputs/results).
        options: the backend's own options (unknown keys are a ``ConfigError``).
    """

    kind: str = "backend"
    # what the backend needs, read by the strategies (never its name): an interior point
    # wants a start inside the relaxed hierarchy's rows, an SQP starts anywhere
    needs_feasible_start: ClassVar[bool] = True
    #: a solve that ran out of iterations is final (a bounded step), not retried cold
    bounded_iterations: bool = False

    @abstractmethod
    def __init__(
        self, transcription: Transcription, options: Mapping[str, Any] | None = None
    ) -> None: ...

    @classmethod
    def check_options(cls, options: Mapping[str, Any], horizon: int | None = None) -> None:
        """Raise ``ConfigError`` (one line naming the key) for options this backend
        cannot take at ``horizon`` steps (any horizon if ``None``); called before anything
        is built. By default: any table."""
        if not isinstance(options, Mapping):
            raise ConfigError(f"solver_options: must be a table, got {options!r}")

    @abstractmethod
    def solve(self, request: SolveRequest) -> NlpResult:
        """Solve ``request``: from its primal guess and the last control step's
        multipliers (moved a stage on unless ``request.shift`` is False)."""


BACKENDS: Registry[Backend] = Registry("backend", "aeromanip.nmpc.backends", Backend)


def make_backend(
    transcription: Transcription, name: str = "ipopt", options: Mapping[str, Any] | None = None
) -> Backend:
    """The backend registered as ``name`` (or ``"package.module:Class"``) for
    ``transcription``."""
    return BACKENDS.get(name, "controller.backend")(transcription, options)


def casadi_message(e: Exception) -> str:
    """CasADi's multi-line error as one line: its messages, without source locations,
    suggestions or option listings."""
    parts = []
    for line in str(e).splitlines():
        line = re.sub(r"^\.\.\./\S+?:\d+: ", "", line.strip())
        if not line or line.startswith(("Did you mean", ">")):
            break
        if not line.startswith(("Error calling", "Error in Function::call")):
            parts.append(line.rstrip(":"))
    return "; ".join(parts) or str(e).strip()[:200]
