"""Manipulability tasks: ``h4 = 1/D^2`` (paper eq. 13-14) and ``h5 = (1 - rho)^2`` (eq. 15-16)."""

from __future__ import annotations

from collections.abc import Sequence

import casadi as ca

from aeromanip.config import Table
from aeromanip.errors import ConfigError
from aeromanip.references import Reference
from aeromanip.tasks.base import TASKS, Stage, Task

TRACKED = "xyz"  # the coordinates whose Jacobian rows make J_eq
EPS = 1e-9  # [units of D] keeps 1/D finite at singular configurations
DELTA = 1e-9  # [units of J_eq J_eq^T] keeps rho finite at singular configurations
KINK = 1e-4  # rounding of rho's kinks (spectral.py), so that Newton-type solvers converge
MAX_KINK = 0.1  # a 10 % rounding of rho already blurs it
MAX_EPS = 1.0  # [units of D]
MAX_DELTA = 1.0  # [units of J_eq J_eq^T]


def _check(value: float, key: str, low: float, high: float) -> float:
    """``value`` as a float in ``[low, high]``, or a ``ConfigError`` naming ``key``."""
    ok = isinstance(value, int | float) and not isinstance(value, bool) and low <= value <= high
    if not ok:
        raise ConfigError(f"{key}: must be a number in [{low:g}, {high:g}], got {value!r}")
    return float(value)


@TASKS.register("manipulability")
class Manipulability(Task):
    """``r = 1 / (D + eps)`` with ``D = det(J_eq J_eq^T)``, so ``||r||^2 = 1/D^2``.

    ``eps`` (default 1e-9, units of ``D``) keeps the cost finite at singular
    configurations (``D = 0``); it changes the cost by a relative ``eps / D`` elsewhere.
    """

    name = "manipulability"

    def __init__(self, tracked: str | Sequence[str] = TRACKED, eps: float = EPS) -> None:
        self.tracked = tracked
        self.eps = _check(eps, "Manipulability.eps", 0.0, MAX_EPS)

    def residual(self, stage: Stage) -> ca.SX:
        """``1 / (D + eps)``."""
        D = stage.kin.manipulability(self.tracked)(stage.x)
        return 1.0 / (D + self.eps)

    @classmethod
    def from_table(cls, table: Table, reference: Reference) -> Manipulability:
        """Options: ``tracked``, ``eps``."""
        eps = table.float("eps", EPS, minimum=0.0, maximum=MAX_EPS)
        return cls(table.str("tracked", TRACKED), eps=eps)


@TASKS.register("condition")
class ConditionNumber(Task):
    """``r = 1 - rho`` with ``rho`` the condition number of ``J_eq J_eq^T``.

    ``rho`` uses the closed form of ``aeromanip.robot.spectral`` with its regularisation
    ``delta`` near singular configurations and ``kink`` (default 1e-4), which rounds the
    kinks of ``rho`` where two extreme eigenvalues coincide (where its minimum usually
    lies) so that Newton-type solvers converge; ``kink=1e-12`` gives the exact ``rho``.
    """

    name = "condition"

    def __init__(
        self, tracked: str | Sequence[str] = TRACKED, delta: float = DELTA, kink: float = KINK
    ) -> None:
        self.tracked = tracked
        self.delta = _check(delta, "ConditionNumber.delta", 0.0, MAX_DELTA)
        self.kink = _check(kink, "ConditionNumber.kink", 0.0, MAX_KINK)

    def residual(self, stage: Stage) -> ca.SX:
        """``1 - rho``."""
        return 1.0 - stage.kin.condition_number(self.tracked, self.delta, self.kink)(stage.x)

    @classmethod
    def from_table(cls, table: Table, reference: Reference) -> ConditionNumber:
        """Options: ``tracked``, ``delta``, ``kink``."""
        return cls(
            table.str("tracked", TRACKED),
            delta=table.float("delta", DELTA, minimum=0.0, maximum=MAX_DELTA),
            kink=table.float("kink", KINK, minimum=0.0, maximum=MAX_KINK),
        )
