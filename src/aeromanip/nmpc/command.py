"""What the controller decided at one step (``Controller.step``'s answer)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from aeromanip.nmpc.strategies import LevelReport


@dataclass
class Command:
    """What the controller decided at one step.

    Attributes:
        u: command to apply now, ``dx/dt`` [m/s, rad/s] (nx,).
        plan_x: predicted states (N+1, nx); plan_u: predicted commands (N, nx).
        task_costs: weighted cost of each task over the horizon.
        status: ``ok``; ``partial`` (a lower hierarchy level failed, the higher levels'
            solution is applied); ``fallback`` (the previous plan is applied); ``stopped``.
        message: why, when not ``ok``.
        iterations, solve_time_s: solver effort (all levels).
        levels: per-level reports (hierarchical) or one report (weighted).
        force_ff: the thrust the flight controller should add [N, world] (tasks that use
            the measured contact force: ``Task.force_feedforward``); ``None``: none.
        observations: what the tasks logged this step (``Task.observations``).
    """

    u: np.ndarray
    plan_x: np.ndarray
    plan_u: np.ndarray
    task_costs: dict[str, float]
    status: str
    message: str
    iterations: int
    solve_time_s: float
    levels: list[LevelReport] = field(default_factory=list)
    force_ff: np.ndarray | None = None
    observations: dict[str, float] = field(default_factory=dict)
