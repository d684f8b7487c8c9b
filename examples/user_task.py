"""Example: a task of your own, ranked under end-effector tracking, in a real-time loop.

The end effector holds a point while a new task, written here without touching the
package, keeps the platform at a chosen height: a residual of the state, weighted and
ranked where it is added to the problem (level 1: only within what tracking leaves
free). Level 1 may spend the hierarchy's tolerance on the tracking cost (``abs_tol``,
1e-6 per stage: about 0.3 mm here with weight 10); make it smaller through
``Controller(..., hierarchy={"abs_tol": ...})``. Run: ``python examples/user_task.py``.
"""

import casadi as ca
import numpy as np

from aeromanip import (
    Bounds,
    Clearance,
    Controller,
    ControlRate,
    EndEffectorTracking,
    Problem,
    Stage,
    Task,
    load_robot,
)
from aeromanip.references import Constant


class PlatformHeight(Task):
    """``r = z - z_ref`` [m]: the platform's height above the ground."""

    name = "platform_height"

    def __init__(self, z_ref: float) -> None:
        self.z_ref = z_ref

    def residual(self, stage: Stage) -> ca.SX:
        """The height error (z is state 2 of ``[x, y, z, yaw, q...]``)."""
        return stage.x[2] - self.z_ref


def main() -> None:
    robot = load_robot("x8-3dof")
    problem = Problem(robot, horizon=10, dt=0.1, bounds=Bounds.from_robot(robot))
    problem.add_task(EndEffectorTracking(Constant([0.3, 0.2, 0.7])), weight=10.0, level=0)
    problem.add_task(PlatformHeight(1.15), weight=1.0, level=1)
    problem.add_task(ControlRate(), weight=0.05, level=None)  # regulariser, every level
    problem.add_constraint(Clearance(0.1))
    ctrl = Controller(problem, strategy="hierarchical", backend="sqp")

    x = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.6, -1.2])
    print(f"{'t s':>5} {'EE error mm':>12} {'z m':>6} {'solve ms':>9}  status")
    for k in range(60):
        cmd = ctrl.step(x, t=0.1 * k)
        x = x + 0.1 * cmd.u  # the ideal inner loop; a robot would apply cmd.u here
        err = np.linalg.norm(np.asarray(robot_ee(problem, x)) - [0.3, 0.2, 0.7])
        if k % 10 == 9:
            print(
                f"{0.1 * (k + 1):5.1f} {1e3 * err:12.2f} {x[2]:6.3f} "
                f"{1e3 * cmd.solve_time_s:9.2f}  {cmd.status}"
            )


def robot_ee(problem: Problem, x: np.ndarray) -> np.ndarray:
    """End-effector position [m], world frame."""
    return np.asarray(problem.kin.ee_position(x)).ravel()


if __name__ == "__main__":
    main()
