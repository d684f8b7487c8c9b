"""Closed-loop simulators: the ideal kinematic loop and full-dynamics physics (MuJoCo)."""
