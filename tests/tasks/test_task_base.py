"""Task options and the ``Task`` base class contract.

Truths: the ``Task`` docstrings (``residual_size`` is the residual's length with the
stage symbols of the right sizes, ``param_values`` is ``(len(times), param_size)``),
the module constants that ``architecture.md`` names as the defaults' one home, and the
definition of a rotation matrix (``R^T R = I``) for the tracking orientation.
"""

import casadi as ca
import numpy as np
import pytest

from aeromanip.config import Table
from aeromanip.errors import ConfigError
from aeromanip.robot.kinematics import Kinematics
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import cog, manipulability
from aeromanip.tasks.base import Task
from aeromanip.tasks.cog import CogAlignment
from aeromanip.tasks.manipulability import ConditionNumber, Manipulability
from aeromanip.tasks.tracking import EndEffectorTracking


class UsesParamsAndDt(Task):
    """A residual that reads the last parameter and divides by ``dt``."""

    param_size = 4

    def residual(self, stage):
        return ca.vertcat(stage.params[3], stage.u[0] / stage.dt, stage.x[1])


@pytest.fixture(scope="module")
def kin():
    return Kinematics(load_robot("x8-3dof"))


def test_residual_size_builds_full_size_stage_symbols(kin):
    assert UsesParamsAndDt().residual_size(kin) == 3


def test_default_param_values_are_zeros_of_the_param_size():
    out = UsesParamsAndDt().param_values(np.array([0.0, 0.1, 0.2]))
    assert out.shape == (3, 4) and not out.any()


def test_cog_alignment_reads_target_xy():
    t = CogAlignment.from_table(Table({"target_xy": [0.1, -0.2]}), None)
    np.testing.assert_array_equal(np.asarray(t.target).ravel(), [0.1, -0.2])
    default = CogAlignment.from_table(Table({}), None)
    np.testing.assert_array_equal(np.asarray(default.target).ravel(), cog.TARGET_XY)
    with pytest.raises(ConfigError, match="target_xy"):
        CogAlignment.from_table(Table({"target_xy": [0.1, 0.2, 0.3]}), None)


def test_manipulability_and_condition_read_their_options():
    m = Manipulability.from_table(Table({"tracked": "yz", "eps": 0.25}), None)
    assert (m.tracked, m.eps) == ("yz", 0.25)
    m = Manipulability.from_table(Table({}), None)
    assert (m.tracked, m.eps) == (manipulability.TRACKED, manipulability.EPS)
    c = ConditionNumber.from_table(Table({"tracked": "xz", "delta": 0.5, "kink": 0.05}), None)
    assert (c.tracked, c.delta, c.kink) == ("xz", 0.5, 0.05)
    c = ConditionNumber.from_table(Table({}), None)
    assert (c.tracked, c.delta, c.kink) == (
        manipulability.TRACKED,
        manipulability.DELTA,
        manipulability.KINK,
    )


def rot_z(a):
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def test_tracking_orientation_accepts_rounded_rotations_only():
    """A rotation rounded at 1e-7 is one (``R^T R = I`` to 1e-6); ``1.3 I`` is not."""
    R = rot_z(0.3) + 1e-7
    assert EndEffectorTracking(None, orientation=R).orientation is not None
    with pytest.raises(ConfigError, match="rotation"):
        EndEffectorTracking(None, orientation=1.3 * np.eye(3))
