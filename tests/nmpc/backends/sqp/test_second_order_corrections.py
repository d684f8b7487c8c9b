"""Repeated second-order corrections (IPOPT's ``max_soc``) where a strict hierarchy's
lower level moves along the higher level's curved rows.

In the hierarchical flight, from step 848 on, the CoG level's QP steps run along the
tracking level's pinned residual rows, which curve strongly: one correction left a
twentieth of a long step's violation, the line search cut the step to a sliver, and the
level ran out of its 50 iterations five steps in a row (partial steps). Truth: IPOPT's
hierarchy on the same inputs (the bench's shadow), and the loop's own iteration count.
"""

import numpy as np
import pytest

from aeromanip.bench.shadow import IpoptHierarchyShadow
from aeromanip.experiment.closed_loop import make_controller
from aeromanip.experiment.scenario import load_scenarios

pytestmark = pytest.mark.codegen  # 850 steps of the flight: compiled

FIRST, LAST = 848, 853  # the steps whose second level crawled along the curved rows


def _flight_to(step: int):
    sets = ["controller.solver_options.seed=none"]
    sc = next(iter(load_scenarios("flight", sets, None).values()))
    ctrl, x, dt = make_controller(sc), sc.x0.copy(), sc.problem.dt
    for k in range(step):
        x = x + dt * ctrl.step(x, k * dt).u
    return ctrl, x, dt


def test_the_lower_level_converges_along_curved_rows_to_ipopts_answer():
    ctrl, x, dt = _flight_to(FIRST)
    shadow = IpoptHierarchyShadow(ctrl)
    for k in range(FIRST, LAST):
        seen = shadow.before(x, k * dt)
        cmd = ctrl.step(x, k * dt)
        shadow.after(*seen, cmd)
        assert cmd.status == "ok", (k, cmd.message)
        assert max(level.iterations for level in cmd.levels) <= 15, (k, cmd.levels)
        x = x + dt * cmd.u
    du = np.array(shadow.records)[:, 0]
    assert len(du) == LAST - FIRST and du.max() < 1e-4, du
