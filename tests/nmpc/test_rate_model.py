"""The prediction model with rate responses, command-rate bounds, latency compensation and
time-scaled weights, each checked against a truth computed here: the ODE
integrated by RK4, IPOPT on the same NLP, the kinematic simulator, a Riemann sum.
"""

import re
import warnings

import casadi as ca
import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.experiment.closed_loop import simulate
from aeromanip.experiment.scenario import load_scenarios
from aeromanip.nmpc.constraints import Bounds
from aeromanip.nmpc.controller import Controller
from aeromanip.nmpc.model import MAX_TAU, RateModel
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.strategies import Weighted
from aeromanip.references import Constant, Lissajous
from aeromanip.robot.loader import load_robot
from aeromanip.sim.kinematic import KinematicSimulator
from aeromanip.tasks import ControlRate, EndEffectorTracking

X8 = load_robot("x8-3dof")
X0 = np.array([0.0, 0.0, 1.0, 0.0, 0.3, 0.4, -0.8])
TAU = np.array([0.3, 0.25, 0.2, 0.08, 0.0, 0.0, 0.01])  # s; two DoFs follow at once
ACCEL = np.array([0.5, 0.5, 0.5, 1.0, 2.0, 2.0, 2.0])  # m/s^2, rad/s^2


def rk4_truth(x, r, u, tau, h, substeps=4000):
    """``dx/dt = r``, ``dr/dt = (u - r) / tau`` (``r = u`` where ``tau = 0``), by RK4."""
    x, r, u = (np.array(a, dtype=float) for a in (x, r, u))
    lag = tau > 0
    r = np.where(lag, r, u)
    dt = h / substeps

    def f(xr):
        _xx, rr = xr[: len(x)], xr[len(x) :]
        dr = np.zeros_like(rr)
        dr[lag] = (u[lag] - rr[lag]) / tau[lag]
        return np.concatenate([np.where(lag, rr, u), dr])

    s = np.concatenate([x, r])
    for _ in range(substeps):
        k1 = f(s)
        k2 = f(s + 0.5 * dt * k1)
        k3 = f(s + 0.5 * dt * k2)
        k4 = f(s + dt * k3)
        s = s + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return s[: len(x)], np.where(lag, s[len(x) :], u)


def test_one_step_of_the_model_is_the_ode_held_over_the_period():
    rng = np.random.default_rng(1)
    model = RateModel(7, 0.1, TAU)
    lag = TAU > 0
    assert model.nz == 14 + lag.sum() and model.has_response  # rates of lagging DoFs only
    for _ in range(3):
        x, v, r, u = (rng.normal(size=7) for _ in range(4))
        z1 = model.A @ np.concatenate([x, v, r[lag]]) + model.B @ u
        x_true, r_true = rk4_truth(x, r, u, TAU, 0.1)
        np.testing.assert_allclose(z1[:7], x_true, atol=1e-10)
        np.testing.assert_allclose(z1[7:14], u, atol=0)  # v: the command just applied
        np.testing.assert_allclose(z1[14:], r_true[lag], atol=1e-10)
        np.testing.assert_allclose(model.rates_of(z1), r_true, atol=1e-10)
        # the symbolic step is the same map
        zs, us = ca.SX.sym("z", model.nz), ca.SX.sym("u", 7)
        step = ca.Function("step", [zs, us], [model.next_sx(zs, us)])
        np.testing.assert_allclose(
            np.asarray(step(np.concatenate([x, v, r[lag]]), u)).ravel(), z1, atol=1e-14
        )


def test_prediction_over_two_intervals_is_the_prediction_over_their_sum():
    model = RateModel(7, 0.1, TAU)
    z = np.random.default_rng(2).normal(size=model.nz)
    u = np.linspace(-1, 1, 7)
    twice = model.predict(model.predict(z, u, 0.013), u, 0.029)
    np.testing.assert_allclose(twice, model.predict(z, u, 0.042), atol=1e-14)


def test_without_time_constants_it_is_the_papers_model():
    model = RateModel(7, 0.5)
    assert model.nz == 14 and not model.has_response
    z = np.concatenate([X0, np.zeros(7)])
    u = np.arange(7.0)
    np.testing.assert_allclose(model.A @ z + model.B @ u, np.concatenate([X0 + 0.5 * u, u]))


@pytest.mark.parametrize(
    "tau",
    [[-0.1] + [0.0] * 6, [np.nan] + [0.0] * 6, [0.1] * 6, [MAX_TAU * 1.001] + [0.0] * 6],
)
def test_bad_time_constants_are_refused(tau):
    with pytest.raises(ConfigError, match=r"^response\.tau: "):
        RateModel(7, 0.1, np.array(tau))


def test_time_constants_at_either_end_of_the_range_are_taken():
    """0 (the command followed at once) and ``MAX_TAU`` itself are allowed."""
    model = RateModel(7, 0.1, np.array([0.0, MAX_TAU] + [0.0] * 5))
    assert model.lagged.tolist() == [1]


def problem(tau=TAU, accel=ACCEL, horizon=8, dt=0.1, weights_dt=None, target=(0.4, 0.3, 0.5)):
    bounds = Bounds.from_robot(X8).with_accel(accel)
    pb = Problem(X8, horizon, dt, bounds, response_tau=tau, weights_dt=weights_dt)
    pb.add_task(EndEffectorTracking(Constant(list(target))), weight=10.0, level=0)
    pb.add_task(ControlRate(), weight=0.05, terminal_weight=0.5, level=None)
    return pb


def test_the_nlps_gap_rows_close_exactly_on_a_model_rollout_and_measure_the_ode_error():
    pb = problem()
    w = Weighted(pb, "ipopt")
    tr = w.transcription
    rng = np.random.default_rng(3)
    U = rng.normal(scale=0.2, size=(pb.horizon, 7))
    u_prev, rates = rng.normal(size=7), rng.normal(size=7)
    Z = pb.model.rollout(pb.model.initial(X0, u_prev, rates), U)
    wv = tr.pack(Z[:, :7], U, u_prev, rates)
    p = tr.parameters(X0, u_prev, pb.stage_params(0.0), rates)
    g = np.asarray(ca.Function("g", [tr.w, tr.p], [tr.g])(wv, p)).ravel()
    assert np.abs(g[tr.gap_rows]).max() < 1e-12
    # the gaps of an RK4 trajectory are RK4's error: tiny
    x_true, _r_true = rk4_truth(X0, rates, U[0], TAU, pb.dt)
    wv2 = wv.copy()
    wv2[tr.index_x[1]] = x_true
    g2 = np.asarray(ca.Function("g", [tr.w, tr.p], [tr.g])(wv2, p)).ravel()
    assert np.abs(g2[tr.gap_rows]).max() < 1e-10


@pytest.mark.parametrize(
    "backend, options",
    [("sqp", {"qpsol": "daqp"}), ("sqp", {"qpsol": "hpipm"}), ("fatrop", {})],
)
def test_every_backend_finds_ipopts_optimum_with_responses_and_command_rate_bounds(
    backend, options
):
    pb = problem()
    ref = Controller(pb, "weighted", "ipopt")
    ctrl = Controller(pb, "weighted", backend, options)
    rates = np.array([0.2, -0.1, 0.05, 0.0, 0.1, 0.0, -0.2])
    a, b = ref.step(X0, 0.0, rates), ctrl.step(X0, 0.0, rates)
    assert a.status == b.status == "ok"
    np.testing.assert_allclose(b.plan_u, a.plan_u, atol=2e-4)
    np.testing.assert_allclose(b.plan_x, a.plan_x, atol=2e-5)
    # the bounds bind (a far target, from rest): |u[k] - u[k-1]| <= a dt, u[-1] = 0
    steps = np.abs(np.diff(np.vstack([np.zeros(7), a.plan_u]), axis=0))
    assert np.all(steps <= ACCEL * pb.dt + 1e-6)
    assert np.any(steps >= ACCEL * pb.dt - 1e-6)


def test_command_rate_bounds_hold_at_every_step_of_a_closed_loop():
    sc = load_scenarios(
        "waypoints",
        [
            "duration=6",
            "controller.dt=0.1",
            "controller.horizon=20",
            "controller.backend='sqp'",
            "bounds.acceleration={x=0.01, y=0.01, z=0.01, yaw=0.02, default=0.02}",
        ],
        only="tracking-only",
    )["tracking-only"]
    log = simulate(sc)
    cmds = np.column_stack([log.column(f"u_{n}") for n in sc.robot.state_names])
    steps = np.abs(np.diff(np.vstack([np.zeros(cmds.shape[1]), cmds]), axis=0))
    limit = np.array([0.01, 0.01, 0.01, 0.02, 0.02, 0.02, 0.02]) * 0.1
    assert set(log.column("status")) == {"ok"}
    assert np.all(steps <= limit + 1e-6), np.max(steps - limit)
    assert np.mean(np.any(steps >= limit - 1e-6, axis=1)) > 0.05  # they bind


def test_a_compensated_latency_plans_from_the_state_reached_when_the_command_lands():
    pb = problem(tau=None, accel=None, horizon=6)
    lag = 0.03
    ctrl = Controller(pb, "weighted", "ipopt", latency_s=lag)
    sim = KinematicSimulator(X8)
    sim.reset(X0)
    held = np.zeros(7)
    for k in range(4):
        cmd = ctrl.step(sim.state(), 0.1 * k)
        sim.advance(held, X0, lag)  # the previous command flies until the new one lands
        np.testing.assert_allclose(cmd.plan_x[0], sim.state(), atol=1e-12)
        sim.advance(cmd.u, cmd.plan_x, 0.1 - lag)
        held = cmd.u


def test_the_plan_starts_from_the_measured_rates_and_samples_the_reference_when_it_lands():
    """What a step hands the solver: the stage-0 state with the measured (lagged) rates,
    and the reference at ``t + latency + k dt`` (a moving one: a Lissajous figure)."""
    ref = Lissajous([0.4, 0.3, 0.5], [0.1, 0.2, 0.05], [0.5, 0.3, 0.2])
    pb = Problem(X8, 6, 0.1, Bounds.from_robot(X8), response_tau=TAU)
    pb.add_task(EndEffectorTracking(ref), weight=10.0)
    ctrl = Controller(pb, "weighted", "ipopt", latency_s=0.0)
    given = []
    solve = ctrl.strategy.solve
    ctrl.strategy.solve = lambda p, gs: given.append(p) or solve(p, gs)
    rates = np.array([0.1, -0.2, 0.05, 0.3, 0.2, -0.1, 0.4])
    ctrl.step(X0, 1.7, rates)
    nx, lagged = 7, TAU > 0
    np.testing.assert_array_equal(given[0][2 * nx : 2 * nx + lagged.sum()], rates[lagged])
    late = Controller(pb, "weighted", "ipopt", latency_s=0.04)
    late.strategy.solve = lambda p, gs: given.append(p) or solve(p, gs)
    late.step(X0, 1.7)
    nz = 2 * nx + lagged.sum()
    times = 1.74 + 0.1 * np.arange(7)
    np.testing.assert_allclose(given[1][nz:].reshape(7, 3), ref.sample(times), rtol=1e-14)


def test_latency_must_be_shorter_than_the_period():
    with pytest.raises(Exception, match="latency"):
        Controller(problem(), "weighted", "ipopt", latency_s=0.1)


def stage_cost_totals(dt, weights_dt):
    """Tracking and control-rate stage costs of one smooth motion sampled every ``dt``."""
    horizon = round(2.0 / dt)
    pb = problem(tau=None, accel=None, horizon=horizon, dt=dt, weights_dt=weights_dt)
    tr = Weighted(pb, "ipopt").transcription
    t = dt * np.arange(horizon + 1)
    X = np.repeat(X0[None], horizon + 1, axis=0)
    X[:, 0] += 0.3 * np.sin(1.3 * t)  # the platform sways along x
    U = np.diff(X, axis=0) / dt
    p = tr.parameters(X0, U[0], pb.stage_params(0.0))
    C = tr.costs(tr.pack(X, U, U[0]), p)  # tasks x stages (terminal last)
    return C[0, :-1].sum(), C[1, :-1].sum()


def test_time_scaled_weights_keep_the_cost_a_time_integral_whatever_the_period():
    coarse, fine = stage_cost_totals(0.1, 0.5), stage_cost_totals(0.025, 0.5)
    np.testing.assert_allclose(fine, coarse, rtol=0.1)  # Riemann sums of one integral
    raw_coarse, raw_fine = stage_cost_totals(0.1, None), stage_cost_totals(0.025, None)
    assert raw_fine[0] / raw_coarse[0] > 3.5  # per-step weights: 4x the stages
    assert raw_fine[1] / raw_coarse[1] < 0.3  # and 1/4 of each step's change, squared x4


def test_weights_tuned_at_the_period_flown_are_taken_as_they_are():
    np.testing.assert_allclose(stage_cost_totals(0.1, 0.1), stage_cost_totals(0.1, None))


def boxed_problem(horizon=20):
    """``problem()`` with the platform in a box ``|x|, |y| <= 0.5`` m, ``z`` in [0.5, 1.5]."""
    b = Bounds.from_robot(X8)
    lo, hi = b.x_lower.copy(), b.x_upper.copy()
    lo[:3], hi[:3] = [-0.5, -0.5, 0.5], [0.5, 0.5, 1.5]
    bounds = Bounds(b.names, lo, hi, b.u_lower, b.u_upper, ACCEL)
    pb = Problem(X8, horizon, 0.1, bounds, response_tau=TAU)
    pb.add_task(EndEffectorTracking(Constant([0.3, 0.0, 0.5])), weight=10.0, level=0)
    pb.add_task(ControlRate(), weight=0.05, terminal_weight=0.5, level=None)
    return pb


@pytest.mark.parametrize(
    "backend, options",
    [("sqp", {"qpsol": "daqp"}), ("sqp", {"qpsol": "hpipm"}), ("ipopt", {})],
)
def test_a_state_carried_out_of_its_box_by_its_rates_is_brought_back_not_given_up(backend, options):
    pb = boxed_problem(horizon=30)
    x0 = X0.copy()
    x0[0] = 0.501  # 1 mm beyond the box, still moving out: rate lag and command-rate bound
    x0[1] = -0.501  # and y on the other side
    u_prev = np.array([0.2, -0.2, 0, 0, 0, 0, 0.0])
    # hand computation: the least x reachable at the next stage, the command cut as far
    # as allowed (u = 0.3 - 0.5 * 0.1), lies outside the box: no plan keeps the hard box
    a = np.exp(-0.1 / 0.3)
    u = 0.2 - ACCEL[0] * 0.1
    assert x0[0] + 0.1 * u + 0.3 * (1 - a) * (0.2 - u) > 0.5
    ctrl = Controller(pb, "weighted", backend, options)
    ctrl.u_prev = u_prev  # the last command, flown at its actual rate
    cmd = ctrl.step(x0, 0.0, u_prev)
    assert cmd.status == "ok", cmd.message
    assert re.search(r"\(state box widened: x \+[-0-9.e]+, y \+[-0-9.e]+\)$", cmd.message)
    X = cmd.plan_x
    assert X[1, 0] > 0.5  # it has to go out further ...
    assert X[-1, 0] <= 0.5 + 1e-6  # ... and is planned back into its box by the end
    steps = np.abs(np.diff(np.vstack([u_prev, cmd.plan_u]), axis=0))
    assert np.all(steps <= ACCEL * pb.dt + 1e-6)


def test_the_box_is_left_as_it_is_wherever_a_plan_can_keep_it():
    pb = boxed_problem()
    tr = Weighted(pb, "ipopt").transcription
    p = tr.parameters(X0, np.zeros(7), pb.stage_params(0.0), np.zeros(7))
    lbw, ubw = tr.variable_bounds(p)
    idx = tr.index_x[1:]
    np.testing.assert_array_equal(lbw[idx], tr.lbw[idx])
    np.testing.assert_array_equal(ubw[idx], tr.ubw[idx])
    assert not np.any(tr.box_widening(p))
    # moving out fast near the wall: widened by no less than the least overshoot any plan
    # has (full deceleration down to the rate bound) and no more than a plain stop's
    x0, v = X0.copy(), np.array([0.0, -0.8, 0, 0, 0, 0, 0])
    x0[1] = -0.45
    p = tr.parameters(x0, v, pb.stage_params(0.0), v)
    cut = ACCEL[1] * pb.dt * np.arange(1, pb.horizon + 1)

    def lowest_y(commands):
        U = np.zeros((pb.horizon, 7))
        U[:, 1] = commands
        return pb.model.rollout(pb.model.initial(x0, v, v), U)[1:, 1].min()

    least = -0.5 - lowest_y(np.minimum(-0.8 + cut, pb.bounds.u_upper[1]))
    stop = -0.5 - lowest_y(np.minimum(-0.8 + cut, 0.0))
    wide = tr.box_widening(p)
    assert 0 < least <= wide[1] <= stop
    assert not np.any(np.delete(wide, 1))


def test_reach_bounds_the_braking_travel_so_skipping_the_recovery_loses_nothing():
    """``RateModel.reach`` against the rollout of the hardest braking the bounds allow,
    from random states; where it says a box cannot be left, the recovery plan agrees."""
    rng = np.random.default_rng(11)
    model = RateModel(7, 0.1, TAU)
    pb = boxed_problem()
    tr = Weighted(pb, "ipopt").transcription
    b = pb.bounds
    held = 0
    for k in range(200):
        speed = 0.5 if k % 2 else 0.05  # half of them slow: their box cannot be left
        v, r = rng.normal(scale=speed, size=7), rng.normal(scale=speed, size=7)
        z0 = model.initial(X0 + rng.normal(scale=0.2, size=7), v, r)
        cut = ACCEL * 0.1
        U = np.sign(v) * np.maximum(np.abs(v) - cut * np.arange(1, 61)[:, None], 0.0)
        travel = np.abs(model.rollout(z0, U)[1:, :7] - z0[:7]).max(axis=0)
        assert np.all(travel <= model.reach(z0, cut) + 1e-12)
        brake = pb.model.recovery(z0, pb.horizon, cut, (b.x_lower, b.x_upper),
                                  (b.u_lower, b.u_upper))  # fmt: skip
        inside = (z0[:7] - model.reach(z0, cut) >= b.x_lower) & (
            z0[:7] + model.reach(z0, cut) <= b.x_upper
        )
        if np.all(inside):
            held += 1
            assert np.all((brake >= b.x_lower - 1e-12) & (brake <= b.x_upper + 1e-12))
    assert held > 50
    assert tr.box_widening(tr.parameters(X0, np.zeros(7), pb.stage_params(0.0))).max() == 0.0


def test_a_discarded_step_leaves_the_previous_plan_flying():
    """``Controller.discard`` (a solve too late to fly): the command in flight is the
    previous plan's next one, whatever the discarded step computed."""
    pb = problem(tau=None, accel=None, horizon=6)
    ctrl = Controller(pb, "weighted", "ipopt")
    first = ctrl.step(X0, 0.0)
    late = ctrl.step(X0 + pb.dt * first.u + 0.05, pb.dt)
    assert not np.allclose(late.u, first.plan_u[1])
    ctrl.discard()
    np.testing.assert_array_equal(ctrl.u_prev, first.plan_u[1])
    ctrl.discard()  # nothing more to forget
    np.testing.assert_array_equal(ctrl.u_prev, first.plan_u[1])


def test_discarded_steps_age_the_flying_plan_until_it_runs_out():
    """Each discarded step leaves the plan of the last flown step one step older: its
    commands are taken in turn as the one in flight, and a failed solve falls back on the
    next of them; past the plan's last command, the last one stays in flight and there is
    no plan to fall back on (``stopped``)."""
    pb = problem(tau=None, accel=None, horizon=3)
    ctrl = Controller(pb, "weighted", "ipopt")
    first = ctrl.step(X0, 0.0)
    for k in (1, 2):  # the solve of step k comes too late: plan command k flies
        ctrl.step(X0 + 0.01 * k, k * pb.dt)
        ctrl.discard()
        np.testing.assert_array_equal(ctrl.u_prev, first.plan_u[k])
    ctrl.step(X0 + 0.03, 3 * pb.dt)
    ctrl.discard()  # the plan had no fourth command: the third stays in flight
    np.testing.assert_array_equal(ctrl.u_prev, first.plan_u[2])
    X, U = ctrl.strategy.transcription.unpack(ctrl.initial_guesses(X0)[0])
    np.testing.assert_array_equal(X, np.repeat(X0[None], 4, axis=0))  # no plan: rest
    np.testing.assert_array_equal(U, np.zeros((3, 7)))
    ctrl.time_budget_s = 1e-12  # every solve now fails
    assert ctrl.step(X0, 4 * pb.dt).status == "stopped"


def test_after_a_discard_a_failed_solve_falls_back_on_the_plans_next_command():
    pb = problem(tau=None, accel=None, horizon=4)
    ctrl = Controller(pb, "weighted", "ipopt")
    first = ctrl.step(X0, 0.0)
    ctrl.step(X0 + 0.01, pb.dt)
    ctrl.discard()  # plan command 1 flies
    ctrl.time_budget_s = 1e-12
    late = ctrl.step(X0, 2 * pb.dt)
    assert late.status == "fallback"
    np.testing.assert_array_equal(late.u, first.plan_u[2])


@pytest.mark.parametrize("lost", ["failed", "discarded"])
def test_after_a_lost_step_the_next_guess_is_the_flying_plan_from_the_stage_it_reached(lost):
    """Step 1 fails (the plan's command 1 flies as the fallback) or comes too late
    (discarded: the same): step 2's guess is step 0's plan from its stage 2 on, the last
    command repeated, starting from the measured state."""
    pb = problem(tau=None, accel=None, horizon=5)
    ctrl = Controller(pb, "weighted", "ipopt")
    first = ctrl.step(X0, 0.0)
    if lost == "failed":
        ctrl.time_budget_s = 1e-12
        assert ctrl.step(X0, pb.dt).status == "fallback"
        ctrl.time_budget_s = None
    else:
        ctrl.step(X0, pb.dt)
        ctrl.discard()
    x2 = X0 + 0.01
    X, U = ctrl.strategy.transcription.unpack(ctrl.initial_guesses(x2)[0])
    P, Q = first.plan_x, first.plan_u
    np.testing.assert_array_equal(X, np.vstack([x2, P[3:], P[-1:], P[-1:]]))
    np.testing.assert_array_equal(U, np.vstack([Q[2:], Q[-1:], Q[-1:]]))


def test_discarding_the_first_step_leaves_nothing_flying():
    pb = problem(tau=None, accel=None, horizon=3)
    ctrl = Controller(pb, "weighted", "ipopt")
    ctrl.discard()  # before any step: nothing to forget
    ctrl.step(X0, 0.0)
    ctrl.discard()  # the first solve came too late: no plan was ever flown
    np.testing.assert_array_equal(ctrl.u_prev, np.zeros(7))
    ctrl.time_budget_s = 1e-12
    assert ctrl.step(X0, pb.dt).status == "stopped"


def test_widening_is_reported_on_a_dof_bounded_on_one_side():
    b = Bounds.from_robot(X8)
    hi = b.x_upper.copy()
    hi[0] = 0.5  # x <= 0.5 only
    pb = Problem(X8, 20, 0.1, Bounds(b.names, b.x_lower, hi, b.u_lower, b.u_upper, ACCEL), TAU)
    pb.add_task(EndEffectorTracking(Constant([0.3, 0.0, 0.5])), weight=10.0, level=0)
    tr = Weighted(pb, "ipopt").transcription
    x0, v = X0.copy(), np.array([0.2, 0, 0, 0, 0, 0, 0.0])
    x0[0] = 0.501
    wide = tr.box_widening(tr.parameters(x0, v, pb.stage_params(0.0), v))
    assert wide[0] > 0.001 and not np.any(wide[1:])


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_a_state_coming_back_into_its_box_is_widened_at_the_first_stage_alone(side):
    """x 2 cm beyond ``|x| <= 0.5``, already moving back at 0.1 m/s: the nearest the next
    stage can be (hand computation: the command cut by ``accel dt`` to -0.15, the rate
    lagging with ``tau = 0.3``) is still out by 9.25 mm; from stage 2 on the box holds."""
    pb = boxed_problem()
    tr = Weighted(pb, "ipopt").transcription
    x0, v = X0.copy(), side * np.array([-0.1, 0, 0, 0, 0, 0, 0.0])
    x0[0] = 0.52 * side
    a, u = np.exp(-0.1 / 0.3), -0.1 - ACCEL[0] * 0.1
    x1 = 0.52 + 0.1 * u + 0.3 * (1 - a) * (-0.1 - u)
    p = tr.parameters(x0, v, pb.stage_params(0.0), v)
    with warnings.catch_warnings():  # inf - inf on the unbounded sides: no warning
        warnings.simplefilter("error")
        assert tr.box_widening(p)[0] == pytest.approx(x1 - 0.5, rel=1e-9)
    lbw, ubw = tr.variable_bounds(p)
    assert np.all((ubw if side > 0 else -lbw)[tr.index_x[2:, 0]] == 0.5)


def test_a_failed_step_names_each_state_outside_its_bounds_and_only_those():
    """The fallback's message lists the state entries beyond their hard bounds (a solve
    cannot help those); one exactly at a bound is inside."""
    bounds = Bounds.from_robot(X8, platform_box={"z": (0.8, 1.5)})
    pb = Problem(X8, 3, 0.5, bounds)
    pb.add_task(EndEffectorTracking(Constant([0.4, 0.3, 0.5])), weight=10.0)
    ctrl = Controller(pb, "weighted", "ipopt", time_budget_s=1e-12)  # every solve fails
    x0 = np.array([0.0, 0.0, 0.7, 0.0, -1.57, 1.6, 2.3])  # q1, q2 at a limit; z, q3 past
    cmd = ctrl.step(x0, 0.0)
    assert cmd.status == "stopped"
    assert cmd.message.endswith(" (state z = 0.7 outside [0.8, 1.5]; q3 = 2.3 outside [-2.2, 2.2])")


def brute_force_recovery(model, z0, steps, max_change, box, limits, grid=200001):
    """``RateModel.recovery`` by search: at each step, per DoF, the commands on a fine grid
    within the rate bounds and ``max_change`` of the last one, each next state from
    ``model.predict``; of those that land in the box the one nearest zero, else the one
    that lands nearest the box."""
    nx, (lo, hi), (u_lo, u_hi) = model.nx, box, limits
    z, out = np.array(z0, float), np.empty((steps, nx))
    for k in range(steps):
        free = model.predict(z, np.zeros(nx), model.dt)[:nx]
        gain = model.predict(z, np.ones(nx), model.dt)[:nx] - free
        last, u = z[nx : 2 * nx], np.empty(nx)
        for i in range(nx):
            lo_u, hi_u = (
                max(last[i] - max_change[i], u_lo[i]),
                min(last[i] + max_change[i], u_hi[i]),
            )
            cand = np.linspace(lo_u, hi_u, grid)
            x = free[i] + gain[i] * cand
            inside = (x >= lo[i]) & (x <= hi[i])
            if inside.any():
                u[i] = cand[inside][np.argmin(np.abs(cand[inside]))]
            else:
                u[i] = cand[np.argmin(np.maximum(lo[i] - x, x - hi[i]))]
        z = model.predict(z, u, model.dt)
        out[k] = z[:nx]
    return out


@pytest.mark.parametrize(
    ("x", "r"),
    [
        ([0.0, 0.1, -0.2], [0.0, 0.0, 0.0]),  # inside, at rest: no command
        ([-0.45, 0.4, 0.3], [-0.6, 0.5, 0.7]),  # heading out: braked at the bound
        ([-0.7, -0.65, -0.8], [-0.3, -0.2, -0.4]),  # below, falling: pushed back up
        ([0.9, 0.6, 0.7], [0.9, 0.8, 0.3]),  # above, rising fast: too far to return at once
    ],
)
def test_the_recovery_plan_is_the_nearest_to_zero_command_that_keeps_the_box(x, r):
    model = RateModel(3, 0.1, np.array([0.2, 0.0, 0.3]))
    z0 = model.initial(np.array(x), np.array(r), np.array(r))
    box, limits = (np.full(3, -0.5), np.full(3, 0.5)), (np.full(3, -1.0), np.full(3, 1.0))
    cut = np.full(3, 0.15)
    plan = model.recovery(z0, 12, cut, box, limits)
    np.testing.assert_allclose(plan, brute_force_recovery(model, z0, 12, cut, box, limits),
                               atol=1e-6)  # fmt: skip


@pytest.mark.parametrize("steps", [0, 1, 8, 9, 50])
def test_a_rollout_is_the_matrix_recursion_loop_or_filter(steps):
    """``rollout`` (a loop up to ``SHORT_ROLLOUT`` steps, a per-DoF filter beyond) against
    ``z[k+1] = A z[k] + B u[k]`` step by step with ``matrices``' A, B; a DoF that follows
    at once and lagged ones alike."""
    model = RateModel(7, 0.1, TAU)
    rng = np.random.default_rng(steps)
    z = model.initial(X0, rng.normal(size=7), rng.normal(size=7))
    U = rng.normal(size=(steps, 7))
    A, B = model.matrices(0.1)
    want = [z]
    for u in U:
        want.append(A @ want[-1] + B @ u)
    np.testing.assert_allclose(model.rollout(z, U), np.array(want), rtol=0, atol=1e-12)
