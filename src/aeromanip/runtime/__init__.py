"""The real-time runtime: the controller on the wall clock, driving a vehicle through a
transport (``transport``: the interface; ``loop``: the control loop; ``follower`` and
``streamer``: setpoints between solves; ``session``: the run directory).

Exports:

* ``RealtimeFlight`` (a scenario's controller flown against a ``Transport`` on the wall
  clock), ``FlightStats``;
* ``Transport`` (the vehicle link's interface), ``ArmInterface``, ``VehicleState``,
  ``Setpoint``, ``LinkError``;
* ``PlanFollower``, ``Plan`` (the plan between solves), ``Streamer`` (setpoints at the
  stream rate);
* ``fly_session`` (a flight into a run directory), ``SessionResult``;
* ``one_scenario`` (the one scenario, or variant, to fly).
"""

from __future__ import annotations

from aeromanip.registry import lazy_exports

# each import on first use: the session's plots load matplotlib
_LAZY = {
    "FlightStats": "aeromanip.runtime.loop",
    "RealtimeFlight": "aeromanip.runtime.loop",
    "ArmInterface": "aeromanip.runtime.transport",
    "LinkError": "aeromanip.runtime.transport",
    "Setpoint": "aeromanip.runtime.transport",
    "Transport": "aeromanip.runtime.transport",
    "VehicleState": "aeromanip.runtime.transport",
    "Plan": "aeromanip.runtime.follower",
    "PlanFollower": "aeromanip.runtime.follower",
    "Streamer": "aeromanip.runtime.streamer",
    "SessionResult": "aeromanip.runtime.session",
    "fly_session": "aeromanip.runtime.session",
    "one_scenario": "aeromanip.runtime.flight_scenario",
}

__all__ = sorted(_LAZY)

__getattr__, __dir__ = lazy_exports(__name__, _LAZY, globals())
