"""The surface-tangential tracking task: its residual and gradient against an independent
NumPy evaluation (finite differences), and tasks on a surface taking the scenario's
``[[physics.surfaces]]`` entry."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.experiment.scenario import load_scenarios
from aeromanip.references import Constant
from aeromanip.robot.kinematics import Kinematics
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import NormalForce, Stage, SurfaceTracking

X8 = load_robot("x8-3dof")
KIN = Kinematics(X8)
X0 = np.array([0.1, -0.2, 1.0, 0.3, 0.3, -0.6, 0.4])
OBLIQUE = np.array([-1.0, 0.5, 0.3])


def _ee(x: np.ndarray) -> np.ndarray:
    return np.asarray(KIN.ee_position(x), dtype=float).ravel()


@pytest.mark.parametrize("normal", [[-1.0, 0.0, 0.0], [0.0, 0.0, -1.0], OBLIQUE.tolist()])
def test_tangential_error_and_gradient_against_finite_differences(normal):
    n = np.array(normal) / np.linalg.norm(normal)
    task = SurfaceTracking(Constant([0.0, 0.0, 0.0]), point=(1.0, 0.0, 1.0), normal=normal)
    x, p = ca.SX.sym("x", X8.nx), ca.SX.sym("p", 3)
    r = task.residual(Stage(KIN, x, None, x, p, 0.1))
    f = ca.Function("f", [x, p], [r, ca.jacobian(r, x), -ca.jacobian(r, p)])
    ref = np.array([0.3, -0.1, 0.5])
    value, jac, T = (np.asarray(v, dtype=float) for v in f(X0, ref))
    err = _ee(X0) - ref
    # the residual is the in-plane error: its norm is |err - (err . n) n|, and the plane's
    # two directions are orthonormal and normal to n (independent of the tangents' choice)
    np.testing.assert_allclose(T @ T.T, np.eye(2), atol=1e-12)
    np.testing.assert_allclose(T @ n, 0.0, atol=1e-12)
    in_plane = err - (err @ n) * n
    assert np.linalg.norm(value.ravel()) == pytest.approx(np.linalg.norm(in_plane), rel=1e-12)
    if abs(n[2]) < 0.99:
        assert abs(T[0, 2]) < 1e-12  # t1 horizontal, as the physics simulator's
    h = 1e-6
    fd = np.column_stack([T @ (_ee(X0 + h * e) - _ee(X0 - h * e)) / (2 * h) for e in np.eye(X8.nx)])
    np.testing.assert_allclose(jac, fd, atol=1e-8)


WALL = """
extends = "flight"
name = "press"
sim = "kinematic"
duration = 1.0

[physics]
probe_radius = 0.02

[[physics.surfaces]]
kind = "ceiling"
point = [0.0, 0.0, 3.0]
size = [1.0, 1.0]
friction = 0.3

[[physics.surfaces]]
kind = "wall"
point = [0.5, 0.0, 0.6]
normal = [-2.0, 0.0, 0.0]
size = [1.0, 1.0]
friction = 0.3

[tasks.press]
kind = "force"
stiffness = 2900.0
f_ref = 2.0
surface = 1
level = 0

[tasks.slide]
kind = "surface_tracking"
surface = 1
level = 0
"""


def test_tasks_take_the_scenario_surface(tmp_path):
    (tmp_path / "press.toml").write_text(WALL)
    sc = load_scenarios(tmp_path / "press.toml")[""]
    tasks = {e.name: e.task for e in sc.problem.entries}
    press, slide = tasks["press"], tasks["slide"]
    assert isinstance(press, NormalForce) and isinstance(slide, SurfaceTracking)
    spring = press.spring()
    assert spring.point == (0.5, 0.0, 0.6) and spring.normal == (-1.0, 0.0, 0.0)
    assert spring.probe_radius == 0.02
    assert slide.plane()[1].tolist() == [-1.0, 0.0, 0.0]
    assert sc.resolved["tasks"]["press"]["surface"] == 1
    (tmp_path / "bad.toml").write_text(
        WALL.replace(
            "surface = 1\nlevel = 0\n\n[tasks.slide]", "surface = 2\nlevel = 0\n\n[tasks.slide]"
        )
    )
    with pytest.raises(ConfigError, match=r"^tasks\.press: force\.surface: 2, but the scenario"):
        load_scenarios(tmp_path / "bad.toml")
