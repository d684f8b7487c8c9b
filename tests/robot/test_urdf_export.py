"""Every value of the URDF export, read back and checked against the robot spec.

The export is read with ``xml.etree`` (the URDF format itself), with the project's URDF
importer (the arm chain) and with MuJoCo (its ``<mujoco><compiler>`` extension). Expected
values come from the spec and from the export's documented rules: the arm joints' limits
(``effort="10"``, a one-sided infinite limit written as ``HALF_OPEN_LIMIT``), the virtual
platform chain (one joint per active DoF along the world axes, ``VIRTUAL_*`` links), and
the display geometry (a box of ``1.4 arm_length`` for the platform, a cylinder from each
link's origin to the next joint, a sphere where that distance is zero), hand-computed here.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest

from aeromanip.robot.loader import load_robot
from aeromanip.robot.spec import MOUNT_LINK, PLATFORM_DOFS, Inertial, Joint, Platform, RobotSpec
from aeromanip.robot.urdf import arm_from_urdf_string
from aeromanip.robot.urdf_export import (
    HALF_OPEN_LIMIT,
    VIRTUAL_INERTIA,
    VIRTUAL_LIMIT,
    VIRTUAL_MASS,
    robot_to_urdf,
)

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "robots" / "urdf-arm.toml"
INERTIA_KEYS = ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")
GREY = "aeromanip_grey"


def _joint(name, xyz, lower=-1.0, upper=1.0, axis=(0.0, 0.0, 1.0), rpy=(0.0, 0.0, 0.0)):
    link = Inertial(0.05, (0.01, -0.02, 0.03), (2e-4, 3e-4, 1e-4, 1e-5, -2e-5, 3e-6))
    return Joint(name, xyz, rpy, axis, lower, upper, 1.25, f"{name}_link", link)


def _custom() -> RobotSpec:
    """Links along x, y, -z, a generic direction and of zero length; every kind of limit."""
    joints = (
        _joint("j1", (0.0, 0.0, 0.0), -math.inf, math.inf, rpy=(0.1, -0.2, 0.3)),
        _joint("j2", (0.2, 0.0, 0.0), -math.inf, 1.0, axis=(0.0, 0.6, 0.8)),
        _joint("j3", (0.0, 0.15, 0.0), -1.0, math.inf, axis=(1.0, 0.0, 0.0)),
        _joint("j4", (0.0, 0.0, -0.1)),
        _joint("j5", (0.05, -0.07, 0.11)),
        _joint("j6", (0.0, 0.0, 0.0)),
    )
    return RobotSpec(
        "custom",
        Platform(("x", "z"), {"y": 0.4}, mass=1.7, inertia=(0.02, 0.03, 0.04), arm_length=0.31),
        joints,
        mount_xyz=(0.01, -0.02, -0.05),
        mount_rpy=(0.3, 0.0, -0.4),
        ee_xyz=(0.03, 0.04, -0.12),
        ee_rpy=(0.0, 0.4, -1.1),
    )


def _spec(label: str) -> RobotSpec:
    return _custom() if label == "custom" else load_robot(EXAMPLE if label == "urdf-arm" else label)


LABELS = ["planar-2dof", "x8-3dof", "urdf-arm", "custom"]


# --- reading the URDF --------------------------------------------------------------------


def floats(text: str) -> tuple[float, ...]:
    return tuple(float(v) for v in text.split())


def rot(axis, angle):
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def rpy_matrix(rpy):
    """URDF fixed-axis XYZ: Rz(yaw) Ry(pitch) Rx(roll)."""
    return rot((0, 0, 1), rpy[2]) @ rot((0, 1, 0), rpy[1]) @ rot((1, 0, 0), rpy[0])


class Urdf:
    def __init__(self, text: str) -> None:
        self.root = ET.fromstring(text)
        self.links = {el.get("name"): el for el in self.root.findall("link")}
        self.joints = {el.get("name"): el for el in self.root.findall("joint")}
        assert len(self.links) == len(self.root.findall("link"))  # names unique
        assert len(self.joints) == len(self.root.findall("joint"))

    def origin(self, el) -> tuple[tuple[float, ...], tuple[float, ...]]:
        o = el.find("origin")
        return floats(o.get("xyz")), floats(o.get("rpy"))

    def joint(self, name):
        el = self.joints[name]
        return el.get("type"), el.find("parent").get("link"), el.find("child").get("link")

    def limit(self, name) -> dict[str, float]:
        return {k: float(v) for k, v in self.joints[name].find("limit").attrib.items()}

    def inertial(self, name):
        el = self.links[name].find("inertial")
        if el is None:
            return None
        inertia = el.find("inertia").attrib
        assert set(inertia) == set(INERTIA_KEYS)
        return (
            float(el.find("mass").get("value")),
            self.origin(el),
            tuple(float(inertia[k]) for k in INERTIA_KEYS),
        )

    def visual(self, name):
        """(origin, geometry tag, its attributes as floats) of a link's one visual."""
        (vis,) = self.links[name].findall("visual")
        (geometry,) = vis.findall("geometry")
        (shape,) = list(geometry)
        assert vis.find("material").get("name") == GREY
        return self.origin(vis), shape.tag, {k: floats(v) for k, v in shape.attrib.items()}


# --- links, joints, inertials -----------------------------------------------------------


@pytest.mark.parametrize("label", LABELS)
def test_every_link_joint_and_inertial_matches_the_spec(label):
    spec = _spec(label)
    u = Urdf(robot_to_urdf(spec))
    assert u.root.tag == "robot" and u.root.get("name") == spec.name
    arm_links = [j.link_name for j in spec.joints]
    assert set(u.links) == {spec.base_link, MOUNT_LINK, *arm_links, spec.ee_link}
    assert set(u.joints) == {"arm_mount", *(j.name for j in spec.joints), f"{spec.ee_link}_joint"}
    # platform -> mount (fixed, the spec's mount frame)
    assert u.joint("arm_mount") == ("fixed", spec.base_link, MOUNT_LINK)
    assert u.origin(u.joints["arm_mount"]) == (spec.mount_xyz, spec.mount_rpy)
    parent = MOUNT_LINK
    for j in spec.joints:
        infinite = math.isinf(j.lower) and math.isinf(j.upper)
        kind = "continuous" if infinite else "revolute"
        assert u.joint(j.name) == (kind, parent, j.link_name)
        assert u.origin(u.joints[j.name]) == (j.xyz, j.rpy)
        axis = floats(u.joints[j.name].find("axis").get("xyz"))
        assert axis == j.axis
        limit = {"velocity": j.velocity, "effort": 10.0}
        if not infinite:  # URDF: a revolute joint needs both limits; +-inf is written finite
            lower = max(j.lower, -HALF_OPEN_LIMIT)
            limit |= {"lower": lower, "upper": min(j.upper, HALF_OPEN_LIMIT)}
        assert u.limit(j.name) == limit
        assert u.inertial(j.link_name) == (j.link.mass, (j.link.com, (0.0,) * 3), j.link.inertia)
        parent = j.link_name
    assert u.joint(f"{spec.ee_link}_joint") == ("fixed", parent, spec.ee_link)
    assert u.origin(u.joints[f"{spec.ee_link}_joint"]) == (spec.ee_xyz, spec.ee_rpy)
    # the platform: its mass and principal inertia about its origin; frames are massless
    pf = spec.platform
    assert u.inertial(spec.base_link) == (
        pf.mass,
        ((0.0,) * 3, (0.0,) * 3),
        (*pf.inertia, 0.0, 0.0, 0.0),
    )
    assert u.inertial(MOUNT_LINK) is None and u.inertial(spec.ee_link) is None


def test_half_open_limits_are_written_finite_and_read_back():
    spec = _custom()
    arm = arm_from_urdf_string(robot_to_urdf(spec), base_link=MOUNT_LINK, tip_link=spec.ee_link)
    got = [(j.lower, j.upper) for j in arm.joints]
    assert got[0] == (-math.inf, math.inf)  # continuous
    assert got[1] == (-HALF_OPEN_LIMIT, 1.0)
    assert got[2] == (-1.0, HALF_OPEN_LIMIT)
    assert got[3:] == [(-1.0, 1.0)] * 3
    for a, j in zip(arm.joints, spec.joints, strict=True):
        assert (a.name, a.xyz, a.rpy, a.axis, a.velocity) == (j.name, j.xyz, j.rpy, j.axis, 1.25)
        assert (a.link_name, a.link) == (j.link_name, j.link)
    assert (arm.ee_xyz, arm.ee_rpy) == (spec.ee_xyz, spec.ee_rpy)


def test_negative_zero_is_written_as_zero():
    """``_fmt`` adds ``0.0`` so that ``-0.0`` is written ``0.0`` (a stable, diffable text)."""
    spec = _custom()
    j = replace(spec.joints[3], xyz=(-0.0, 0.0, -0.1), rpy=(-0.0, -0.0, -0.0))
    text = robot_to_urdf(replace(spec, joints=(*spec.joints[:3], j, *spec.joints[4:])))
    assert "-0.0 " not in text and '-0.0"' not in text
    assert 'xyz="0.0 0.0 -0.1"' in text


# --- display geometry ----------------------------------------------------------------------


@pytest.mark.parametrize("label", LABELS)
def test_display_geometry_follows_the_links(label):
    spec = _spec(label)
    u = Urdf(robot_to_urdf(spec))
    L = spec.platform.arm_length
    # the platform: a flat box 1.4 arm_length wide, 5 cm thick, centred on its origin
    box = {"size": (1.4 * L, 1.4 * L, 0.05)}
    assert u.visual(spec.base_link) == (((0.0,) * 3, (0.0,) * 3), "box", box)
    # each arm link: a cylinder from its origin to the next joint (the EE for the last)
    ends = [j.xyz for j in spec.joints[1:]] + [spec.ee_xyz]
    for j, d in zip(spec.joints, ends, strict=True):
        (xyz, rpy), tag, attrs = u.visual(j.link_name)
        n = math.sqrt(sum(c * c for c in d))
        if n == 0.0:
            assert (xyz, rpy, tag, attrs) == (
                (0.0,) * 3,
                (0.0,) * 3,
                "sphere",
                {"radius": (0.018,)},
            )
            continue
        assert (tag, attrs) == ("cylinder", {"radius": (0.012,), "length": (n,)})
        np.testing.assert_allclose(xyz, np.array(d) / 2, rtol=0, atol=1e-15)
        R = rpy_matrix(rpy)  # the cylinder's axis is its local z (URDF)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(R[:, 2], np.array(d) / n, atol=1e-12)
    # the end effector: a small sphere on its frame
    assert u.visual(spec.ee_link) == (((0.0,) * 3, (0.0,) * 3), "sphere", {"radius": (0.018,)})
    assert not u.links[MOUNT_LINK].findall("visual")


def test_the_custom_arm_has_links_along_every_axis():
    """Guards the test above: its robot has links along x, y, -z, tilted and of length 0."""
    spec = _custom()
    ends = [j.xyz for j in spec.joints[1:]] + [spec.ee_xyz]
    units = [np.array(d) / (np.linalg.norm(d) or 1.0) for d in ends]
    for axis in np.eye(3):
        assert any(abs(abs(u @ axis) - 1.0) < 1e-12 for u in units)
    assert any(np.all(np.abs(u) > 0.1) for u in units) and any(not any(d) for d in ends)


@pytest.mark.parametrize("label", LABELS)
def test_the_display_material_is_defined_once(label):
    root = ET.fromstring(robot_to_urdf(_spec(label)))
    (material,) = root.findall("material")  # URDF: visuals name a material defined at top level
    assert material.get("name") == GREY
    rgba = floats(material.find("color").get("rgba"))
    assert len(rgba) == 4 and all(0.0 <= c <= 1.0 for c in rgba) and rgba[3] == 1.0
    names = {m.get("name") for m in root.iter("material") if m is not material}
    assert names == {GREY}


# --- the virtual platform chain --------------------------------------------------------------


def _platform_variants():
    planar, x8 = load_robot("planar-2dof"), load_robot("x8-3dof")
    return {
        "planar": planar,
        "planar-fixed-x-yaw": replace(
            planar, platform=replace(planar.platform, fixed={"x": 0.3, "yaw": 0.7})
        ),
        "x8": x8,
        "xz-defaults": replace(x8, platform=Platform(("x", "z"))),
        "x8-fixed-yaw": replace(x8, platform=Platform(("x", "y", "z"), {"yaw": -1.2})),
        "yaw-only": replace(x8, platform=Platform(("yaw",), {"x": 0.5, "z": 2.0})),
    }


@pytest.mark.parametrize("label", list(_platform_variants()))
def test_platform_chain_one_joint_per_active_dof_along_the_world_axes(label):
    spec = _platform_variants()[label]
    pf = spec.platform
    u = Urdf(robot_to_urdf(spec, platform_joints=True))
    fixed = {d: pf.fixed.get(d, 0.0) for d in PLATFORM_DOFS if d not in pf.dofs}
    yaw0 = fixed.get("yaw", 0.0)
    chain = ["world", *(f"platform_{d}_link" for d in pf.dofs[:-1]), spec.base_link]
    assert u.inertial("world") is None
    for link in chain[1:-1]:
        assert u.inertial(link) == (
            VIRTUAL_MASS,
            ((0.0,) * 3, (0.0,) * 3),
            (VIRTUAL_INERTIA,) * 3 + (0.0,) * 3,
        )
    arm = {"arm_mount", *(j.name for j in spec.joints), f"{spec.ee_link}_joint"}
    assert set(u.joints) - arm == {f"platform_{d}" for d in pf.dofs}
    R0 = rot((0, 0, 1), yaw0)
    world_axis = {"x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1), "yaw": (0, 0, 1)}
    for k, d in enumerate(pf.dofs):
        name = f"platform_{d}"
        kind = "continuous" if d == "yaw" else "prismatic"
        assert u.joint(name) == (kind, chain[k], chain[k + 1])
        first = ((fixed.get("x", 0.0), fixed.get("y", 0.0), fixed.get("z", 0.0)), (0.0, 0.0, yaw0))
        assert u.origin(u.joints[name]) == (first if k == 0 else ((0.0,) * 3, (0.0,) * 3))
        axis = np.array(floats(u.joints[name].find("axis").get("xyz")))
        assert np.linalg.norm(axis) == pytest.approx(1.0, abs=1e-15)  # URDF: a unit vector
        np.testing.assert_allclose(R0 @ axis, world_axis[d], atol=1e-15)
        limit = u.limit(name)
        assert limit["velocity"] > 0 and limit["effort"] > 0
        if d == "yaw":
            assert set(limit) == {"velocity", "effort"}
        else:  # URDF: without lower/upper a prismatic joint is locked at 0
            assert (limit["lower"], limit["upper"]) == (-VIRTUAL_LIMIT, VIRTUAL_LIMIT)
            assert set(limit) == {"velocity", "effort", "lower", "upper"}


def test_platform_without_active_dofs_is_one_fixed_joint():
    x8 = load_robot("x8-3dof")
    spec = replace(x8, platform=Platform((), {"x": 0.1, "y": -0.2, "yaw": 0.5}))
    u = Urdf(robot_to_urdf(spec, platform_joints=True))
    assert u.joint("platform_fixed") == ("fixed", "world", spec.base_link)
    assert u.origin(u.joints["platform_fixed"]) == ((0.1, -0.2, 0.0), (0.0, 0.0, 0.5))
    assert not [n for n in u.joints if n.startswith("platform_") and n != "platform_fixed"]
    assert set(u.links) - {j.link_name for j in spec.joints} == {
        "world",
        spec.base_link,
        MOUNT_LINK,
        spec.ee_link,
    }


# --- MuJoCo's compiler extension --------------------------------------------------------------


def test_mujoco_compiler_extension_keeps_bodies_drops_visuals_and_balances_inertia():
    spec = load_robot("x8-3dof")
    # principal moments 0.5 % short of the triangle inequality: valid for the spec
    # (INERTIA_SLACK), rejected by MuJoCo unless balanceinertia is on
    link = Inertial(0.08, (0.0, 0.0, -0.08), (1e-5, 1e-5, 2.01e-5, 0.0, 0.0, 0.0))
    spec = replace(spec, joints=(*spec.joints[:2], replace(spec.joints[2], link=link)))
    text = robot_to_urdf(spec, platform_joints=True, mujoco_compiler=True)
    (compiler,) = ET.fromstring(text).findall("mujoco/compiler")
    assert compiler.attrib == {
        "discardvisual": "true",
        "fusestatic": "false",
        "balanceinertia": "true",
    }
    model = mujoco.MjModel.from_xml_string(text)
    assert model.ngeom == 0  # visuals discarded
    bodies = {model.body(i).name for i in range(model.nbody)}
    assert {MOUNT_LINK, spec.ee_link, spec.base_link} <= bodies  # static links kept as bodies
    assert "<mujoco" not in robot_to_urdf(spec, platform_joints=True)
    with pytest.raises(ValueError, match=r"(?i)inertia"):  # the same without balanceinertia
        mujoco.MjModel.from_xml_string(text.replace(' balanceinertia="true"', ""))
