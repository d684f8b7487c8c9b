"""UAM tasks (paper Sec. IV): each a residual whose weighted square is a cost term.

Exports:

* ``Task`` (the base: ``residual(stage)``; its ``from_table`` reads a scenario's options
  from the constructor's parameters), ``Stage`` (the symbols a residual sees), the
  registry ``TASKS`` (a scenario's ``kind``, or ``"package.module:Class"``);
* the built-ins ``EndEffectorTracking`` (h1), ``CogAlignment`` (h2), ``CogVelocity``
  (h3), ``Manipulability`` (h4), ``ConditionNumber`` (h5), ``ControlRate`` (the
  regulariser) and ``Posture``;
* contact: ``ContactSpring`` (the prediction's contact model), ``SurfaceTask`` (a task
  on a surface of the scenario), ``NormalForce`` (``f_n - f_ref``) and
  ``SurfaceTracking`` (the EE error in the surface's plane).
"""

from aeromanip.tasks.base import TASKS, Stage, Task
from aeromanip.tasks.cog import CogAlignment, CogVelocity
from aeromanip.tasks.contact import ContactSpring, SurfaceTask
from aeromanip.tasks.effort import ControlRate
from aeromanip.tasks.force import NormalForce
from aeromanip.tasks.manipulability import ConditionNumber, Manipulability
from aeromanip.tasks.posture import Posture
from aeromanip.tasks.surface_tracking import SurfaceTracking
from aeromanip.tasks.tracking import EndEffectorTracking

__all__ = [
    "TASKS",
    "CogAlignment",
    "CogVelocity",
    "ConditionNumber",
    "ContactSpring",
    "ControlRate",
    "EndEffectorTracking",
    "Manipulability",
    "NormalForce",
    "Posture",
    "Stage",
    "SurfaceTask",
    "SurfaceTracking",
    "Task",
]
