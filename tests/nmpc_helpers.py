"""Shared by the NMPC contract tests: a start state and the plan that rests there."""

from __future__ import annotations

import numpy as np

X0 = np.array([0.0, 0.0, 1.0, 0.0, 0.3, 0.4, -0.8])  # x8-3dof: [x, y, z, yaw, q1, q2, q3]


def rest(pb, U=None):
    """States rolled out from ``X0`` under commands ``U`` (default: rest)."""
    U = np.zeros((pb.horizon, 7)) if U is None else U
    X = X0 + np.vstack([np.zeros(7), np.cumsum(pb.dt * U, axis=0)])
    return X, U
