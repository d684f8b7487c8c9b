"""Control-rate task ``||u_k - u_{k-1}||^2_{W_u}`` (paper eq. 4, Sec. IV-D)."""

from __future__ import annotations

import casadi as ca

from aeromanip.errors import ConfigError
from aeromanip.tasks.base import TASKS, Stage, Task


@TASKS.register("control_rate")
class ControlRate(Task):
    """``r = u_k - u_{k-1}`` (per DoF; the applied command for ``k = 0``) [state units/s].

    Per-DoF weights (given with ``Problem.add_task``) push motion to the arm or the
    platform (Sec. IV-D). The terminal term is ``r = u_{N-1}``: with the terminal weight
    ``W_s`` it is the paper's terminal control cost ``||u_{k+N}||^2_{W_s}``.
    """

    name = "control_rate"
    time_scaling = "difference"

    def residual(self, stage: Stage) -> ca.SX:
        """``u_k - u_{k-1}``."""
        if stage.u is None:
            raise ConfigError(
                f"{type(self).__name__}.residual: needs the stage command u, got None "
                "(the terminal stage has none: use terminal_residual)"
            )
        return stage.u - stage.u_prev

    def terminal_residual(self, stage: Stage) -> ca.SX:
        """The last command of the horizon."""
        return stage.u_prev
