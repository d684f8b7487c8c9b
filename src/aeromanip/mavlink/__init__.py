"""MAVLink 2 (PX4 offboard): ``frames`` (ENU/FLU <-> NED/FRD), ``protocol`` (the subset),
``bridge`` (the runtime's transport), ``arm`` (joints through the autopilot), ``vehicle``
and ``sitl`` (a software-in-the-loop PX4 stand-in over the MuJoCo physics).

Exports (pymavlink, the ``mavlink`` extra, is imported only when a link opens):

* ``MavlinkTransport`` (the runtime's ``Transport`` over a MAVLink link),
  ``MavlinkActuatorArm`` (the arm's joints through ``MAV_CMD_DO_SET_ACTUATOR``);
* ``SitlAutopilot`` (PX4's offboard subset over the physics), ``Vehicle`` (its flight
  modes and failsafes), ``run_sitl`` (serve a scenario's vehicle until stopped);
* ``parse_link`` (check a link URL such as ``udpin:127.0.0.1:14540``), ``load_mavutil``.
"""

from __future__ import annotations

from aeromanip.registry import lazy_exports

# each import on first use: the SITL loads MuJoCo
_LAZY = {
    "MavlinkTransport": "aeromanip.mavlink.bridge",
    "MavlinkActuatorArm": "aeromanip.mavlink.arm",
    "SitlAutopilot": "aeromanip.mavlink.sitl",
    "Vehicle": "aeromanip.mavlink.vehicle",
    "run_sitl": "aeromanip.mavlink.sitl_run",
    "load_mavutil": "aeromanip.mavlink.protocol",
    "parse_link": "aeromanip.mavlink.protocol",
}

__all__ = sorted(_LAZY)

__getattr__, __dir__ = lazy_exports(__name__, _LAZY, globals())
