"""Example: an end-effector reference of your own, followed by the controller.

``Circle`` subclasses ``aeromanip.references.Reference``: ``sample(times)`` returns the
positions [m] at those times, shape (len, 3). Here a horizontal circle of radius 0.15 m
run once in 8 s, starting at the end effector's initial position. The controller
(weighted, SQP, 10 Hz, 1 s horizon) previews it over the horizon; the kinematic simulator
is the ideal inner loop.

Run: ``python examples/user_reference.py`` (about a second).

Prints every 2 s the reference, the EE position and their distance, then a final line
``user reference: EE RMSE ... mm over the circle (max ... mm)``.
"""

from collections.abc import Sequence

import numpy as np

from aeromanip import Bounds, Controller, ControlRate, EndEffectorTracking, Problem, load_robot
from aeromanip.references import Reference
from aeromanip.sim import KinematicSimulator

X0 = [0.011292851, 0.0, 1.020614110, 0.0, 0.0, 0.6, -1.2]  # EE at (0, 0, 0.6)
DT = 0.1  # [s]


class Circle(Reference):
    """A horizontal circle through ``start`` [m], radius ``radius`` [m], one turn in
    ``period`` [s], then held at ``start``."""

    def __init__(self, start: Sequence[float], radius: float, period: float) -> None:
        self.start = np.asarray(start, dtype=float)
        self.radius, self.period = radius, period
        self.duration = period

    def sample(self, times: np.ndarray | Sequence[float]) -> np.ndarray:
        """Positions [m] at ``times`` [s], shape (len(times), 3)."""
        t = np.clip(np.atleast_1d(np.asarray(times, dtype=float)), 0.0, self.period)
        a = 2 * np.pi * t / self.period
        offset = self.radius * np.stack([np.cos(a) - 1.0, np.sin(a), 0 * a], axis=1)
        return self.start + offset


def main() -> None:
    robot = load_robot("x8-3dof")
    circle = Circle(start=[0.0, 0.0, 0.6], radius=0.15, period=8.0)
    problem = Problem(robot, horizon=10, dt=DT, bounds=Bounds.from_robot(robot))
    problem.add_task(EndEffectorTracking(circle), weight=10.0, terminal_weight=10.0)
    problem.add_task(ControlRate(), weight=0.05, level=None)
    ctrl = Controller(problem, strategy="weighted", backend="sqp")
    sim = KinematicSimulator(robot)
    sim.reset(np.array(X0))

    errors = []
    print(f"{'t s':>4}  {'reference m':>22}  {'end effector m':>22}  {'error mm':>8}")
    for k in range(round(circle.period / DT)):
        t = k * DT
        sim.advance(ctrl.step(sim.state(), t=t).u, None, DT)
        ref = circle.position(t + DT)
        ee = np.asarray(problem.kin.ee_position(sim.state())).ravel()
        errors.append(np.linalg.norm(ee - ref))
        if (k + 1) % 20 == 0:
            print(f"{t + DT:4.1f}  {fmt(ref):>22}  {fmt(ee):>22}  {1e3 * errors[-1]:8.2f}")
    rmse, worst = float(np.sqrt(np.mean(np.square(errors)))), max(errors)
    print(f"user reference: EE RMSE {1e3 * rmse:.2f} mm over the circle (max {1e3 * worst:.2f} mm)")


def fmt(p: np.ndarray) -> str:
    """A position [m] as ``(x, y, z)``."""
    return "(" + ", ".join(f"{v:+.3f}" for v in p) + ")"


if __name__ == "__main__":
    main()
