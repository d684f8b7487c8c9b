"""The do-mpc peer states the flight problem's objective as aeromanip does."""

import pytest

pytest.importorskip("do_mpc")

from aeromanip.bench.controller_speed import bench_scenario
from aeromanip.bench.peer_dompc import EQUIV_RTOL, equivalence


@pytest.mark.parametrize("seed, t", [(0, 0.0), (1, 3.0), (2, 41.5)])
def test_dompc_objective_equals_aeromanip(seed, t):
    """At one trajectory (random commands within the bounds) both objectives agree."""
    eq = equivalence(bench_scenario("flight", 60.0), seed=seed, t=t)
    assert eq["rel_diff"] < EQUIV_RTOL
    assert eq["rel_diff_costs"] < EQUIV_RTOL
    assert eq["f_aeromanip"] > 1.0  # the trajectory is far from the optimum: every term counts
