"""Example: the controller by hand, flying the full-dynamics (MuJoCo) simulator.

No scenario file: a ``Problem`` (end-effector tracking, control-rate regulariser, the
robot's bounds, the self-collision clearance), a ``Controller`` (weighted, SQP) and a
``PhysicsSimulator`` (rigid-body dynamics, a PX4-like flight controller, PID joint
servos) in a loop at 2 Hz for 10 s: the end effector moves 30 cm to a new point while the
platform tilts to fly. The error is measured on MuJoCo's end effector (the tilted
platform's), not on the controller's model.

Run: ``python examples/physics_by_hand.py`` (a few seconds).

Prints every 2 s the time, the physical EE error [mm], roll and pitch [deg] and the
solve time, then a final line ``physics by hand: EE error ... mm after 10.0 s``.
"""

import numpy as np

from aeromanip import (
    Bounds,
    Clearance,
    Controller,
    ControlRate,
    EndEffectorTracking,
    Problem,
    load_robot,
)
from aeromanip.references import Constant
from aeromanip.sim import PhysicsSimulator

TARGET = [0.3, 0.1, 0.75]  # [m] world frame
X0 = [
    0.011292851,
    0.0,
    1.020614110,
    0.0,
    0.0,
    0.6,
    -1.2,
]  # [x, y, z, yaw, q1..q3]: EE at (0, 0, 0.6)
DT, DURATION = 0.5, 10.0  # [s] 2 Hz, the paper's rate (faster needs the rate model)


def main() -> None:
    robot = load_robot("x8-3dof")
    problem = Problem(robot, horizon=10, dt=DT, bounds=Bounds.from_robot(robot))
    problem.add_task(EndEffectorTracking(Constant(TARGET)), weight=10.0)
    problem.add_task(ControlRate(), weight=0.05, level=None)
    problem.add_constraint(Clearance(0.1))
    ctrl = Controller(problem, strategy="weighted", backend="sqp")
    sim = PhysicsSimulator(robot)
    sim.reset(np.array(X0))

    print(f"{'t s':>4} {'EE error mm':>12} {'roll deg':>9} {'pitch deg':>9} {'solve ms':>9}")
    steps = round(DURATION / DT)
    for k in range(steps):
        cmd = ctrl.step(sim.state(), t=k * DT)
        sim.advance(cmd.u, cmd.plan_x, DT)  # the flight controller flies it for DT
        err_mm = 1e3 * float(np.linalg.norm(sim.ee_position() - TARGET))
        if (k + 1) % 4 == 0:
            att = sim.extras()
            print(
                f"{(k + 1) * DT:4.1f} {err_mm:12.1f} {np.degrees(att['roll']):9.2f} "
                f"{np.degrees(att['pitch']):9.2f} {1e3 * cmd.solve_time_s:9.2f}"
            )
    print(f"physics by hand: EE error {err_mm:.1f} mm after {DURATION:.1f} s")


if __name__ == "__main__":
    main()
