"""MJCF generation: loads in MuJoCo and matches the CasADi kinematics exactly."""

from __future__ import annotations

import math
from dataclasses import replace

import mujoco
import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.robot.kinematics import Kinematics
from aeromanip.robot.loader import load_robot
from aeromanip.robot.spec import PLATFORM_DOFS, Inertial
from aeromanip.sim.flight_controller import Mixer, rotor_layout
from aeromanip.sim.mjcf import (
    FREE_JOINT,
    K_M,
    MIN_MASS,
    THRUST_TO_WEIGHT,
    robot_to_mjcf,
    servo_gains,
    total_mass,
)

ROBOTS = ["planar-2dof", "x8-3dof"]


def _place(spec, model, data, x):
    """Put the MuJoCo model at NMPC state ``x`` (roll = pitch = 0)."""
    pose = {d: float(spec.platform.fixed.get(d, 0.0)) for d in PLATFORM_DOFS}
    for i, d in enumerate(spec.platform.dofs):
        pose[d] = float(x[i])
    adr = model.jnt_qposadr[model.joint(FREE_JOINT).id]
    data.qpos[adr : adr + 3] = (pose["x"], pose["y"], pose["z"])
    data.qpos[adr + 3 : adr + 7] = (math.cos(pose["yaw"] / 2), 0, 0, math.sin(pose["yaw"] / 2))
    for j, q in zip(spec.joints, x[spec.n_platform :], strict=True):
        data.qpos[model.jnt_qposadr[model.joint(j.name).id]] = q
    mujoco.mj_kinematics(model, data)


@pytest.mark.parametrize("name", ROBOTS)
def test_mjcf_loads_with_expected_structure(name):
    spec = flat(load_robot(name))
    model = mujoco.MjModel.from_xml_string(robot_to_mjcf(spec, rotors=4))
    assert model.nq == 7 + spec.n_joints and model.nu == 4 + spec.n_joints
    base = model.body(spec.base_link).id
    assert model.body_subtreemass[base] == pytest.approx(spec.platform.mass + spec.arm_mass)
    assert model.body_mass[base] == pytest.approx(spec.platform.mass)
    np.testing.assert_allclose(model.body_inertia[base], spec.platform.inertia)
    # rotors: X layout at arm_length, thrust along z, alternating reaction torque
    f_max = THRUST_TO_WEIGHT * total_mass(spec) * 9.81 / 4
    spins = []
    for i in range(4):
        site = model.site(f"rotor_{i + 1}")
        assert np.hypot(*site.pos[:2]) == pytest.approx(spec.platform.arm_length)
        assert abs(site.pos[0]) == pytest.approx(abs(site.pos[1]))  # 45 deg: X layout
        gear = model.actuator(f"rotor_{i + 1}").gear
        np.testing.assert_allclose(gear[:3], [0, 0, 1])
        assert abs(gear[5]) == pytest.approx(K_M)
        spins.append(np.sign(gear[5]))
        np.testing.assert_allclose(model.actuator(f"rotor_{i + 1}").ctrlrange, [0, f_max])
    assert spins == [1, -1, 1, -1]
    # servos: position actuators with the documented gains; joint limits and no contacts
    for j, (kp, kv) in zip(spec.joints, servo_gains(spec), strict=True):
        act = model.actuator(f"servo_{j.name}")
        assert act.gainprm[0] == pytest.approx(kp) and act.biasprm[2] == pytest.approx(-kv)
        np.testing.assert_allclose(model.joint(j.name).range, [j.lower, j.upper])
    assert model.opt.timestep == pytest.approx(0.002)
    assert np.all(model.geom_contype == 0) and np.all(model.geom_conaffinity == 0)


def _twisted(name):
    """A built-in robot with non-trivial mount, joint and end-effector rotations and axes."""
    spec = load_robot(name)
    rng = np.random.default_rng(11)
    joints = []
    for j in spec.joints:
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        rpy = tuple(float(a) for a in rng.uniform(-2.5, 2.5, 3))
        com = tuple(float(a) for a in rng.uniform(-0.05, 0.05, 3))
        joints.append(replace(j, rpy=rpy, axis=tuple(axis), link=replace(j.link, com=com)))
    return replace(
        spec,
        joints=tuple(joints),
        mount_xyz=(0.02, -0.01, -0.08),
        mount_rpy=(0.3, -0.2, 0.9),
        ee_rpy=(-1.0, 0.4, 2.0),
    )


@pytest.mark.parametrize("twisted", [False, True])
@pytest.mark.parametrize("name", ROBOTS)
def test_mjcf_arm_kinematics_match_casadi(name, twisted):
    spec = _twisted(name) if twisted else load_robot(name)
    kin = Kinematics(spec)
    model = mujoco.MjModel.from_xml_string(robot_to_mjcf(spec))
    data = mujoco.MjData(model)
    rng = np.random.default_rng(3)
    lo = np.array([j.lower for j in spec.joints])
    hi = np.array([j.upper for j in spec.joints])
    ee = model.site(spec.ee_link).id
    arm = [model.body(j.link_name).id for j in spec.joints]
    masses = np.array([j.link.mass for j in spec.joints])
    for _ in range(20):
        x = np.concatenate([rng.uniform(-2, 2, spec.n_platform), rng.uniform(lo, hi)])
        _place(spec, model, data, x)
        np.testing.assert_allclose(data.site_xpos[ee], kin.ee_position(x).full().ravel(), atol=1e-9)
        np.testing.assert_allclose(
            data.site_xmat[ee].reshape(3, 3), kin.ee_rotation(x).full(), atol=1e-9
        )
        joints = np.array([data.xanchor[model.joint(j.name).id] for j in spec.joints]).T
        np.testing.assert_allclose(joints, kin.joint_positions(x).full(), atol=1e-9)
        # arm CoG (link CoMs and masses) in the body frame
        base = model.body(spec.base_link).id
        R, p = data.xmat[base].reshape(3, 3), data.xpos[base]
        cog_world = masses @ data.xipos[arm] / masses.sum()
        np.testing.assert_allclose(R.T @ (cog_world - p), kin.cog_body(x).full().ravel(), atol=1e-9)


def test_mjcf_bounds_massless_links_and_supports_more_rotors():
    spec = flat(load_robot("x8-3dof"))
    light = Inertial(mass=0.0, com=(0.0, 0.0, 0.0), inertia=(0.0,) * 6)
    joints = (replace(spec.joints[0], link=light), *spec.joints[1:])
    spec = replace(spec, joints=joints)
    model = mujoco.MjModel.from_xml_string(robot_to_mjcf(spec, rotors=8))
    assert model.body(spec.joints[0].link_name).mass[0] == pytest.approx(MIN_MASS)
    assert model.nu == 8 + spec.n_joints
    angles = [math.atan2(*model.site(f"rotor_{i + 1}").pos[1::-1]) for i in range(8)]
    np.testing.assert_allclose(np.diff(np.unwrap(angles)), 2 * math.pi / 8)


def flat(spec):
    """``spec`` with its rotors in one plane (no coaxial pairs)."""
    return replace(spec, platform=replace(spec.platform, coaxial=False))


def test_x8_has_four_coaxial_pairs_that_allocate_any_wrench():
    """The 3DR X8: 8 rotors on 4 arms, each arm an upper and a lower rotor of opposite
    spin; the mixer's allocation reproduces thrust and every body torque exactly."""
    spec = load_robot("x8-3dof")
    assert (spec.platform.rotors, spec.platform.coaxial) == (8, True)
    model = mujoco.MjModel.from_xml_string(robot_to_mjcf(spec))
    assert model.nu == 8 + spec.n_joints
    sites = np.array([model.site(f"rotor_{i + 1}").pos for i in range(8)])
    spins = np.sign([model.actuator(f"rotor_{i + 1}").gear[5] for i in range(8)])
    np.testing.assert_allclose(sites[0::2], sites[1::2])  # pairs share their arm
    np.testing.assert_array_equal(spins[0::2], -spins[1::2])
    angles = np.degrees(np.arctan2(sites[0::2, 1], sites[0::2, 0])) % 360
    np.testing.assert_allclose(angles, [45, 135, 225, 315])
    positions, spin = rotor_layout(8, spec.platform.arm_length, coaxial=True)
    np.testing.assert_allclose(sites[:, :2], positions, atol=1e-12)  # MJCF = mixer's layout
    np.testing.assert_array_equal(spins, spin)
    mixer = Mixer(positions, spin, K_M, 100.0)
    wrench = np.array([20.0, 0.3, -0.2, 0.05])
    np.testing.assert_allclose(mixer.A @ mixer.mix(wrench[0], wrench[1:]), wrench, atol=1e-9)


@pytest.mark.parametrize("rotors", [3, 5, 2, 0])
def test_mjcf_rejects_bad_rotor_count(rotors):
    with pytest.raises(ConfigError, match=r"physics\.rotors:"):
        robot_to_mjcf(load_robot("x8-3dof"), rotors=rotors)
