"""Constraint tightening ramped in along the horizon (``bounds.margin_ramp``): the bounds of
each predicted state against the true and the tightened limits, the NLP's variable bounds
stage by stage, the scenario key, and what it is for: a measured state a little past the
tightened bound (sensor noise) no longer forces the next state back inside at once.
"""

import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.experiment.scenario import load_scenarios
from aeromanip.nmpc.constraints import Bounds
from aeromanip.nmpc.controller import Controller
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.strategies import Weighted
from aeromanip.references import Constant
from aeromanip.robot.loader import load_robot
from aeromanip.tasks import ControlRate, EndEffectorTracking

X8 = load_robot("x8-3dof")
BOX = {"x": (-0.6, 0.6), "y": (-0.6, 0.6), "z": (0.8, 1.5)}
MARGINS = {"x": 0.01, "y": 0.01, "z": 0.01, "q2": 0.02}
TAU = np.array([0.28, 0.28, 0.2, 0.08, 0.0, 0.0, 0.0])  # s: the platform lags its commands


def limits() -> Bounds:
    return Bounds.from_robot(X8, platform_box=BOX)


@pytest.mark.parametrize("t", [0.0, 0.1, 0.15, 0.29])
@pytest.mark.parametrize("past", [-0.002, 0.0003, 0.004, 0.02])
def test_a_plan_may_brake_into_the_margin_as_far_as_the_vehicle_coasts(t, past):
    """By hand: the room left at ``t`` is ``(1 - t / 0.3)`` of the margin; a coasting
    state ``past`` [m] beyond a tightened bound moves that bound out by ``past``, within
    the room; the true limits bound everything."""
    true, ramp = limits(), 0.3
    b = true.tightened(MARGINS, ramp)
    coast = np.clip(np.zeros(7), b.x_lower, b.x_upper)  # inside: nothing to give...
    coast[0] = b.x_upper[0] + past  # ...but x, coasting `past` beyond its upper bound
    coast[2] = b.x_lower[2] - past  # and z beyond its lower one
    lo, hi = b.return_bounds(coast, t)
    room = (1.0 - t / ramp) * 0.01
    given = min(max(past, 0.0), room)
    assert hi[0] == pytest.approx(0.59 + given, abs=1e-15)
    assert lo[2] == pytest.approx(0.81 - given, abs=1e-15)
    assert hi[0] <= true.x_upper[0] and lo[2] >= true.x_lower[2]
    untouched = [i for i in range(7) if i not in (0, 2)]
    np.testing.assert_array_equal(hi[untouched], b.x_upper[untouched])
    np.testing.assert_array_equal(lo[untouched], b.x_lower[untouched])
    assert lo[0] == b.x_lower[0] and hi[2] == b.x_upper[2]  # the other sides stay


@pytest.mark.parametrize(("ramp", "t"), [(0.0, 0.0), (0.0, 0.1), (0.3, 0.3), (0.3, 2.0)])
def test_without_a_ramp_or_past_it_every_state_has_the_full_margin(ramp, t):
    b = limits().tightened(MARGINS, ramp)
    lo, hi = b.return_bounds(b.x_upper + 0.005, t)
    np.testing.assert_array_equal(lo, b.x_lower)
    np.testing.assert_array_equal(hi, b.x_upper)


def test_untightened_bounds_have_nothing_to_ramp():
    b = limits()
    assert b.margin is None
    np.testing.assert_array_equal(b.return_bounds(b.x_upper + 1.0, 0.0)[1], b.x_upper)
    ramped = Bounds(b.names, b.x_lower, b.x_upper, b.u_lower, b.u_upper, margin_ramp=0.3)
    lo, hi = ramped.return_bounds(b.x_upper + 1.0, 0.1)  # a ramp, but no margin to give
    np.testing.assert_array_equal(hi, b.x_upper)
    np.testing.assert_array_equal(lo, b.x_lower)


def test_the_ramp_survives_adding_command_rate_bounds():
    b = limits().tightened(MARGINS, 0.3).with_accel(np.full(7, 2.0))
    assert b.margin_ramp == 0.3
    np.testing.assert_array_equal(b.margin, limits().tightened(MARGINS).margin)


@pytest.mark.parametrize("bad", [-0.1, np.nan, np.inf])
def test_a_negative_or_non_finite_ramp_is_refused(bad):
    with pytest.raises(ConfigError, match=r"^bounds\.margin_ramp: must be >= 0 s"):
        limits().tightened(MARGINS, bad)


def problem(ramp: float) -> Problem:
    pb = Problem(X8, 10, 0.1, limits().tightened(MARGINS, ramp), response_tau=TAU)
    # the end effector wanted far beyond the box in x: the platform presses on its bound
    pb.add_task(EndEffectorTracking(Constant([1.5, 0.0, 0.6])), weight=10.0)
    pb.add_task(ControlRate(), weight=0.05)
    return pb


def test_the_nlp_bounds_follow_the_coasting_vehicle_into_the_margin():
    """Moving out at 0.05 m/s, 2 mm inside the tightened x bound, with a 0.28 s lag: the
    coasting position (the lag's exact decay: x0 + r0 tau (1 - exp(-t / tau))) bounds
    each state for 0.3 s, within the room left; later the tightened bound."""
    pb = problem(0.3)
    tr = Weighted(pb, "ipopt").transcription
    x0 = np.array([0.588, 0.0, 1.0, 0.0, 0.0, 0.4, -0.8])
    rates = np.array([0.05, 0, 0, 0, 0, 0, 0])
    p = tr.parameters(x0, rates, pb.stage_params(0.0), rates)
    lbw, ubw = tr.variable_bounds(p)
    for k in range(1, tr.N + 1):
        t = 0.1 * k
        coast = 0.588 + 0.05 * 0.28 * (1.0 - np.exp(-t / 0.28))
        room = max(1.0 - t / 0.3, 0.0) * 0.01
        expected = 0.59 + min(max(coast - 0.59, 0.0), room)
        assert ubw[tr.index_x[k]][0] == pytest.approx(expected, abs=1e-12), k
        np.testing.assert_array_equal(lbw[tr.index_x[k]], pb.bounds.x_lower)
    # stage 0 stays the measured state, pinned
    np.testing.assert_array_equal(lbw[tr.index_x[0]], x0)
    np.testing.assert_array_equal(ubw[tr.index_x[0]], x0)
    assert ubw[tr.index_x[1]][0] > 0.59 + 1e-4  # the margin is used at stage 1...
    assert ubw[tr.index_x[3]][0] == 0.59  # ...and not from 0.3 s on


def test_noise_past_the_tightened_bound_does_not_force_a_hard_command_back():
    """The platform at rest 0.3 mm past its tightened x bound (0.59 m), pulled outward by
    the task: without the ramp the next state must be back inside, which a platform that
    lags its command by 0.28 s reaches only with a hard inward command; with it the plan
    holds where it is, never further out, and is back inside by 0.3 s."""
    x0 = np.array([0.5903, 0.0, 1.0, 0.0, 0.0, 0.4, -0.8])
    first = {}
    for ramp in (0.0, 0.3):
        cmd = Controller(problem(ramp), "weighted", "ipopt").step(x0, 0.0, rates=np.zeros(7))
        assert cmd.status == "ok", cmd.message
        X = cmd.plan_x
        first[ramp] = cmd.u[0]
        assert X[:, 0].max() <= 0.5903 + 1e-8  # never further out than it is
        assert X[3:, 0].max() <= 0.59 + 1e-8  # inside the tightened bound from 0.3 s on
    assert first[0.0] < -0.01  # m/s: an inward command the lag turns into a jolt
    assert abs(first[0.3]) < 0.2 * abs(first[0.0])


def test_the_scenario_key_reaches_the_plan_and_bad_values_name_it():
    sc = load_scenarios("flight", ["bounds.margin_ramp=0.3"])[""]
    assert sc.problem.bounds.margin_ramp == 0.3
    assert load_scenarios("flight", [])[""].problem.bounds.margin_ramp == 0.0
    with pytest.raises(ConfigError, match=r"bounds\.margin_ramp"):
        load_scenarios("flight", ["bounds.margin_ramp=-1"])


def test_tightening_shrinks_each_named_state_and_refuses_what_it_cannot():
    """``Bounds.tightened``: each named state's box shrunk by its margin on both sides (a
    margin of half the width pins it), no ramp unless given; an unknown state, or a margin
    that crosses the bounds, is one line naming it."""
    b = Bounds.from_robot(load_robot("x8-3dof"), platform_box={"x": (-0.6, 0.6)})
    t = b.tightened({"x": 0.1, "q2": 1.6})  # q2 in [-1.6, 1.6]: pinned at 0
    i, j = b.names.index("x"), b.names.index("q2")
    assert (t.x_lower[i], t.x_upper[i]) == pytest.approx((-0.5, 0.5))
    assert t.x_lower[j] == pytest.approx(0.0) and t.x_upper[j] == pytest.approx(0.0)
    others = [k for k in range(len(b.names)) if k not in (i, j)]
    np.testing.assert_array_equal(t.x_lower[others], b.x_lower[others])
    assert t.margin_ramp == 0.0 and t.margin[i] == 0.1 and t.margin[j] == 1.6
    np.testing.assert_array_equal(t.return_bounds(t.x_upper + 1.0, 0.0)[1], t.x_upper)
    with pytest.raises(ConfigError, match=r"^bounds margin: unknown state 'z2'$"):
        b.tightened({"z2": 0.1})
    with pytest.raises(ConfigError, match=r"^bounds margin: 0\.7 closes the bounds of x$"):
        b.tightened({"x": 0.7})


def test_the_violation_is_how_far_a_state_lies_outside_its_box():
    b = Bounds.from_robot(load_robot("x8-3dof"), platform_box={"z": (0.8, 1.5)})
    x = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.6, -1.2])
    assert b.violation(x) == 0.0
    k = b.names.index("z")
    for z, out in ((0.75, 0.05), (1.6, 0.1)):
        x[k] = z
        assert b.violation(x) == pytest.approx(out)


def test_several_coasting_states_at_once_get_the_bounds_of_each_alone():
    """``return_bounds`` on a (k, nx) stack of coasting states with their times (k, 1),
    as ``variable_bounds`` asks, against one call per state; the last time is past the
    ramp (the full margin)."""
    b = limits().tightened(MARGINS, 0.3)
    rng = np.random.default_rng(3)
    finite = np.where(np.isfinite(b.x_upper), b.x_upper, 1.0)
    coast = finite + rng.uniform(-0.03, 0.03, size=(4, 7))
    times = np.array([[0.0], [0.1], [0.25], [0.4]])
    lo, hi = b.return_bounds(coast, times)
    for k in range(4):
        lo_k, hi_k = b.return_bounds(coast[k], float(times[k, 0]))
        np.testing.assert_array_equal(lo[k], lo_k)
        np.testing.assert_array_equal(hi[k], hi_k)
    np.testing.assert_array_equal(hi[3], b.x_upper)  # past the ramp: nothing to give
