"""aeromanip: nonlinear model predictive control (NMPC) of aerial manipulators.

Implements Lunni et al., "Nonlinear Model Predictive Control for Aerial Manipulation",
ICUAS 2017: a kinematic UAM model, task costs composed by weights or as a strict
hierarchy, bounds and self-collision constraints, solved in a receding horizon.
"""

from aeromanip.errors import AeromanipError, ConfigError, InfeasibleProblemError, StateError
from aeromanip.registry import lazy_exports

# each import on first use: the command line answers (and handles Ctrl-C) before numpy
# and CasADi are loaded
_LAZY = {
    "Bounds": "aeromanip.nmpc.constraints",
    "Clearance": "aeromanip.nmpc.constraints",
    "PathConstraint": "aeromanip.nmpc.constraints",
    "UserConstraint": "aeromanip.nmpc.constraints",
    "Command": "aeromanip.nmpc.controller",
    "Controller": "aeromanip.nmpc.controller",
    "Problem": "aeromanip.nmpc.problem",
    "Kinematics": "aeromanip.robot.kinematics",
    "builtin_robots": "aeromanip.robot.loader",
    "load_robot": "aeromanip.robot.loader",
    "robot_from_table": "aeromanip.robot.loader",
    "Inertial": "aeromanip.robot.spec",
    "Joint": "aeromanip.robot.spec",
    "Platform": "aeromanip.robot.spec",
    "RobotSpec": "aeromanip.robot.spec",
    "arm_from_urdf": "aeromanip.robot.urdf",
    "robot_to_urdf": "aeromanip.robot.urdf_export",
    "CogAlignment": "aeromanip.tasks",
    "CogVelocity": "aeromanip.tasks",
    "ConditionNumber": "aeromanip.tasks",
    "ControlRate": "aeromanip.tasks",
    "EndEffectorTracking": "aeromanip.tasks",
    "Manipulability": "aeromanip.tasks",
    "Stage": "aeromanip.tasks",
    "Task": "aeromanip.tasks",
}

__version__ = "0.1.0"

__all__ = [
    "AeromanipError",
    "Bounds",
    "Clearance",
    "CogAlignment",
    "CogVelocity",
    "Command",
    "ConditionNumber",
    "ConfigError",
    "ControlRate",
    "Controller",
    "EndEffectorTracking",
    "Inertial",
    "InfeasibleProblemError",
    "Joint",
    "Kinematics",
    "Manipulability",
    "PathConstraint",
    "Platform",
    "Problem",
    "RobotSpec",
    "Stage",
    "StateError",
    "Task",
    "UserConstraint",
    "arm_from_urdf",
    "builtin_robots",
    "load_robot",
    "robot_from_table",
    "robot_to_urdf",
]

__getattr__, __dir__ = lazy_exports(__name__, _LAZY, globals())
