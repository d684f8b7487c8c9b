"""Contact with scenario surfaces: force balance, Coulomb friction, Newton's second law,
the wrist sensor against the true contact force, no contact, and the options' checks."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.robot.loader import load_robot
from aeromanip.sim.contact import probe_body, read_surfaces, sensors, surface_geoms
from aeromanip.sim.contact_sensor import CONTACT_COLUMNS, ContactSensor
from aeromanip.sim.physics import PhysicsSimulator

G = 9.81
MASS = 2.0  # [kg] the pressed block
RADIUS = 0.02  # [m] its probe sphere
# static cases: a soft contact settling for 1 s, MuJoCo's solver at its default tolerance
STATIC_RTOL = 1e-4


def _block(surface: dict, gravity: bool) -> tuple[mujoco.MjModel, mujoco.MjData, ContactSensor]:
    """A free block (mass ``MASS``, CoM at its probe's centre, a rotational inertia so
    large it cannot roll) touching ``surface`` with the simulator's probe and sensor."""
    surfaces = read_surfaces([surface])
    n, p = np.array(surfaces[0].normal), np.array(surfaces[0].point)
    start = p + n * RADIUS  # the probe resting on the face
    g = -G if gravity else 0.0
    xml = "\n".join(
        [
            "<mujoco>",
            f'  <option timestep="0.002" gravity="0 0 {g}" cone="elliptic"/>',
            "  <worldbody>",
            *surface_geoms(surfaces),
            f'    <body name="block" pos="{" ".join(map(repr, start.tolist()))}">',
            "      <freejoint/>",
            f'      <inertial pos="0 0 0" mass="{MASS}" diaginertia="1e3 1e3 1e3"/>',
            *probe_body("      ", "0 0 0", "1 0 0 0", RADIUS),
            "    </body>",
            "  </worldbody>",
            *sensors(),
            "</mujoco>",
        ]
    )
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    return model, data, ContactSensor(model, data, surfaces)


def _push(model, data, force, seconds):
    """Apply ``force`` [N] (world) at the block's CoM for ``seconds``."""
    block = model.body("block").id
    data.xfrc_applied[block, :3] = force
    for _ in range(round(seconds / model.opt.timestep)):
        mujoco.mj_step(model, data)


OBLIQUE = [1.0, -2.0, 0.5]


@pytest.mark.parametrize("normal", [[0, 0, 1], [-1, 0, 0], OBLIQUE])
def test_pressed_block_normal_force_equals_the_load(normal):
    """Gravity off, a load F along -n: at rest the contact's normal force is F (force
    balance), along n, with no friction; the sensor measures the same force."""
    surface = dict(kind="wall", point=[0.3, -0.2, 1.0], normal=normal, size=[1, 1], friction=0.8)
    model, data, sensor = _block(surface, gravity=False)
    n = np.array(normal, dtype=float) / np.linalg.norm(normal)
    load = 7.5  # [N]
    _push(model, data, -load * n, 1.0)
    r = sensor.read(1.0)
    assert np.linalg.norm(data.qvel) < 1e-6  # at rest: a static case
    assert r.in_contact and r.surface == 0
    assert r.normal_force == pytest.approx(load, rel=STATIC_RTOL)
    assert r.tangential_force < STATIC_RTOL * load
    np.testing.assert_allclose(r.contact_force, load * n, atol=STATIC_RTOL * load)
    np.testing.assert_allclose(r.force, r.contact_force, atol=1e-9)
    np.testing.assert_allclose(r.torque, 0.0, atol=1e-9)  # the force acts at the site


def test_block_on_a_floor_carries_its_weight_and_the_load():
    """Gravity on: the floor's normal force is m g plus the downward load."""
    surface = dict(kind="wall", point=[0, 0, 0.5], normal=[0, 0, 1], size=[2, 2], friction=0.5)
    model, data, sensor = _block(surface, gravity=True)
    _push(model, data, [0.0, 0.0, -3.0], 1.0)
    r = sensor.read(1.0)
    assert r.normal_force == pytest.approx(MASS * G + 3.0, rel=STATIC_RTOL)
    np.testing.assert_allclose(r.force, [0.0, 0.0, MASS * G + 3.0], rtol=STATIC_RTOL, atol=1e-9)


def test_ceiling_pushed_from_below():
    surface = dict(kind="ceiling", point=[0, 0, 2.0], size=[2, 2], friction=0.5)
    model, data, sensor = _block(surface, gravity=True)
    _push(model, data, [0.0, 0.0, MASS * G + 4.0], 1.0)  # 4 N up, net of the weight
    r = sensor.read(1.0)
    assert r.normal_force == pytest.approx(4.0, rel=STATIC_RTOL)
    np.testing.assert_allclose(r.force, [0.0, 0.0, -4.0], atol=4.0 * STATIC_RTOL)


MU = 0.4


def test_friction_holds_below_mu_n():
    """A horizontal push below mu N: the block stays, friction balances the push."""
    surface = dict(kind="wall", point=[0, 0, 0], normal=[0, 0, 1], size=[4, 4], friction=MU)
    model, data, sensor = _block(surface, gravity=True)
    push = 0.5 * MU * MASS * G
    _push(model, data, [push, 0.0, 0.0], 1.0)
    r = sensor.read(1.0)
    assert abs(data.qvel[0]) < 5e-3  # sticking (MuJoCo's soft friction creeps: 2 mm/s)
    assert r.tangential_force == pytest.approx(push, rel=1e-3)
    assert r.tangential_force <= MU * r.normal_force


def test_sliding_friction_is_mu_n_and_balances_the_drive():
    """Dragged along the floor at a steady 1.4 cm/s by a velocity servo (3 cm/s set): at every
    step friction stays in the cone (f_t <= mu f_n) and sits on its edge (sliding), opposes
    the motion, and balances the drive on average (constant velocity: no net force)."""
    surface = dict(kind="wall", point=[0, 0, 0], normal=[0, 0, 1], size=[40, 40], friction=MU)
    model, data, sensor = _block(surface, gravity=True)
    _push(model, data, [0.0, 0.0, 0.0], 0.3)  # settle on the floor
    normal, tangential, drive, speed = [], [], [], []
    for k in range(750):  # 1.5 s: the speed set ramps up over 0.4 s, the last 0.5 s measured
        drive.append(500.0 * (0.03 * min(1.0, k / 200) - float(data.qvel[0])))  # [N]
        _push(model, data, [drive[-1], 0.0, 0.0], model.opt.timestep)
        r = sensor.read(k)
        normal.append(r.normal_force)
        tangential.append(r.tangential_force)
        speed.append(float(data.qvel[0]))
        assert r.contact_force[0] <= 0.0
    fn, ft = np.array(normal[500:]), np.array(tangential[500:])
    assert np.all(ft <= MU * fn * (1 + 1e-9))
    np.testing.assert_allclose(ft, MU * fn, rtol=1e-6)
    np.testing.assert_allclose(fn, MASS * G, rtol=1e-4)
    assert min(speed[500:]) > 0.01
    assert np.mean(drive[500:]) == pytest.approx(MU * MASS * G, rel=1e-3)


# --- the physics simulator ---------------------------------------------------------------

FLOOR_UNDER_EE = dict(kind="wall", point=[0, 0, 0.52], normal=[0, 0, 1], size=[1, 1], friction=0.5)


def _hover(sim, seconds, dt=0.1):
    x = sim.true_state()
    u, plan = np.zeros(sim.spec.nx), np.tile(x, (11, 1))
    for _ in range(round(seconds / dt)):
        sim.advance(u, plan, dt)


def test_uam_resting_its_probe_on_a_floor_balances_forces():
    """The UAM holding hover with its probe on a floor 1 cm above where it hangs (its
    bottom at z = 0.51): quasi-static, the floor carries m g minus the thrust; the wrist
    sensor measures the contact force."""
    sim = PhysicsSimulator(load_robot("x8-3dof"), surfaces=[FLOOR_UNDER_EE])
    assert set(CONTACT_COLUMNS) <= set(sim.extras()) and "contact" in sim.instant_extras
    _hover(sim, 3.0)
    e = sim.extras()
    assert e["contact"] == 1.0 and e["f_n"] > 0.1
    tilt = math.acos(math.cos(e["roll"]) * math.cos(e["pitch"]))
    assert e["f_n"] + e["thrust_total"] * math.cos(tilt) == pytest.approx(sim.mass * G, abs=0.02)
    wrench = sim.measured_wrench()
    np.testing.assert_allclose(wrench[:3], [0.0, 0.0, e["f_n"]], atol=1e-6)
    assert e["f_t"] < 1e-6


def test_no_contact_no_force_and_no_surfaces_no_sensor():
    far = dict(FLOOR_UNDER_EE, point=[0, 0, -5.0])
    sim = PhysicsSimulator(load_robot("x8-3dof"), surfaces=[far])
    _hover(sim, 0.5)
    e = sim.extras()
    assert e["contact"] == 0.0 and e["f_n"] == 0.0 and e["f_t"] == 0.0
    np.testing.assert_allclose(sim.measured_wrench(), 0.0, atol=1e-9)
    plain = PhysicsSimulator(load_robot("x8-3dof"))
    assert plain.measured_wrench() is None and "f_n" not in plain.extras()
    assert "ee_probe" not in plain.to_xml() and 'contact="disable"' in plain.to_xml()


def test_sensor_noise_is_seeded_and_leaves_the_state_noise_alone():
    spec = load_robot("x8-3dof")
    noise = {"position": 0.01, "force": 0.2}
    runs = []
    for force_std in (0.2, 0.2, 0.0):
        sim = PhysicsSimulator(
            spec, surfaces=[FLOOR_UNDER_EE], noise=dict(noise, force=force_std), seed=3
        )
        states, errors = [], []
        for k in range(200):
            sim.time = 0.01 * (k + 1)  # a new reading each time (no flight needed)
            states.append(sim.state())
            r = sim.contact.read(sim.time)
            errors.append(r.force - r.contact_force)
        runs.append((np.array(states), np.array(errors)))
    np.testing.assert_array_equal(runs[0][1], runs[1][1])  # same seed, same noise
    np.testing.assert_array_equal(runs[0][0], runs[2][0])  # state noise unchanged
    assert np.std(runs[0][1]) == pytest.approx(0.2, rel=0.15)
    np.testing.assert_allclose(runs[2][1], 0.0, atol=1e-9)


@pytest.mark.parametrize(
    "surfaces, match",
    [
        ({"kind": "wall"}, r"physics\.surfaces: must be an array of tables"),
        ([dict(FLOOR_UNDER_EE, kind="pipe")], r"surfaces\[0\]\.kind: 'pipe' is not one of"),
        ([dict(FLOOR_UNDER_EE, colour=1)], r"surfaces\[0\]\.colour: unknown key"),
        ([dict(FLOOR_UNDER_EE, normal=[0, 0, 0])], r"surfaces\[0\]\.normal: must not be zero"),
        ([dict(FLOOR_UNDER_EE, normal=[0, 1])], r"surfaces\[0\]\.normal: must be a list of 3"),
        ([dict(FLOOR_UNDER_EE, size=[1, -1])], r"surfaces\[0\]\.size: must be a list of 2"),
        ([dict(FLOOR_UNDER_EE, friction=-0.1)], r"surfaces\[0\]\.friction: must be in \[0, 10\]"),
        ([dict(FLOOR_UNDER_EE, friction="high")], r"friction: must be a finite number"),
        ([dict(FLOOR_UNDER_EE, thickness=0)], r"surfaces\[0\]\.thickness: must be > 0"),
        ([{k: v for k, v in FLOOR_UNDER_EE.items() if k != "point"}], r"\.point: missing"),
        ([{k: v for k, v in FLOOR_UNDER_EE.items() if k != "normal"}], r"\.normal: missing"),
        ([dict(FLOOR_UNDER_EE, kind="ceiling")], r"\.normal: a ceiling faces down"),
    ],
)
def test_bad_surface_options_are_one_line_errors(surfaces, match):
    with pytest.raises(ConfigError, match=match) as err:
        PhysicsSimulator.check_options({"surfaces": surfaces})
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    "options, match",
    [
        ({"probe_radius": 0.0}, r"physics\.probe_radius: must be > 0"),
        ({"probe_radius": 0.5}, r"physics\.probe_radius: must be in \[0, 0.1\]"),
        ({"noise": {"force": 5.0}}, r"physics\.noise\.force: must be in \[0, 1\]"),
    ],
)
def test_bad_probe_and_sensor_options(options, match):
    with pytest.raises(ConfigError, match=match):
        PhysicsSimulator.check_options(options)
