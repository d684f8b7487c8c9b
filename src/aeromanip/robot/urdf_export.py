"""URDF export: a whole ``RobotSpec`` -> URDF text, loadable by standard URDF tools.

Export writes ``base_link`` (the platform) -> fixed ``arm_mount`` -> ``arm_mount_link`` -> the
arm joints -> fixed ``<ee_link>_joint`` -> ``ee_link``, so that
``arm_from_urdf_string(robot_to_urdf(spec), "arm_mount_link", spec.ee_link)`` gives back
``spec.joints`` and the end-effector frame exactly. The platform DoFs are virtual joints
(prismatic x, y, z and revolute yaw) for tools that need a fixed root.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.robot.spec import (
    MOUNT_LINK,
    PLATFORM_DOFS,
    Inertial,
    RobotSpec,
    Vec3,
    reserved_names,
)
from aeromanip.robot.urdf import matrix_to_rpy

_ZERO3: Vec3 = (0.0, 0.0, 0.0)

VIRTUAL_MASS = 1e-3  # [kg] virtual links between platform joints (importers need mass > 0)
VIRTUAL_INERTIA = 1e-6  # [kg m^2] their principal inertia
VIRTUAL_LIMIT = 1e3  # [m] position limit of the virtual prismatic platform joints
HALF_OPEN_LIMIT = 1e9  # [rad] a one-sided infinite arm joint limit is exported as this


def _fmt(*values: float) -> str:
    return " ".join(repr(float(v) + 0.0) for v in values)  # repr: exact round trip, no -0.0


def _sub(parent: ET.Element, tag: str, **attrs: str) -> ET.Element:
    return ET.SubElement(parent, tag, attrs)


def _joint_el(
    robot: ET.Element,
    name: str,
    kind: str,
    parent: str,
    child: str,
    origin: tuple[Vec3, Vec3] = (_ZERO3, _ZERO3),
    axis: Vec3 | None = None,
    **limit: str,
) -> None:
    el = _sub(robot, "joint", name=name, type=kind)
    _sub(el, "origin", xyz=_fmt(*origin[0]), rpy=_fmt(*origin[1]))
    _sub(el, "parent", link=parent)
    _sub(el, "child", link=child)
    if axis is not None:
        _sub(el, "axis", xyz=_fmt(*axis))
        _sub(el, "limit", **limit)


def _link_el(robot: ET.Element, name: str, link: Inertial | None = None) -> ET.Element:
    el = _sub(robot, "link", name=name)
    if link is not None:
        inertial = _sub(el, "inertial")
        _sub(inertial, "origin", xyz=_fmt(*link.com), rpy="0 0 0")
        _sub(inertial, "mass", value=_fmt(link.mass))
        keys = ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")
        _sub(inertial, "inertia", **{k: _fmt(v) for k, v in zip(keys, link.inertia, strict=True)})
    return el


def _visual(link: ET.Element, d: Vec3 | None, box: tuple[float, ...] = ()) -> None:
    """A box, or a cylinder from the link origin to ``d`` [m] (a sphere if ``d`` is ~0)."""
    vis, n = _sub(link, "visual"), float(np.linalg.norm(d or _ZERO3))
    R, geometry = np.eye(3), {"sphere": {"radius": "0.018"}}
    if box:
        geometry = {"box": {"size": _fmt(*box)}}
    elif n > 1e-9:
        z = np.array(d) / n
        a = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        x = (a - (a @ z) * z) / np.linalg.norm(a - (a @ z) * z)
        R, geometry = (
            np.column_stack([x, np.cross(z, x), z]),
            {"cylinder": {"radius": "0.012", "length": _fmt(n)}},
        )
    _sub(vis, "origin", xyz=_fmt(*(np.array(d or _ZERO3) / 2)), rpy=_fmt(*matrix_to_rpy(R)))
    for tag, attrs in geometry.items():
        _sub(_sub(vis, "geometry"), tag, **attrs)
    _sub(vis, "material", name="aeromanip_grey")


def robot_to_urdf(
    spec: RobotSpec, *, platform_joints: bool = False, mujoco_compiler: bool = False
) -> str:
    """URDF text of the whole robot (platform ``base_link`` + arm + end-effector link).

    With ``platform_joints`` the chain starts at a ``world`` link with one virtual joint per
    active platform DoF (x, y, z prismatic along world axes, yaw continuous about z; virtual
    links of ``VIRTUAL_MASS``/``VIRTUAL_INERTIA``), so the joint positions are the NMPC state;
    inactive DoFs are constant offsets (``spec.platform.fixed``). The base pose is
    ``Trans(x, y, z) Rz(yaw)``. ``mujoco_compiler`` adds MuJoCo's ``<mujoco><compiler>``
    extension (keep every link as a body, discard visuals), ignored by other URDF tools.
    Arm joints get ``effort="10"`` [N m] (URDF requires one; aeromanip does not use it).
    """
    ours = reserved_names(spec.ee_link)
    clash = sorted(
        ours
        & {spec.base_link, spec.ee_link, *(n for j in spec.joints for n in (j.name, j.link_name))}
    )
    if clash:
        raise ConfigError(f"robot {spec.name!r}: names {clash} are reserved by the URDF export")
    robot = ET.Element("robot", name=spec.name)
    if mujoco_compiler:
        attrs = {"discardvisual": "true", "fusestatic": "false", "balanceinertia": "true"}
        _sub(_sub(robot, "mujoco"), "compiler", **attrs)
    _sub(_sub(robot, "material", name="aeromanip_grey"), "color", rgba="0.6 0.6 0.65 1")
    if platform_joints:
        _platform_chain(robot, spec)
    pf = spec.platform
    base = _link_el(robot, spec.base_link, Inertial(pf.mass, _ZERO3, (*pf.inertia, 0, 0, 0)))
    _visual(base, None, box=(1.4 * pf.arm_length, 1.4 * pf.arm_length, 0.05))
    _joint_el(
        robot, "arm_mount", "fixed", spec.base_link, MOUNT_LINK, (spec.mount_xyz, spec.mount_rpy)
    )
    _link_el(robot, MOUNT_LINK)
    parent = MOUNT_LINK
    for i, j in enumerate(spec.joints):
        limit = {"velocity": _fmt(j.velocity), "effort": "10"}
        kind = "continuous"
        if not (math.isinf(j.lower) and math.isinf(j.upper)):
            kind = "revolute"
            limit |= {
                "lower": _fmt(max(j.lower, -HALF_OPEN_LIMIT)),
                "upper": _fmt(min(j.upper, HALF_OPEN_LIMIT)),
            }
        _joint_el(robot, j.name, kind, parent, j.link_name, (j.xyz, j.rpy), j.axis, **limit)
        nxt = spec.joints[i + 1].xyz if i + 1 < spec.n_joints else spec.ee_xyz
        _visual(_link_el(robot, j.link_name, j.link), nxt)
        parent = j.link_name
    _joint_el(
        robot, f"{spec.ee_link}_joint", "fixed", parent, spec.ee_link, (spec.ee_xyz, spec.ee_rpy)
    )
    _visual(_link_el(robot, spec.ee_link), _ZERO3)
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def _platform_chain(robot: ET.Element, spec: RobotSpec) -> None:
    """``world`` -> one virtual joint per active platform DoF -> ``spec.base_link``."""
    pf = spec.platform
    fixed = {d: float(pf.fixed.get(d, 0.0)) for d in PLATFORM_DOFS if d not in pf.dofs}
    offset: Vec3 = (fixed.get("x", 0.0), fixed.get("y", 0.0), fixed.get("z", 0.0))
    yaw0 = fixed.get("yaw", 0.0)
    c, s = math.cos(yaw0), math.sin(yaw0)
    # every joint frame carries the constant yaw, so world axes are rotated by -yaw0 into it
    axes = {"x": (c, -s, 0.0), "y": (s, c, 0.0), "z": (0.0, 0.0, 1.0), "yaw": (0.0, 0.0, 1.0)}
    _link_el(robot, "world")
    parent, origin = "world", (offset, (0.0, 0.0, yaw0))
    if not pf.dofs:
        _joint_el(robot, "platform_fixed", "fixed", parent, spec.base_link, origin)
    virtual = Inertial(VIRTUAL_MASS, _ZERO3, (VIRTUAL_INERTIA,) * 3 + (0.0,) * 3)
    for k, d in enumerate(pf.dofs):
        child = spec.base_link if k == len(pf.dofs) - 1 else f"platform_{d}_link"
        limit = {"velocity": "10.0", "effort": "10000.0"}
        if d != "yaw":
            limit |= {"lower": _fmt(-VIRTUAL_LIMIT), "upper": _fmt(VIRTUAL_LIMIT)}
        kind = "continuous" if d == "yaw" else "prismatic"
        _joint_el(robot, f"platform_{d}", kind, parent, child, origin, axes[d], **limit)
        if child != spec.base_link:
            _link_el(robot, child, virtual)
        parent, origin = child, (_ZERO3, _ZERO3)
