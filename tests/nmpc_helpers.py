"""Shared by the NMPC tests: a start state, the plan that rests there, the two-level
reaching problem the backends are compared on."""

from __future__ import annotations

import numpy as np

from aeromanip.nmpc.constraints import Bounds, Clearance
from aeromanip.nmpc.problem import Problem
from aeromanip.references import Constant
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import CogAlignment, ControlRate, EndEffectorTracking

X0 = np.array([0.0, 0.0, 1.0, 0.0, 0.3, 0.4, -0.8])  # x8-3dof: [x, y, z, yaw, q1, q2, q3]
FAST = {"codegen": False}  # in-process Functions: no compile time in most tests


def make_problem(levels=(0, 1), target=(0.5, 0.3, 0.6), box=None, horizon=10):
    """x8-3dof reaching ``target`` (level ``levels[0]``) with the CoG aligned (level
    ``levels[1]``), a rate regulariser and a 0.1 m clearance."""
    x8 = load_robot("x8-3dof")
    pb = Problem(x8, horizon, 0.5, Bounds.from_robot(x8, platform_box=box))
    pb.add_task(EndEffectorTracking(Constant(list(target))), weight=10.0, level=levels[0])
    pb.add_task(CogAlignment(), weight=1.0, level=levels[1])
    pb.add_task(ControlRate(), weight=0.1, level=None)
    pb.add_constraint(Clearance(0.1))
    return pb


def rest(pb, U=None):
    """States rolled out from ``X0`` under commands ``U`` (default: rest)."""
    U = np.zeros((pb.horizon, 7)) if U is None else U
    X = X0 + np.vstack([np.zeros(7), np.cumsum(pb.dt * U, axis=0)])
    return X, U
