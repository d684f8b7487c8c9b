"""End-effector reference trajectories (world frame, metres, seconds); one kind a module.

Exports:

* ``Reference`` (the base: ``sample(times) -> (len, 3)`` positions), the registry
  ``REFERENCES`` (``"constant"``, ``"waypoints"``, ``"sinusoids"``, ``"lissajous"``,
  ``"csv"``, or ``"package.module:Class"``) and ``reference_from_table`` (a scenario's
  ``[reference]`` table);
* the built-ins ``Constant``, ``Waypoints``, ``SinusoidPhases``, ``Lissajous``, ``Csv``.
"""

from aeromanip.references.base import REFERENCES, Reference, reference_from_table
from aeromanip.references.constant import Constant
from aeromanip.references.lissajous import Lissajous
from aeromanip.references.sinusoids import SinusoidPhases
from aeromanip.references.tabulated import Csv
from aeromanip.references.waypoints import Waypoints

__all__ = [
    "REFERENCES",
    "Constant",
    "Csv",
    "Lissajous",
    "Reference",
    "SinusoidPhases",
    "Waypoints",
    "reference_from_table",
]
