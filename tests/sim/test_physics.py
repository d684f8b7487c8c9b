"""Physics simulator: hover, steps, agreement with the kinematic loop, arm torque, noise."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from aeromanip.errors import ConfigError, StateError
from aeromanip.robot.kinematics import Kinematics
from aeromanip.robot.loader import load_robot
from aeromanip.sim.flight_controller import (
    FlightController,
    Mixer,
    rotor_layout,
)
from aeromanip.sim.kinematic import KinematicSimulator
from aeromanip.sim.physics import PhysicsSimulator

G = 9.81


def _hold(sim, x_ref, seconds, dt=0.1):
    """Advance with u = 0 and a constant plan; yield after every period."""
    u = np.zeros(sim.spec.nx)
    plan = np.tile(x_ref, (11, 1))
    for _ in range(round(seconds / dt)):
        sim.advance(u, plan, dt)
        yield


def _static_moment(spec, x):
    """|xy| of the arm weight's moment about the base origin, level base [N m]."""
    cog = Kinematics(spec).cog_body(x).full().ravel()
    return spec.arm_mass * G * math.hypot(cog[0], cog[1])


# --- flight controller (pure NumPy) ------------------------------------------------------


def test_mixer_allocates_exactly_and_prioritises_roll_pitch():
    pos, spins = rotor_layout(4, 0.25)
    mixer = Mixer(pos, spins, 0.016, f_max=10.0)
    f = mixer.mix(20.0, np.array([0.3, -0.2, 0.05]))
    np.testing.assert_allclose(mixer.A @ f, [20.0, 0.3, -0.2, 0.05], atol=1e-12)
    # an impossible yaw demand is cut, roll/pitch and collective thrust are kept
    f = mixer.mix(20.0, np.array([0.3, -0.2, 5.0]))
    wrench = mixer.A @ f
    assert np.all(f >= 0) and np.all(f <= 10.0)
    np.testing.assert_allclose(wrench[:3], [20.0, 0.3, -0.2], atol=1e-12)
    assert 0 < wrench[3] < 5.0
    # near full thrust, roll/pitch are kept and the collective thrust gives way
    f = mixer.mix(39.0, np.array([0.5, 0.0, 0.0]))
    np.testing.assert_allclose((mixer.A @ f)[1:3], [0.5, 0.0], atol=1e-12)
    assert (mixer.A @ f)[0] < 39.0 and f.max() == pytest.approx(10.0)


def test_flight_controller_hover_output_and_tilt_limit():
    pos, spins = rotor_layout(4, 0.25)
    mixer = Mixer(pos, spins, 0.016, f_max=2 * 2.0 * G / 4)
    fc = FlightController(2.0, (0.03, 0.03, 0.05), mixer, 0.002)
    z = np.zeros(3)
    f = fc.update(z, z.copy(), np.eye(3), z.copy(), z.copy(), z.copy(), 0.0)
    np.testing.assert_allclose(f, 2.0 * G / 4)
    fc.reset()
    fc.update(z, z.copy(), np.eye(3), z.copy(), np.array([50.0, 0, 0]), z.copy(), 0.0)
    tilt = math.acos(fc.R_sp[2, 2])
    assert tilt == pytest.approx(math.radians(35.0), abs=1e-9)
    assert fc.R_sp[0, 2] > 0  # leans towards +x to accelerate there


# --- physics simulator -------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "x0"),
    [
        ("planar-2dof", [0.0, 1.0, 0.0, 0.0]),
        ("x8-3dof", [0.3, -0.2, 1.0, 0.4, 0.0, 0.0, 0.0]),
        ("x8-3dof", [0.0, 0.0, 1.5, 0.0, 0.7, 1.0, -1.2]),  # bent: CoG 0.08 m off axis
    ],
)
def test_hover_from_reset_is_steady(name, x0):
    spec = load_robot(name)
    sim = PhysicsSimulator(spec)
    x0 = np.array(x0)
    sim.reset(x0)
    p0 = sim.data.qpos[:3].copy()
    drift, tilt, joints = 0.0, 0.0, 0.0
    for _ in _hold(sim, x0, 5.0):
        drift = max(drift, float(np.linalg.norm(sim.data.qpos[:3] - p0)))
        e = sim.extras()
        tilt = max(tilt, abs(e["roll"]), abs(e["pitch"]))
        joints = max(
            joints, float(np.abs(sim.state()[spec.n_platform :] - x0[spec.n_platform :]).max())
        )
    msg = f"drift {drift:.2e} m, tilt {math.degrees(tilt):.2e} deg, joints {joints:.2e} rad"
    assert drift < 0.01 and math.degrees(tilt) < 0.5 and joints < 1e-3, msg
    e = sim.extras()
    assert e["thrust_total"] == pytest.approx(sim.mass * G, rel=1e-6)
    assert sum(e[f"motor_{i + 1}"] for i in range(sim.rotors)) == pytest.approx(e["thrust_total"])


def test_hover_with_bent_arm_and_zeroed_integrators_recovers():
    """Without the reset trim the rate integrator must learn the arm's CoG moment."""
    spec = load_robot("x8-3dof")
    sim = PhysicsSimulator(spec)
    x0 = np.array([0.0, 0.0, 1.0, 0.0, 0.7, 1.0, -1.2])
    sim.reset(x0)
    sim.controller.reset()  # no torque trim
    drift, tilt = 0.0, 0.0
    for _ in _hold(sim, x0, 5.0):
        drift = max(drift, float(np.linalg.norm(sim.data.qpos[:3] - x0[:3])))
        tilt = max(tilt, abs(sim.extras()["roll"]), abs(sim.extras()["pitch"]))
    final = float(np.linalg.norm(sim.data.qpos[:3] - x0[:3]))
    msg = f"max drift {drift:.4f} m, final {final:.4f} m, tilt {math.degrees(tilt):.2f} deg"
    assert drift < 0.03 and final < 0.005 and math.degrees(tilt) < 1.0, msg


def test_position_step_settles_without_oscillation():
    spec = load_robot("x8-3dof")
    sim = PhysicsSimulator(spec)
    x0 = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.5, -0.8])
    sim.reset(x0)
    target = x0.copy()
    target[0] += 0.5
    t, x, yz = [], [], []
    for k, _ in enumerate(_hold(sim, target, 5.0, dt=0.02)):
        t.append(0.02 * (k + 1))
        x.append(sim.data.qpos[0])
        yz.append(np.abs(sim.data.qpos[1:3] - x0[1:3]).max())
    t, err = np.array(t), np.array(x) - target[0]
    overshoot = err.max()
    settle = t[np.nonzero(np.abs(err) > 0.02)[0].max() + 1]
    big = np.sign(err[np.abs(err) > 0.005])  # sign changes of excursions beyond 1 % of the step
    crossings = int(np.count_nonzero(np.diff(big)))
    msg = f"overshoot {overshoot:.4f} m, 2 cm settling {settle:.2f} s, crossings {crossings}"
    assert overshoot < 0.05 and settle < 3.0 and crossings <= 1, msg
    assert abs(err[-1]) < 0.005 and max(yz) < 0.02, msg


@pytest.mark.parametrize(
    ("name", "x0"),
    [("planar-2dof", [0.0, 1.0, 0.3, 0.5]), ("x8-3dof", [0.0, 0.0, 1.0, 0.0, 0.0, 0.4, -0.6])],
)
def test_slow_motion_follows_kinematic_simulation(name, x0):
    """Same commands to both simulators for 10 s: y sinusoid 0.1 m/s, joints 0.2 rad/s."""
    spec = load_robot(name)
    kin = Kinematics(spec)
    x0 = np.array(x0)
    results = {}
    for mode in ("nominal", "measured"):
        sim, ideal = PhysicsSimulator(spec), KinematicSimulator(spec)
        sim.reset(x0)
        ideal.reset(x0)
        errors, side = [], 0.0
        for k in range(100):
            u = np.zeros(spec.nx)
            u[spec.platform.dofs.index("y")] = 0.1 * math.cos(0.6 * k * 0.1)
            u[spec.n_platform :] = 0.2 * np.cos(0.5 * k * 0.1 + np.arange(spec.n_joints))
            # nominal: ramps start on the ideal trajectory; measured: on the physics state
            start = ideal.state() if mode == "nominal" else sim.state()
            plan = np.tile(start, (11, 1))
            sim.advance(u, plan, 0.1)
            ideal.advance(u, plan, 0.1)
            ee_ideal = kin.ee_position(ideal.state()).full().ravel()
            errors.append(np.linalg.norm(sim.ee_position() - ee_ideal))
            if name == "planar-2dof":  # inactive DoFs held: x = 0, yaw = 0
                w, qx, qy, qz = sim.data.qpos[3:7]
                yaw = math.atan2(2 * (w * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz))
                side = max(side, abs(sim.data.qpos[0]), abs(yaw))
        results[mode] = (float(np.sqrt(np.mean(np.square(errors)))), float(np.max(errors)))
        assert side < 0.01, f"planar x/yaw left their fixed values: {side}"
    msg = ", ".join(f"{m}: EE RMS {r:.4f} m, max {mx:.4f} m" for m, (r, mx) in results.items())
    assert results["nominal"][0] < 0.03, msg
    assert results["measured"][0] < 0.04, msg


def test_arm_torque_matches_static_moment():
    spec = load_robot("x8-3dof")
    sim = PhysicsSimulator(spec)
    x0 = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0])
    sim.reset(x0)
    assert sim.extras()["arm_torque"] < 1e-9  # hanging straight: no moment
    # move the arm into a bent configuration, then hold it
    target = np.array([0.0, 0.0, 1.0, 0.0, 0.7, 1.0, -1.2])
    x = x0.copy()
    for _ in range(40):
        u = np.zeros(spec.nx)
        u[4:] = np.clip((target[4:] - x[4:]) / 0.1, -0.5, 0.5)
        sim.advance(u, np.tile(x, (11, 1)), 0.1)
        x = x + 0.1 * u
    moving = sim.extras()["arm_torque"]
    for _ in _hold(sim, x, 2.0):
        pass
    expected = _static_moment(spec, sim.true_state())
    measured = sim.extras()["arm_torque"]
    err = abs(measured - expected) / expected
    msg = f"arm torque {measured:.5f} N m vs static moment {expected:.5f} N m ({100 * err:.3f} %)"
    assert expected > 0.1 and err < 0.02, msg
    assert moving > 0.0
    # planar robot reset directly into a bent pose
    spec = load_robot("planar-2dof")
    sim = PhysicsSimulator(spec)
    x0 = np.array([0.0, 1.0, 0.9, -0.4])
    sim.reset(x0)
    for _ in _hold(sim, x0, 1.0):
        pass
    expected = _static_moment(spec, sim.true_state())
    assert sim.extras()["arm_torque"] == pytest.approx(expected, rel=0.02)


def test_yaw_ramp_is_tracked_and_unwrapped():
    spec = load_robot("x8-3dof")
    sim = PhysicsSimulator(spec)
    x = np.array([0.0, 0.0, 1.0, 3.0, 0.0, 0.0, 0.0])
    sim.reset(x)
    u = np.zeros(spec.nx)
    u[3] = 0.8
    for _ in range(60):
        sim.advance(u, np.tile(x, (11, 1)), 0.1)
        x = x + 0.1 * u
    state = sim.state()
    assert state[3] == pytest.approx(x[3], abs=0.01)  # 7.8 rad, past +pi twice
    assert np.linalg.norm(state[:3] - x[:3]) < 0.01


def test_noise_has_requested_std_and_is_reproducible():
    spec = load_robot("x8-3dof")
    sigma = {"position": 0.01, "yaw": 0.02, "joints": 0.005}
    sim = PhysicsSimulator(spec, noise=sigma, seed=7)
    x0 = np.array([0.1, 0.2, 1.0, 0.3, 0.2, 0.4, -0.5])
    sim.reset(x0)
    samples = np.array([sim.state() for _ in range(4000)])
    truth = sim.true_state()
    np.testing.assert_allclose(samples.mean(axis=0), truth, atol=2e-3)
    expected = np.array([0.01] * 3 + [0.02] + [0.005] * 3)
    np.testing.assert_allclose(samples.std(axis=0), expected, rtol=0.05)
    sim.reset(x0)
    np.testing.assert_array_equal(sim.state(), samples[0])
    other = PhysicsSimulator(spec, noise=sigma, seed=7)
    other.reset(x0)
    np.testing.assert_array_equal(other.state(), samples[0])
    other = PhysicsSimulator(spec, noise=sigma, seed=8)
    other.reset(x0)
    assert not np.array_equal(other.state(), samples[0])
    quiet = PhysicsSimulator(spec)
    quiet.reset(x0)
    np.testing.assert_array_equal(quiet.state(), quiet.true_state())


def test_from_options_and_xml(tmp_path):
    spec = load_robot("planar-2dof")
    sim = PhysicsSimulator.from_options(
        spec,
        {
            "rate_hz": 250,
            "rotors": 8,
            "seed": 3,
            "noise": {"position": 0.002},
            "gains": {"pos_p_xy": 1.2},
        },
    )
    assert sim.model.opt.timestep == pytest.approx(0.004) and sim.model.nu == 8 + 2
    assert sim.gains.pos_p_xy == 1.2 and sim.noise["position"] == 0.002 and sim.seed == 3
    path = sim.save_xml(tmp_path / "uam.xml")
    model = mujoco.MjModel.from_xml_path(str(path))
    assert model.nbody == sim.model.nbody and sim.to_xml() == path.read_text()


@pytest.mark.parametrize(
    ("options", "key"),
    [
        ({"nosie": {}}, "physics.nosie"),
        ({"noise": {"positon": 0.1}}, "physics.noise.positon"),
        ({"noise": {"yaw": -1.0}}, "physics.noise.yaw"),
        ({"noise": 0.1}, "physics.noise"),
        ({"gains": {"kp": 1.0}}, "physics.gains.kp"),
        ({"gains": {"pos_p_xy": "fast"}}, "physics.gains.pos_p_xy"),
        ({"rotors": 5}, "physics.rotors"),
        ({"rotors": 4.0}, "physics.rotors"),
        ({"rate_hz": 10}, "physics.rate_hz"),
        ({"seed": "x"}, "physics.seed"),
        ({"servo_hz": 0}, "physics.servo_hz"),
    ],
)
def test_bad_options_name_the_key(options, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.") + ":"):
        PhysicsSimulator.from_options(load_robot("planar-2dof"), options)


def test_bad_commands_are_rejected():
    spec = load_robot("planar-2dof")
    sim = PhysicsSimulator(spec)
    x0 = np.array([0.0, 1.0, 0.0, 0.0])
    with pytest.raises(ConfigError, match="dt"):
        sim.advance(np.zeros(4), np.tile(x0, (3, 1)), 0.0015)
    with pytest.raises(StateError):
        sim.advance(np.zeros(3), np.tile(x0, (3, 1)), 0.1)
    with pytest.raises(StateError):
        sim.reset(np.array([0.0, np.nan, 0.0, 0.0]))


# --- multi-rate inner loop ---------------------------------------------------------------


def test_outer_loop_runs_every_outer_every_ticks():
    pos, spins = rotor_layout(4, 0.25)
    mixer = Mixer(pos, spins, 0.016, f_max=2 * 2.0 * G / 4)
    fc = FlightController(2.0, (0.03, 0.03, 0.05), mixer, 0.002, outer_every=5)
    assert fc.outer_dt == pytest.approx(0.01)
    z = np.zeros(3)
    forces, motors = [], []
    for k in range(10):  # the position reference moves every tick
        f = fc.update(z, z, np.eye(3), z, np.array([0.01 * (k + 1), 0.0, 0.0]), z, 0.0)
        forces.append(fc.F)
        motors.append(f)
    # the thrust vector is recomputed on ticks 0 and 5 only, then held
    assert forces[1:5] == [forces[0]] * 4 and forces[6:] == [forces[5]] * 4
    assert forces[5][0] > forces[0][0] > 0.0
    # the inner loop runs every tick: its rate integrator moves the rotors in between
    assert not np.allclose(motors[1], motors[2])
    with pytest.raises(ConfigError, match="outer_every"):
        FlightController(2.0, (0.03, 0.03, 0.05), mixer, 0.002, outer_every=0)


def test_update_equals_outer_then_inner_on_floats():
    pos, spins = rotor_layout(6, 0.3)
    mixer = Mixer(pos, spins, 0.016, f_max=6.0)
    J = np.array([[0.05, 0.002, -0.001], [0.002, 0.06, 0.003], [-0.001, 0.003, 0.09]])
    a = FlightController(2.5, J, mixer, 0.002)
    b = FlightController(2.5, J, mixer, 0.002)
    rng = np.random.default_rng(1)
    for _ in range(20):
        p, v, w, p_ref, v_ref = (rng.normal(size=3) for _ in range(5))
        R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        R *= np.linalg.det(R)  # a rotation
        yaw, rate = rng.normal(), rng.normal()
        f = a.update(p, v, R, w, p_ref, v_ref, yaw, rate)
        b.outer(tuple(p.tolist()), tuple(v.tolist()), tuple(p_ref.tolist()), tuple(v_ref.tolist()))
        g = b.inner(R.ravel().tolist(), tuple(w.tolist()), yaw, rate)
        np.testing.assert_array_equal(f, g)
        np.testing.assert_allclose(mixer.A @ f, mixer.A @ mixer.mix(b.thrust, b.torque))
    np.testing.assert_allclose(a.R_sp.T @ a.R_sp, np.eye(3), atol=1e-12)


def test_multi_rate_matches_single_rate_loop():
    """Outer loop at 100 Hz (default) vs every 500 Hz step: same flight within millimetres."""
    spec = load_robot("x8-3dof")
    x0 = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.4, -0.6])
    runs = {}
    for outer in (100.0, 500.0):
        sim = PhysicsSimulator(spec, outer_rate_hz=outer)
        sim.reset(x0)
        x, ee, torque = x0.copy(), [], []
        for k in range(50):
            u = np.zeros(spec.nx)
            u[:3] = 0.2 * np.cos(0.6 * k * 0.1 + np.arange(3))
            u[3] = 0.3
            u[4:] = 0.3 * np.cos(0.5 * k * 0.1 + np.arange(3))
            sim.advance(u, np.tile(x, (2, 1)), 0.1)
            x = x + 0.1 * u
            ee.append(sim.ee_position())
            torque.append(sim.extras()["arm_torque"])
        runs[outer] = (np.array(ee), np.array(torque), sim)
    assert runs[100.0][2].outer_every == 5 and runs[500.0][2].outer_every == 1
    ee_diff = np.linalg.norm(runs[100.0][0] - runs[500.0][0], axis=1).max()
    t100, t500 = runs[100.0][1].mean(), runs[500.0][1].mean()
    msg = f"EE max diff {ee_diff:.2e} m, mean arm torque {t100:.4f} vs {t500:.4f} N m"
    assert ee_diff < 0.003 and abs(t100 - t500) < 0.02 * t500, msg


def test_derivative_gains_keep_the_step_response_settled():
    spec = load_robot("x8-3dof")
    gains = {"vel_d_xy": 0.1, "vel_d_z": 0.1, "rate_d_rp": 0.02, "rate_d_yaw": 0.01}
    sim = PhysicsSimulator.from_options(spec, {"gains": gains})
    x0 = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.5, -0.8])
    sim.reset(x0)
    target = x0.copy()
    target[0] += 0.5
    err = []
    for _ in _hold(sim, target, 4.0):
        err.append(sim.data.qpos[0] - target[0])
    assert max(err) < 0.05 and abs(err[-1]) < 0.005, f"overshoot {max(err)}, final {err[-1]}"


def test_outer_rate_option():
    spec = load_robot("planar-2dof")
    sim = PhysicsSimulator.from_options(spec, {"rate_hz": 250, "outer_rate_hz": 50})
    assert sim.outer_every == 5 and sim.outer_rate_hz == pytest.approx(50.0)
    assert sim.controller.outer_dt == pytest.approx(0.02)
    sim = PhysicsSimulator(spec, outer_rate_hz=90.0)  # rounded to a divisor of 500 Hz
    assert sim.outer_every == 6 and sim.outer_rate_hz == pytest.approx(500.0 / 6)
    for value in (600.0, 5.0, "fast"):
        with pytest.raises(ConfigError, match=r"physics\.outer_rate_hz:"):
            PhysicsSimulator.from_options(spec, {"outer_rate_hz": value})
