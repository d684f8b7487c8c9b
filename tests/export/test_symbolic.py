"""The exported step's generated twins against the Python controller's NumPy code: the
solve's parameters and row bounds (``Transcription.variable_bounds``: margins, braking,
a recovery plan's widening), the plan's rollout and the end effector."""

from __future__ import annotations

import numpy as np
import pytest

from aeromanip.experiment.closed_loop import make_controller
from aeromanip.experiment.scenario import load_scenarios
from aeromanip.nmpc.backends.sqp.step_functions import (
    bounds_function,
    ee_function,
    parameters_function,
    plan_function,
)

# short horizons (the condensed model), with and without rate lags and latency
CASES = {  # scenario, overrides, variant
    "flight": ("flight", ["controller.strategy=weighted"], None),
    "flight, latency": ("flight", ["controller.strategy=weighted", "controller.latency=0.2"], None),
    # rate lags, command-rate bounds and a margin ramp
    "waypoints-rates": ("waypoints-rates", ["controller.strategy=weighted", "controller.horizon=10",
                                            "controller.backend=sqp",
                                            "controller.solver_options.qpsol=daqp"], "10hz"),
}  # fmt: skip


def _controller(case):
    name, sets, variant = CASES[case]
    sc = next(iter(load_scenarios(name, sets, variant).values()))
    assert variant is None or sc.problem.model.has_response
    return sc, make_controller(sc)


def _numpy_twin(sc, ctrl, x, u_prev, rates, t):
    """What ``Controller.step`` and ``CondensedQpModel.start`` compute."""
    st = ctrl.strategy.solvers[0]
    tr, model = st.tr, st.backend.model
    ctrl.reset(u_prev)
    x0 = ctrl._start(x, rates)
    p = tr.parameters(x0, u_prev, sc.problem.stage_params(t + ctrl.latency_s), ctrl._rates)
    lbw, ubw = tr.variable_bounds(p)
    lbc = np.concatenate([tr.lbg[model.keep], lbw[model.state_idx]])
    ubc = np.concatenate([tr.ubg[model.keep], ubw[model.state_idx]])
    return p, lbc, ubc, tr.box_widening(p).any()


def _states(sc, rng, n):
    """Inside the box, beside its faces (within the braking distance) and outside it."""
    b = sc.problem.bounds
    lo, hi = (
        np.where(np.isfinite(b.x_lower), b.x_lower, -1.0),
        np.where(np.isfinite(b.x_upper), b.x_upper, 1.0),
    )
    for _ in range(n):
        share = rng.uniform(-0.3, 1.3, lo.size)  # some beyond a face
        yield lo + share * (hi - lo), rng.uniform(-1, 1, lo.size) * np.minimum(b.u_upper, 1.0)


@pytest.mark.parametrize("case", list(CASES))
def test_the_parameters_and_row_bounds_equal_the_python_controllers(case):
    sc, ctrl = _controller(case)
    st = ctrl.strategy.solvers[0]
    params = parameters_function(st.tr, ctrl.latency_s, "parameters")
    bounds = bounds_function(st.backend.model, st.tr.lbg, st.tr.ubg, "bounds")
    rng = np.random.default_rng(7)
    widened = 0
    for x, u_prev in _states(sc, rng, 120):
        t = rng.uniform(-1.0, sc.duration + 5)
        rates = u_prev + rng.normal(0.0, 0.2, u_prev.size)  # measured: not the command
        p, lbc, ubc, wide = _numpy_twin(sc, ctrl, x, u_prev, rates, t)
        widened += wide
        got_p = np.array(params(x, u_prev, rates, t)).ravel()
        np.testing.assert_allclose(got_p, p, rtol=0, atol=1e-12)
        for have, want in zip(bounds(got_p), (lbc, ubc), strict=True):
            have = np.array(have).ravel()
            assert np.array_equal(np.isinf(have), np.isinf(want))
            fin = np.isfinite(want)
            np.testing.assert_allclose(have[fin], want[fin], rtol=0, atol=1e-12)
    assert 10 < widened < 110  # both branches: the box as it is, and widened


@pytest.mark.parametrize("case", ["flight", "waypoints-rates"])
def test_the_plan_and_the_end_effector_equal_the_python_controllers(case):
    sc, ctrl = _controller(case)
    tr = ctrl.strategy.solvers[0].tr
    plan, ee = plan_function(tr, "plan"), ee_function(tr, "ee")
    rng = np.random.default_rng(3)
    for x, u_prev in _states(sc, rng, 5):
        z0 = tr.model.initial(x, u_prev)
        p = np.concatenate([z0, np.zeros(tr.p.numel() - z0.size)])
        U = rng.uniform(-0.3, 0.3, (tr.N, tr.nx))
        X = np.array(plan(p, U.ravel())).reshape(tr.N + 1, tr.nx)
        np.testing.assert_allclose(X, tr.model.rollout(z0, U)[:, : tr.nx], rtol=0, atol=1e-13)
        np.testing.assert_allclose(np.array(ee(x)).ravel(), sc.problem.ee_of(x), atol=1e-14)
