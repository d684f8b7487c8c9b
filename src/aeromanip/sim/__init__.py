"""Closed-loop simulators: the ideal kinematic loop and full-dynamics physics (MuJoCo).

Exports:

* ``Simulator`` (the interface: ``reset``, ``advance``, ``state``), the registry
  ``SIMULATORS`` (``"kinematic"``, ``"physics"``, or ``"package.module:Class"``);
* ``KinematicSimulator`` (``x <- x + dt u``, a perfect inner loop);
* ``PhysicsSimulator`` (MuJoCo rigid-body dynamics with a PX4-like flight controller),
  ``FlightController``, ``FlightGains``, ``Mixer``, ``FeedbackNoise``, and
  ``robot_to_mjcf`` (the robot as an MJCF model); the MuJoCo ones imported on first use.
"""

from __future__ import annotations

from aeromanip.registry import lazy_exports
from aeromanip.sim.base import SIMULATORS, Simulator
from aeromanip.sim.feedback import FeedbackNoise
from aeromanip.sim.flight_controller import FlightController, FlightGains, Mixer
from aeromanip.sim.kinematic import KinematicSimulator

# MuJoCo and the MJCF writer load in a few tenths of a second: imported when first named
_LAZY = {
    "PhysicsSimulator": "aeromanip.sim.physics",
    "robot_to_mjcf": "aeromanip.sim.mjcf",
}

__all__ = [
    "SIMULATORS",
    "FeedbackNoise",
    "FlightController",
    "FlightGains",
    "KinematicSimulator",
    "Mixer",
    "PhysicsSimulator",
    "Simulator",
    "robot_to_mjcf",
]


__getattr__, __dir__ = lazy_exports(__name__, _LAZY, globals())
