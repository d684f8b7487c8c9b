"""MAVLink 2 (PX4 offboard): ``frames`` (ENU/FLU <-> NED/FRD), ``protocol`` (the subset),
``bridge`` (the runtime's transport), ``arm`` (joints through the autopilot), ``vehicle``
and ``sitl`` (a software-in-the-loop PX4 stand-in over the MuJoCo physics)."""
