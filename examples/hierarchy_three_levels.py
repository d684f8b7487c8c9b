"""Example: a strict hierarchy of three levels, against tracking alone.

Level 0 tracks the end effector along waypoints; level 1 aligns the arm's centre of
gravity under the platform (paper task h2) only within what level 0 leaves free; level 2
turns the platform's yaw and the arm's pan joint to rest (``Posture``) within what levels
0 and 1 leave free. The same flight with tracking alone is the yardstick: the lower levels
must not cost the tracking more than the hierarchy's tolerance, and they do reduce their
own costs.

Run: ``python examples/hierarchy_three_levels.py`` (a few seconds).

Prints, for both flights, the EE RMSE [mm], the mean arm-CoG offset [mm] and the mean
posture error [rad], then per level the mean cost at the applied solution, how much
level 0's cost rose above its own optimum (what levels 1 and 2 took), and a final
line ``hierarchy: EE RMSE ... mm (tracking alone ... mm), CoG offset ... mm (...)``.
"""

import numpy as np

from aeromanip import (
    Bounds,
    Clearance,
    CogAlignment,
    Controller,
    ControlRate,
    EndEffectorTracking,
    Problem,
    load_robot,
)
from aeromanip.references import Waypoints
from aeromanip.sim import KinematicSimulator
from aeromanip.tasks import Posture

X0 = [0.011292851, 0.0, 1.020614110, 0.3, 0.3, 0.6, -1.2]  # yaw and pan turned: 0.3 rad
DT, STEPS = 0.2, 40  # [s], 8 s
POINTS = [[0.0, 0.0, 0.6], [0.4, 0.2, 0.7], [0.2, -0.3, 0.6]]  # [m]
TIMES = [0.0, 3.0, 6.0]  # [s]


def fly(levels: int) -> dict[str, float]:
    """A closed loop with the first ``levels`` levels: EE, CoG and posture errors."""
    robot = load_robot("x8-3dof")
    reference = Waypoints(POINTS, TIMES)
    problem = Problem(robot, horizon=10, dt=DT, bounds=Bounds.from_robot(robot))
    problem.add_task(EndEffectorTracking(reference), weight=10.0, terminal_weight=10.0, level=0)
    if levels > 1:
        problem.add_task(CogAlignment(), weight=1.0, level=1)
        problem.add_task(Posture(["yaw", "q1"]), weight=0.1, level=2)
    problem.add_task(ControlRate(), weight=0.05, level=None)
    problem.add_constraint(Clearance(0.1))
    strategy = "hierarchical" if levels > 1 else "weighted"
    ctrl = Controller(problem, strategy=strategy, backend="sqp")
    sim = KinematicSimulator(robot)
    sim.reset(np.array(X0))
    ee_err, cog, posture, level_costs, worsened = [], [], [], [], []
    for k in range(STEPS):
        cmd = ctrl.step(sim.state(), t=k * DT)
        sim.advance(cmd.u, cmd.plan_x, DT)
        x = sim.state()
        ee = np.asarray(problem.kin.ee_position(x)).ravel()
        ee_err.append(np.linalg.norm(ee - reference.position((k + 1) * DT)))
        cog.append(np.linalg.norm(np.asarray(problem.kin.cog_body(x)).ravel()[:2]))
        posture.append(np.hypot(x[3], x[4]))
        level_costs.append([r.cost + r.loss for r in cmd.levels])
        # level 0 at the applied solution against level 0's own optimum (solved first)
        worsened.append(cmd.task_costs["tracking"] - cmd.levels[0].cost)
    return {
        "rmse_mm": 1e3 * float(np.sqrt(np.mean(np.square(ee_err)))),
        "cog_mm": 1e3 * float(np.mean(cog)),
        "posture_rad": float(np.mean(posture)),
        "level_costs": np.mean(level_costs, axis=0),
        "worsened": max(worsened),
    }


def main() -> None:
    alone, three = fly(1), fly(3)
    print(f"{'flight':>14} {'EE RMSE mm':>11} {'CoG mm':>8} {'posture rad':>12}")
    for name, r in (("tracking alone", alone), ("three levels", three)):
        print(f"{name:>14} {r['rmse_mm']:11.3f} {r['cog_mm']:8.2f} {r['posture_rad']:12.3f}")
    for level, cost in enumerate(three["level_costs"]):
        print(f"level {level}: mean cost at the applied solution {cost:.3e}")
    print(f"level 0's cost above its own optimum, at most: {three['worsened']:.2e}")
    print(
        f"hierarchy: EE RMSE {three['rmse_mm']:.3f} mm (tracking alone {alone['rmse_mm']:.3f} mm), "
        f"CoG offset {three['cog_mm']:.2f} mm ({alone['cog_mm']:.2f} mm)"
    )


if __name__ == "__main__":
    main()
