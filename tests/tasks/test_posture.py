"""The posture task: ``r = x[dofs] - target`` (its docstring), its options and errors.

Truths: the residual's documented formula evaluated with NumPy on the state vector
(entries picked by the robot's ``state_names``, in the order the task names them), the
default target 0, and the key paths of the scenario format.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from aeromanip.config import Table
from aeromanip.errors import ConfigError
from aeromanip.robot.kinematics import Kinematics
from aeromanip.robot.loader import load_robot
from aeromanip.tasks.base import Stage
from aeromanip.tasks.posture import Posture

X = np.array([0.1, -0.2, 1.3, 0.7, 0.25, -0.4, 0.9])  # x, y, z, yaw, q1, q2, q3


@pytest.fixture(scope="module")
def kin():
    return Kinematics(load_robot("x8-3dof"))


def residual(task, kin, x=X):
    stage = Stage(kin, ca.DM(x), ca.DM.zeros(7), ca.DM.zeros(7), ca.DM.zeros(0), 0.1)
    return np.asarray(ca.evalf(task.residual(stage))).ravel()


def test_residual_is_the_named_entries_minus_their_targets_in_the_tasks_order(kin):
    task = Posture(["q3", "yaw", "x"], [0.5, -0.1, 2.0])
    np.testing.assert_array_equal(residual(task, kin), [0.9 - 0.5, 0.7 + 0.1, 0.1 - 2.0])
    assert task.target == [0.5, -0.1, 2.0] and all(type(v) is float for v in task.target)


def test_default_target_is_zero(kin):
    task = Posture(["q1", "q2"])
    assert task.target == [0.0, 0.0]
    np.testing.assert_array_equal(residual(task, kin), [0.25, -0.4])


def test_from_table_reads_dofs_and_target_with_zero_default(kin):
    task = Posture.from_table(Table({"dofs": ["yaw", "q1"], "target": [0.3, 1]}, "tasks.p"), None)
    assert (task.dofs, task.target) == (["yaw", "q1"], [0.3, 1.0])
    np.testing.assert_allclose(residual(task, kin), [0.7 - 0.3, 0.25 - 1.0], atol=1e-15)
    task = Posture.from_table(Table({"dofs": ["z"]}, "tasks.p"), None)
    assert (task.dofs, task.target) == (["z"], [0.0])


@pytest.mark.parametrize(
    ("table", "match"),
    [
        ({"dofs": "yaw"}, r"^tasks\.p\.dofs: expected an array of state names"),
        ({"dofs": ["yaw", 3]}, r"^tasks\.p\.dofs: expected an array of state names"),
        ({"dofs": ["yaw", "q1"], "target": [0.1]}, r"^tasks\.p\.target"),
        ({}, r"tasks\.p\.dofs"),
    ],
)
def test_from_table_errors_name_the_key(table, match):
    with pytest.raises(ConfigError, match=match):
        Posture.from_table(Table(table, "tasks.p"), None)


def test_constructor_errors():
    with pytest.raises(ConfigError, match=r"^Posture\.dofs: expected distinct state names"):
        Posture([])
    with pytest.raises(ConfigError, match=r"^Posture\.dofs: expected distinct state names"):
        Posture(["q1", "q1"])
    with pytest.raises(ConfigError, match=r"^Posture\.target: expected 2 values \(one per DoF\)"):
        Posture(["q1", "q2"], [0.0])
    assert Posture(["q1", "q2"], [0.0, 1.0]).dofs == ["q1", "q2"]


def test_an_unknown_state_name_is_reported_when_the_residual_is_built(kin):
    with pytest.raises(ConfigError, match=r"^posture\.dofs: 'q4' is not a state of the robot"):
        residual(Posture(["q1", "q4"]), kin)
