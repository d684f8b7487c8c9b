"""The real-time runtime: the controller on the wall clock, driving a vehicle through a
transport (``transport``: the interface; ``loop``: the control loop; ``follower`` and
``streamer``: setpoints between solves; ``session``: the run directory)."""
