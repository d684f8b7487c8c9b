"""The manipulability tasks' options: their documented ranges, defaults and error keys.

Truths: the module constants (``EPS``, ``DELTA``, ``KINK`` and their ``MAX_*`` bounds,
documented in ``tasks/manipulability.py`` as the defaults' one home), the closed
intervals they name (``[0, MAX]``: both ends are valid values), and the residuals'
formulas (paper eq. 13-16) evaluated with NumPy on a non-square ``J_eq``.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from aeromanip.config import Table
from aeromanip.errors import ConfigError
from aeromanip.robot.kinematics import Kinematics
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import manipulability as mp
from aeromanip.tasks.base import Stage
from aeromanip.tasks.manipulability import ConditionNumber, Manipulability

OPTIONS = [  # (class, option, constructor key named in the error, upper bound)
    (Manipulability, "eps", "Manipulability.eps", mp.MAX_EPS),
    (ConditionNumber, "delta", "ConditionNumber.delta", mp.MAX_DELTA),
    (ConditionNumber, "kink", "ConditionNumber.kink", mp.MAX_KINK),
]


@pytest.mark.parametrize(("cls", "option", "key", "high"), OPTIONS)
def test_both_ends_of_the_documented_range_are_valid(cls, option, key, high):
    for value in (0, 0.0, high):
        task = cls(**{option: value})
        got = getattr(task, option)
        assert got == value and type(got) is float
        task = cls.from_table(Table({option: value}, "tasks.t"), None)
        assert getattr(task, option) == value


@pytest.mark.parametrize(("cls", "option", "key", "high"), OPTIONS)
def test_values_outside_the_range_name_the_constructor_key(cls, option, key, high):
    for bad in (-1e-12, high * (1 + 1e-9), True, "0.1", None, float("nan")):
        with pytest.raises(ConfigError, match=rf"^{key}: must be a number in \[0, {high:g}\]"):
            cls(**{option: bad})


@pytest.mark.parametrize(("cls", "option", "key", "high"), OPTIONS)
def test_a_scenario_value_outside_the_range_names_its_key_path(cls, option, key, high):
    for bad in (-0.5, 2 * high):
        with pytest.raises(ConfigError, match=rf"^tasks\.t\.{option}\b"):
            cls.from_table(Table({option: bad}, "tasks.t"), None)


def test_defaults_are_the_module_constants():
    m = Manipulability()
    assert (m.tracked, m.eps) == (mp.TRACKED, mp.EPS)
    c = ConditionNumber()
    assert (c.tracked, c.delta, c.kink) == (mp.TRACKED, mp.DELTA, mp.KINK)
    m = Manipulability.from_table(Table({"tracked": "xz"}), None)
    assert (m.tracked, m.eps) == ("xz", mp.EPS)
    c = ConditionNumber.from_table(Table({"tracked": "yz", "kink": 0.01}), None)
    assert (c.tracked, c.delta, c.kink) == ("yz", mp.DELTA, 0.01)


# --- residual values on a non-square J_eq (2 tracked rows, 3 joints + 4 platform DoFs) ----


@pytest.fixture(scope="module")
def kin():
    return Kinematics(load_robot("x8-3dof"))


def _residual(task, kin, x):
    spec = kin.spec
    stage = Stage(
        kin=kin,
        x=ca.DM(x),
        u=ca.DM.zeros(spec.nx),
        u_prev=ca.DM.zeros(spec.nx),
        params=ca.DM.zeros(task.param_size),
        dt=0.1,
    )
    return float(task.residual(stage))


def _jeq(kin, x, rows):
    """Finite-difference Jacobian of the EE position w.r.t. the arm joints, ``rows`` kept."""
    n_p, h = kin.spec.n_platform, 1e-6
    J = np.zeros((3, kin.spec.n_joints))
    for i in range(kin.spec.n_joints):
        e = np.zeros(kin.spec.nx)
        e[n_p + i] = h
        J[:, i] = (
            np.asarray(kin.ee_position(x + e)).ravel() - np.asarray(kin.ee_position(x - e)).ravel()
        ) / (2 * h)
    return J[rows]


@pytest.mark.parametrize(("tracked", "rows"), [("yz", [1, 2]), ("xz", [0, 2])])
def test_residuals_follow_the_papers_formulas_with_fewer_rows_than_joints(kin, tracked, rows):
    x = np.array([0.3, -0.2, 1.0, 0.4, 0.5, 0.7, -0.9])
    A = _jeq(kin, x, rows) @ _jeq(kin, x, rows).T
    D = np.linalg.det(A)
    eps = 0.01
    assert _residual(Manipulability(tracked, eps=eps), kin, x) == pytest.approx(
        1 / (D + eps), rel=1e-6
    )
    lam = np.linalg.eigvalsh(A)
    rho = lam[-1] / lam[0]  # eq. 16: lambda_max / lambda_min of J_eq J_eq^T
    got = _residual(ConditionNumber(tracked, delta=0.0, kink=0.0), kin, x)
    assert got == pytest.approx(1 - rho, rel=1e-6)
