"""aeromanip: nonlinear model predictive control (NMPC) of aerial manipulators.

Implements Lunni et al., "Nonlinear Model Predictive Control for Aerial Manipulation",
ICUAS 2017: a kinematic UAM model, task costs composed by weights or as a strict
hierarchy, bounds and self-collision constraints, solved in a receding horizon.
"""

from aeromanip.errors import AeromanipError, ConfigError, InfeasibleProblemError, StateError
from aeromanip.nmpc.constraints import Bounds, Clearance, PathConstraint, UserConstraint
from aeromanip.nmpc.controller import Command, Controller
from aeromanip.nmpc.problem import Problem
from aeromanip.robot.kinematics import Kinematics
from aeromanip.robot.loader import builtin_robots, load_robot, robot_from_table
from aeromanip.robot.spec import Inertial, Joint, Platform, RobotSpec
from aeromanip.robot.urdf import arm_from_urdf
from aeromanip.robot.urdf_export import robot_to_urdf
from aeromanip.tasks import (
    CogAlignment,
    CogVelocity,
    ConditionNumber,
    ControlRate,
    EndEffectorTracking,
    Manipulability,
    Stage,
    Task,
)

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
