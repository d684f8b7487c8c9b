"""Optimality measures of the SQP's iterates: bound violation, its l1 sum (the merit
function's penalty) and complementarity.

Constraint rows ``lb <= g <= ub``; multipliers in CasADi's sign convention (``> 0`` at an
upper bound, ``< 0`` at a lower one).
"""

from __future__ import annotations

import numpy as np


def violation(g: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> float:
    """Largest bound violation of ``g`` (0 inside)."""
    if g.size == 0:
        return 0.0
    return float(max(np.max(lb - g), np.max(g - ub), 0.0))


def l1(g: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> float:
    """Sum of the bound violations of ``g``."""
    return float(np.sum(np.maximum(lb - g, 0.0)) + np.sum(np.maximum(g - ub, 0.0)))


def complementarity(g: np.ndarray, lb: np.ndarray, ub: np.ndarray, lam: np.ndarray) -> float:
    """Largest ``|lam| * distance to its bound`` (casadi sign: ``lam > 0`` at the upper one)."""
    if g.size == 0:
        return 0.0
    # the distance to the bound each multiplier belongs to (0 where it is 0: no 0 * inf)
    dist = np.where(lam > 0, ub - g, np.where(lam < 0, lb - g, 0.0))
    c = np.abs(lam * dist).max()
    return float(c) if np.isfinite(c) else np.inf
