"""End-effector reference trajectories (world frame, metres, seconds); one kind a module."""

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
