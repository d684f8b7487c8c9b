"""URDF import/export, checked against MuJoCo's own URDF importer and a small numpy FK."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.robot.loader import load_robot
from aeromanip.robot.spec import Inertial, Joint, Platform, RobotSpec
from aeromanip.robot.urdf import UrdfArm, arm_from_urdf, arm_from_urdf_string
from aeromanip.robot.urdf_export import robot_to_urdf

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(__file__).resolve().parents[1] / "data"
BUILTIN = ["x8-3dof", "planar-2dof"]
MJ_COMPILER = '<mujoco><compiler fusestatic="false" discardvisual="true"/></mujoco>'


# --- independent numpy kinematics ------------------------------------------------------


def rot(axis, angle):
    """Rodrigues rotation about a unit axis."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def rpy_rot(rpy):
    """URDF fixed-axis XYZ: Rz(yaw) Ry(pitch) Rx(roll)."""
    return rot((0, 0, 1), rpy[2]) @ rot((0, 1, 0), rpy[1]) @ rot((1, 0, 0), rpy[0])


def tf(xyz=(0, 0, 0), R=None):
    T = np.eye(4)
    T[:3, :3] = np.eye(3) if R is None else R
    T[:3, 3] = xyz
    return T


def arm_fk(joints, ee_xyz, ee_rpy, q, T0=None):
    """World frames of the moving links and of the end effector."""
    T = np.eye(4) if T0 is None else T0
    frames = []
    for j, qi in zip(joints, q, strict=True):
        T = T @ tf(j.xyz, rpy_rot(j.rpy)) @ tf(R=rot(j.axis, qi))
        frames.append(T)
    return frames, T @ tf(ee_xyz, rpy_rot(ee_rpy))


def inertia_matrix(i6):
    ixx, iyy, izz, ixy, ixz, iyz = i6
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])


def composite(masses, coms, inertias):
    """Total mass, CoM and inertia about the CoM of rigid parts (world frame)."""
    m = float(np.sum(masses))
    c = np.einsum("i,ij->j", masses, coms) / m
    total = np.zeros((3, 3))
    for mi, ci, Ii in zip(masses, coms, inertias, strict=True):
        d = ci - c
        total += Ii + mi * (d @ d * np.eye(3) - np.outer(d, d))
    return m, c, total


def arm_composite(joints, frames):
    masses = np.array([j.link.mass for j in joints])
    coms = np.array(
        [T[:3, :3] @ j.link.com + T[:3, 3] for j, T in zip(joints, frames, strict=True)]
    )
    inertias = [
        T[:3, :3] @ inertia_matrix(j.link.inertia) @ T[:3, :3].T
        for j, T in zip(joints, frames, strict=True)
    ]
    return composite(masses, coms, inertias)


def mj_subtree_composite(model, data, root_body):
    """Mass, CoM and inertia about the CoM (world) of a body's subtree in MuJoCo."""
    ids = [b for b in range(model.nbody) if any(a == root_body for a in _ancestors(model, b))]
    inertias = [
        data.ximat[b].reshape(3, 3) @ np.diag(model.body_inertia[b]) @ data.ximat[b].reshape(3, 3).T
        for b in ids
    ]
    return composite(model.body_mass[ids], data.xipos[ids], inertias)


def _ancestors(model, b):
    out = [b]
    while b:
        b = model.body_parentid[b]
        out.append(b)
    return out


def _after_robot(text):
    i = text.index("<robot ")
    j = text.index(">", i) + 1
    return text[:j] + MJ_COMPILER + text[j:]


def assert_joints_equal(a, b, tol=1e-12):
    assert len(a) == len(b)
    for ja, jb in zip(a, b, strict=True):
        assert (ja.name, ja.link_name) == (jb.name, jb.link_name)
        for key in ("xyz", "rpy", "axis"):
            np.testing.assert_allclose(getattr(ja, key), getattr(jb, key), rtol=0, atol=tol)
        assert (ja.lower, ja.upper) == pytest.approx((jb.lower, jb.upper), abs=tol)
        assert ja.velocity == pytest.approx(jb.velocity, abs=tol)
        assert ja.link.mass == pytest.approx(jb.link.mass, abs=tol)
        np.testing.assert_allclose(ja.link.com, jb.link.com, rtol=0, atol=tol)
        np.testing.assert_allclose(ja.link.inertia, jb.link.inertia, rtol=0, atol=tol)


# --- round trips ------------------------------------------------------------------------


@pytest.mark.parametrize("name", BUILTIN)
def test_round_trip_builtin(name):
    spec = load_robot(name)
    text = robot_to_urdf(spec)
    arm = arm_from_urdf_string(text, base_link="arm_mount_link", tip_link=spec.ee_link)
    assert isinstance(arm, UrdfArm)
    assert (arm.base_link, arm.tip_link) == ("arm_mount_link", spec.ee_link)
    assert_joints_equal(arm.joints, spec.joints)
    np.testing.assert_allclose(arm.ee_xyz, spec.ee_xyz, rtol=0, atol=1e-12)
    np.testing.assert_allclose(arm.ee_rpy, spec.ee_rpy, rtol=0, atol=1e-12)
    again = replace(spec, joints=arm.joints, ee_xyz=arm.ee_xyz, ee_rpy=arm.ee_rpy)
    assert robot_to_urdf(again) == text
    assert "<mujoco" not in text  # plain URDF unless asked


def test_round_trip_continuous_and_rotated_frames():
    spec = load_robot("x8-3dof")
    j0 = replace(spec.joints[0], lower=-math.inf, upper=math.inf, rpy=(0.1, -0.2, 0.3))
    j2 = replace(
        spec.joints[2],
        axis=(0.0, 0.6, 0.8),
        link=Inertial(0.08, (0.01, -0.02, -0.08), (2e-4, 3e-4, 1e-4, 1e-5, -2e-5, 3e-6)),
    )
    spec = replace(
        spec,
        joints=(j0, spec.joints[1], j2),
        ee_rpy=(0.0, 0.4, -1.1),
        mount_rpy=(math.pi, 0.0, 0.0),
    )
    text = robot_to_urdf(spec)
    assert 'type="continuous"' in text
    arm = arm_from_urdf_string(text, base_link="arm_mount_link", tip_link=spec.ee_link)
    assert_joints_equal(arm.joints, spec.joints)
    assert arm.joints[0].lower == -math.inf and arm.joints[0].upper == math.inf
    np.testing.assert_allclose(arm.ee_rpy, spec.ee_rpy, rtol=0, atol=1e-12)


def test_default_base_folds_the_mount_into_the_first_joint():
    spec = load_robot("x8-3dof")
    arm = arm_from_urdf_string(robot_to_urdf(spec))  # root base_link, single leaf end_effector
    assert (arm.base_link, arm.tip_link) == (spec.base_link, spec.ee_link)
    expected = np.add(spec.mount_xyz, spec.joints[0].xyz)
    np.testing.assert_allclose(arm.joints[0].xyz, expected, atol=1e-15)
    assert_joints_equal(arm.joints[1:], spec.joints[1:])


# --- export against MuJoCo --------------------------------------------------------------


def _variant(label):
    """A built-in robot, or one with constant (inactive) platform offsets."""
    if label in BUILTIN:
        return load_robot(label)
    if label == "planar-fixed-x-yaw":
        planar = load_robot("planar-2dof")
        pf = replace(planar.platform, fixed={"x": 0.3, "yaw": 0.7})
        return replace(planar, platform=pf, mount_rpy=(0.2, -0.1, 0.3))
    if label == "x8-fixed-yaw":
        return replace(load_robot("x8-3dof"), platform=Platform(("x", "y", "z"), {"yaw": -1.2}))
    fixed = {"x": 0.1, "y": -0.2, "z": 1.0, "yaw": 0.5}
    return replace(load_robot("x8-3dof"), platform=Platform((), fixed))


@pytest.mark.parametrize(
    "label", [*BUILTIN, "planar-fixed-x-yaw", "x8-fixed-yaw", "x8-hovering-fixed"]
)
def test_platform_joints_export_in_mujoco(label):
    spec = _variant(label)
    text = robot_to_urdf(spec, platform_joints=True, mujoco_compiler=True)
    model = mujoco.MjModel.from_xml_string(text)
    data = mujoco.MjData(model)
    assert model.nq == spec.nx
    names = [model.joint(i).name for i in range(model.njnt)]
    assert names == [f"platform_{d}" for d in spec.platform.dofs] + [j.name for j in spec.joints]
    base = model.body(spec.base_link).id
    ee = model.body(spec.ee_link).id
    arm_root = model.body(spec.joints[0].link_name).id
    rng = np.random.default_rng(7)
    for _ in range(20):
        x = rng.uniform(-1.5, 1.5, spec.nx)
        data.qpos[:] = x
        mujoco.mj_kinematics(model, data)
        pose = dict(spec.platform.fixed) | dict(zip(spec.platform.dofs, x, strict=False))
        p = [pose.get(k, 0.0) for k in "xyz"]
        R = rot((0, 0, 1), pose.get("yaw", 0.0))
        np.testing.assert_allclose(data.xpos[base], p, atol=1e-12)
        np.testing.assert_allclose(data.xmat[base].reshape(3, 3), R, atol=1e-12)
        T0 = tf(p, R) @ tf(spec.mount_xyz, rpy_rot(spec.mount_rpy))
        frames, T_ee = arm_fk(spec.joints, spec.ee_xyz, spec.ee_rpy, x[spec.n_platform :], T0)
        np.testing.assert_allclose(data.xpos[ee], T_ee[:3, 3], atol=1e-12)
        np.testing.assert_allclose(data.xmat[ee].reshape(3, 3), T_ee[:3, :3], atol=1e-12)
        m, c, _ = arm_composite(spec.joints, frames)
        m_mj, c_mj, _ = mj_subtree_composite(model, data, arm_root)
        assert m_mj == pytest.approx(m, abs=1e-12)
        np.testing.assert_allclose(c_mj, c, atol=1e-12)


@pytest.mark.parametrize("name", BUILTIN)
def test_plain_export_loads_in_mujoco(name):
    spec = load_robot(name)
    model = mujoco.MjModel.from_xml_string(robot_to_urdf(spec))
    assert model.nq == spec.n_joints
    # the root (platform) link is static, so MuJoCo fuses it into the world body
    assert model.body_mass.sum() == pytest.approx(spec.arm_mass, abs=1e-12)


# --- import of a third-party-style arm ---------------------------------------------------


def test_import_matches_mujoco_on_branched_arm():
    path = DATA / "branched_arm.urdf"
    arm = arm_from_urdf(path, tip_link="tcp")
    assert [j.name for j in arm.joints] == ["j1", "j2", "j3", "j4"]
    assert arm.joints[2].axis == pytest.approx((math.sqrt(0.5), math.sqrt(0.5), 0.0))
    assert (arm.joints[3].lower, arm.joints[3].upper) == (-math.inf, math.inf)
    assert arm.joints[3].velocity == 2.0
    # camera + elbow housing ride on link2; tool + off-chain finger on link4
    assert arm.joints[1].link.mass == pytest.approx(0.2 + 0.04 + 0.07)
    assert arm.joints[3].link.mass == pytest.approx(0.05 + 0.08 + 0.01)
    model = mujoco.MjModel.from_xml_string(_after_robot(path.read_text()))
    data = mujoco.MjData(model)
    assert model.nq == 5  # 4 arm joints + the finger slide, left at 0
    adr = [model.joint(j.name).qposadr[0] for j in arm.joints]
    tcp, link1 = model.body("tcp").id, model.body("link1").id
    rng = np.random.default_rng(3)
    for _ in range(50):
        q = rng.uniform(-3.0, 3.0, 4)
        data.qpos[:] = 0.0
        data.qpos[adr] = q
        mujoco.mj_kinematics(model, data)
        frames, T_ee = arm_fk(arm.joints, arm.ee_xyz, arm.ee_rpy, q)
        np.testing.assert_allclose(T_ee[:3, 3], data.xpos[tcp], atol=1e-9)
        np.testing.assert_allclose(T_ee[:3, :3], data.xmat[tcp].reshape(3, 3), atol=1e-9)
        m, c, inertia = arm_composite(arm.joints, frames)
        m_mj, c_mj, inertia_mj = mj_subtree_composite(model, data, link1)
        assert m == pytest.approx(m_mj, abs=1e-12)
        np.testing.assert_allclose(c, c_mj, atol=1e-9)
        np.testing.assert_allclose(inertia, inertia_mj, atol=1e-9)


def test_import_without_fixed_links_keeps_inertia_rotation():
    text = _urdf(
        inertial='<inertial><origin xyz="0.1 0 0" rpy="0 0 1.5707963267948966"/>'
        '<mass value="2"/><inertia ixx="1" iyy="2" izz="3" ixy="0" ixz="0" iyz="0"/>'
        "</inertial>"
    )
    link = arm_from_urdf_string(text).joints[1].link
    np.testing.assert_allclose(link.inertia, (2, 1, 3, 0, 0, 0), atol=1e-15)
    assert link.mass == 2 and link.com == (0.1, 0.0, 0.0)


def test_missing_inertial_is_massless():
    arm = arm_from_urdf_string(_urdf())
    assert arm.joints[0].link == Inertial(0.0, (0.0, 0.0, 0.0), (0.0,) * 6)
    assert (arm.base_link, arm.tip_link) == ("base", "tip")


# --- errors -----------------------------------------------------------------------------


def _urdf(
    elbow_type="revolute",
    limit='<limit lower="-1" upper="1" velocity="2"/>',
    axis='<axis xyz="0 1 0"/>',
    parent="upper",
    inertial="",
    extra="",
):
    return f"""<robot name="t">
  <link name="base"/><link name="upper"/><link name="lower">{inertial}</link><link name="tip"/>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/>
    <limit lower="-1" upper="1" velocity="2"/></joint>
  <joint name="elbow" type="{elbow_type}"><origin xyz="0 0 -0.2"/><parent link="{parent}"/>
    <child link="lower"/>{axis}{limit}</joint>
  <joint name="tool" type="fixed"><parent link="lower"/><child link="tip"/></joint>{extra}
</robot>"""


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"limit": ""}, r"<string>: joint 'elbow': <limit> is missing"),
        ({"limit": '<limit lower="0" upper="1"/>'}, r"joint 'elbow': <limit velocity> is missing"),
        ({"elbow_type": "continuous", "limit": ""}, r"joint 'elbow': <limit> is missing"),
        ({"limit": '<limit lower="1" upper="-1" velocity="1"/>'}, r"joint 'elbow'.*above upper"),
        ({"axis": '<axis xyz="0 0 0"/>'}, r"joint 'elbow': <axis> is zero"),
        ({"axis": '<axis xyz="0 1"/>'}, r"joint 'elbow': <axis>: xyz='0 1'"),
        ({"parent": "ghost"}, r"joint 'elbow': parent link 'ghost' does not exist"),
        ({"elbow_type": "prismatic"}, r"joint 'elbow': type 'prismatic' is not supported"),
        ({"elbow_type": "floating"}, r"joint 'elbow': type 'floating'"),
        ({"elbow_type": "planar"}, r"joint 'elbow': type 'planar'"),
        ({"inertial": "<inertial/>"}, r"link 'lower': <inertial>: <mass> is missing"),
        ({"extra": '<link name="stray"/>'}, r"root link: .*\['base', 'stray'\]; give base_link"),
        (
            {
                "extra": '<link name="cam"/><joint name="c" type="fixed"><parent link="upper"/>'
                '<child link="cam"/></joint>'
            },
            r"tip link below 'base': .*\['cam', 'tip'\]; give tip_link",
        ),
    ],
)
def test_errors_name_the_element(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        arm_from_urdf_string(_urdf(**kwargs))


def test_errors_on_links_and_files(tmp_path):
    with pytest.raises(ConfigError, match=r"base link 'nope' does not exist"):
        arm_from_urdf_string(_urdf(), base_link="nope")
    with pytest.raises(ConfigError, match=r"tip link 'nope' does not exist"):
        arm_from_urdf_string(_urdf(), tip_link="nope")
    with pytest.raises(ConfigError, match=r"tip link 'base' is not below base link 'upper'"):
        arm_from_urdf_string(_urdf(), base_link="upper", tip_link="base")
    with pytest.raises(ConfigError, match=r"no revolute joint between 'lower' and 'tip'"):
        arm_from_urdf_string(_urdf(), base_link="lower")
    with pytest.raises(ConfigError, match=r"nope\.urdf: file not found"):
        arm_from_urdf(tmp_path / "nope.urdf")
    bad = tmp_path / "bad.urdf"
    bad.write_text("<robot><link name='a'></robot>")
    with pytest.raises(ConfigError, match=r"bad\.urdf: malformed XML"):
        arm_from_urdf(bad)
    with pytest.raises(ConfigError, match=r"arm\.urdf: root element is <sdf>"):
        arm_from_urdf_string("<sdf/>", source="arm.urdf")


def test_names_reserved_by_the_export_are_refused_when_the_robot_is_built():
    spec = load_robot("planar-2dof")
    with pytest.raises(ConfigError, match=r"link\.name: name 'arm_mount_link' is reserved"):
        replace(spec, joints=(replace(spec.joints[0], link_name="arm_mount_link"), spec.joints[1]))


# --- example ----------------------------------------------------------------------------


def test_example_robot_from_urdf():
    spec = load_robot(ROOT / "examples" / "robots" / "urdf-arm.toml")
    assert isinstance(spec, RobotSpec)
    assert [j.name for j in spec.joints] == ["pan", "shoulder", "elbow"]
    assert all(isinstance(j, Joint) for j in spec.joints)
    arm = arm_from_urdf(
        ROOT / "examples" / "robots" / "urdf-arm.urdf", base_link="arm_base", tip_link="gripper_tip"
    )
    assert (spec.ee_xyz, spec.ee_rpy) == (arm.ee_xyz, arm.ee_rpy)
    assert spec.arm_mass > 0.2


def test_robot_toml_with_missing_urdf_names_the_file(tmp_path):
    toml = tmp_path / "r.toml"
    toml.write_text('name = "r"\n[platform]\ndofs = ["z"]\n[arm]\nurdf = "missing.urdf"\n')
    with pytest.raises(ConfigError, match=r"missing\.urdf: file not found"):
        load_robot(toml)
