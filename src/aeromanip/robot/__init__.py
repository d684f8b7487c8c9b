"""Robot description (spec, TOML, URDF) and its CasADi kinematics.

Exports:

* ``RobotSpec``, ``Platform``, ``Joint``, ``Inertial`` (the description);
* ``load_robot`` (a built-in name or a TOML file), ``builtin_robots``,
  ``robot_from_table`` (a parsed TOML table);
* ``arm_from_urdf``, ``arm_from_urdf_string``, ``UrdfArm`` (an arm from URDF) and
  ``robot_to_urdf`` (the whole robot as URDF);
* ``Kinematics`` (CasADi Functions: forward kinematics, arm CoG, Jacobians).
"""

from aeromanip.robot.kinematics import Kinematics
from aeromanip.robot.loader import builtin_robots, load_robot, robot_from_table
from aeromanip.robot.spec import Inertial, Joint, Platform, RobotSpec
from aeromanip.robot.urdf import UrdfArm, arm_from_urdf, arm_from_urdf_string
from aeromanip.robot.urdf_export import robot_to_urdf

__all__ = [
    "Inertial",
    "Joint",
    "Kinematics",
    "Platform",
    "RobotSpec",
    "UrdfArm",
    "arm_from_urdf",
    "arm_from_urdf_string",
    "builtin_robots",
    "load_robot",
    "robot_from_table",
    "robot_to_urdf",
]
