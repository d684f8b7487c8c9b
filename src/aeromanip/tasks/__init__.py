"""UAM tasks (paper Sec. IV): each a residual whose weighted square is a cost term."""

from aeromanip.tasks.base import TASKS, Stage, Task
from aeromanip.tasks.cog import CogAlignment, CogVelocity
from aeromanip.tasks.effort import ControlRate
from aeromanip.tasks.manipulability import ConditionNumber, Manipulability
from aeromanip.tasks.posture import Posture
from aeromanip.tasks.tracking import EndEffectorTracking

__all__ = [
    "TASKS",
    "CogAlignment",
    "CogVelocity",
    "ConditionNumber",
    "ControlRate",
    "EndEffectorTracking",
    "Manipulability",
    "Posture",
    "Stage",
    "Task",
]
