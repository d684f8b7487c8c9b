"""The force task: its residual and gradient against finite differences of an independent
NumPy evaluation, its options, and weighted and hierarchical NMPCs pressing a wall."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from aeromanip.config import Table
from aeromanip.errors import ConfigError
from aeromanip.nmpc.controller import Controller
from aeromanip.nmpc.problem import Problem
from aeromanip.references import Constant
from aeromanip.robot.kinematics import Kinematics
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import TASKS, ControlRate, EndEffectorTracking, NormalForce, Stage

K, S, R = 2900.0, 1e-4, 0.01  # stiffness [N/m], softplus width [m], probe radius [m]
X8 = load_robot("x8-3dof")
KIN = Kinematics(X8)
X0 = np.array([0.0, 0.0, 1.0, 0.0, 0.3, -0.6, 0.4])  # x, y, z, yaw, q1..q3


def _ee(x: np.ndarray) -> np.ndarray:
    return np.asarray(KIN.ee_position(x), dtype=float).ravel()


def _wall_at(x: np.ndarray, depth: float) -> dict:
    """A wall of normal -x whose rest point is ``depth`` [m] behind the EE at ``x``."""
    return dict(point=tuple(_ee(x) + np.array([R - depth, 0.0, 0.0])), normal=(-1.0, 0.0, 0.0))


def _force_numpy(x: np.ndarray, point, normal) -> float:
    """``k softplus_s((p_rest - p_e) . n)`` in NumPy (``logaddexp``), not the task's code."""
    n = np.asarray(normal) / np.linalg.norm(normal)
    d = (np.asarray(point) + R * n - _ee(x)) @ n
    return K * S * float(np.logaddexp(0.0, d / S))


@pytest.mark.parametrize("depth", [-5e-4, 0.0, 3e-4, 2e-3])
def test_residual_and_gradient_against_finite_differences(depth):
    wall = _wall_at(X0, depth)
    task = NormalForce(K, f_ref=2.0, smoothing=S, probe_radius=R, **wall)
    x, p = ca.SX.sym("x", X8.nx), ca.SX.sym("p", 1)
    r = task.residual(Stage(KIN, x, None, x, p, 0.1))
    f = ca.Function("f", [x, p], [r, ca.jacobian(r, x)])
    rng = np.random.default_rng(1)
    for xk in (X0, X0 + rng.normal(0.0, 1e-4, X8.nx)):
        value, jac = (np.asarray(v, dtype=float).ravel() for v in f(xk, 2.0))
        assert value[0] == pytest.approx(_force_numpy(xk, **wall) - 2.0, abs=1e-9)
        h = 1e-7
        fd = [
            (_force_numpy(xk + h * e, **wall) - _force_numpy(xk - h * e, **wall)) / (2 * h)
            for e in np.eye(X8.nx)
        ]
        np.testing.assert_allclose(jac, fd, rtol=1e-5, atol=1e-4 * K * 1e-3)
    if depth > 1e-3:  # well in contact: pushing the platform 1 m along x is k N more
        assert jac[0] == pytest.approx(K, rel=1e-6)


def test_schedule_and_options_from_a_table():
    table = Table(
        {"stiffness": 3000.0, "schedule": [[0.0, 0.0], [2.0, 2.0]], "point": [1, 0, 1],
         "normal": [-1, 0, 0]},
        "tasks.press",
    )  # fmt: skip
    task = TASKS.get("force").from_table(table, Constant([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(task.param_values(np.array([-1.0, 1.0, 5.0])).ravel(), [0, 1, 2])
    assert NormalForce(100.0, f_ref=1.5).param_values(np.zeros(2)).ravel().tolist() == [1.5] * 2
    with pytest.raises(ConfigError, match=r"^force.schedule: must be \[\[t, f\]"):
        NormalForce(100.0, schedule=[[1.0, 1.0], [0.5, 2.0]])
    with pytest.raises(ConfigError, match=r"^contact\.stiffness: "):
        NormalForce(0.0)
    with pytest.raises(ConfigError, match=r"^force: give both point and normal"):
        NormalForce(100.0, point=(0.0, 0.0, 0.0))
    with pytest.raises(ConfigError, match=r"^force: no surface"):
        NormalForce(100.0).spring()
    unbound = NormalForce(100.0, surface=1)
    with pytest.raises(ConfigError, match=r"^force.surface: 1, but the scenario has 1 "):
        unbound.use_scenario([((0, 0, 0), (0, 0, 1))], 0.02)
    unbound.use_scenario([((0, 0, 0), (0, 0, 1)), ((2, 0, 0), (-2, 0, 0))], 0.02)
    spring = unbound.spring()
    assert spring.normal == (-1.0, 0.0, 0.0) and spring.probe_radius == 0.02


def _press(strategy: str, levels: tuple[int, int]) -> tuple[list[float], float]:
    """Closed loop (ideal inner loops: x += dt u) on a wall 1 mm ahead of the probe's rest:
    the predicted normal force at the start and after each of 6 steps; 2 N set, the EE's
    y, z held (their largest drift [m] returned too)."""
    wall = _wall_at(X0, -1e-3)
    pb = Problem(X8, 8, 0.1)
    force = NormalForce(K, f_ref=2.0, smoothing=S, probe_radius=R, **wall)
    pb.add_task(force, weight=1.0, level=levels[0])
    hold = EndEffectorTracking(Constant(_ee(X0)), tracked="yz")
    pb.add_task(hold, weight=100.0, level=levels[1])
    pb.add_task(ControlRate(), weight=0.01, level=None)
    ctrl, x = Controller(pb, strategy), X0.copy()
    forces, drift = [force.spring().normal_force(_ee(x))], 0.0
    for k in range(6):
        cmd = ctrl.step(x, 0.1 * k)
        assert cmd.status == "ok"
        x = x + 0.1 * cmd.u
        forces.append(force.spring().normal_force(_ee(x)))
        drift = max(drift, float(np.max(np.abs(_ee(x)[1:] - _ee(X0)[1:]))))
    return forces, drift


@pytest.mark.parametrize("strategy, levels", [("weighted", (0, 0)), ("hierarchical", (0, 1))])
def test_nmpc_drives_the_predicted_force_to_the_set_force(strategy, levels):
    """From 1 mm off the wall (no force: < 1e-3 N) to 2 N within 2 steps, held (0.02 N),
    never beyond 1.5x the set force; the EE's y, z stay within 1 mm."""
    forces, drift = _press(strategy, levels)
    assert forces[0] < 1e-3
    np.testing.assert_allclose(forces[2:], 2.0, atol=0.02)
    assert max(forces) < 2.0 * 1.5
    assert not any(math.isnan(f) for f in forces)
    assert drift < 1e-3
