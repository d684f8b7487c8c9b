"""URDF import (an arm chain -> ``Joint``s) and export (a whole ``RobotSpec`` -> URDF text).

Import walks the chain from a base link to a tip link. Revolute and continuous joints become
``Joint``s; fixed joints are folded away: a fixed transform is composed into the next moving
joint's origin (or, after the last one, into the end-effector frame) and the inertial of every
link rigidly attached to a moving link (through fixed joints, on or off the chain) is merged
into that link. Off-chain branches through moving joints (e.g. gripper fingers) are merged
rigidly at joint position 0. Links rigidly attached to the base (before the first moving
joint) belong to the platform: their mass is ignored. Prismatic, floating and planar joints on
the chain are rejected.

Export writes ``base_link`` (the platform) -> fixed ``arm_mount`` -> ``arm_mount_link`` -> the
arm joints -> fixed ``<ee_link>_joint`` -> ``ee_link``, so that
``arm_from_urdf_string(robot_to_urdf(spec), "arm_mount_link", spec.ee_link)`` gives back
``spec.joints`` and the end-effector frame exactly.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.robot.spec import PLATFORM_DOFS, Inertial, Joint, RobotSpec, Vec3

MOUNT_LINK = "arm_mount_link"  # exported link the first arm joint hangs from
VIRTUAL_MASS = 1e-3  # [kg] virtual links between platform joints (importers need mass > 0)
VIRTUAL_INERTIA = 1e-6  # [kg m^2] their principal inertia
VIRTUAL_LIMIT = 1e3  # [m] position limit of the virtual prismatic platform joints
HALF_OPEN_LIMIT = 1e9  # [rad] a one-sided infinite arm joint limit is exported as this

_ZERO3: Vec3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class UrdfArm:
    """An arm read from URDF: its joints base to tip and the end-effector frame.

    ``ee_xyz``/``ee_rpy`` [m, rad] place ``tip_link`` in the frame of the last moving link.
    """

    joints: tuple[Joint, ...]
    ee_xyz: Vec3
    ee_rpy: Vec3
    base_link: str
    tip_link: str


# --- rotations (URDF rpy: R = Rz(yaw) Ry(pitch) Rx(roll)) ---------------------------------


def rpy_to_matrix(rpy: tuple[float, float, float]) -> np.ndarray:
    """Rotation matrix of URDF roll-pitch-yaw angles [rad]."""
    cr, sr = math.cos(rpy[0]), math.sin(rpy[0])
    cp, sp = math.cos(rpy[1]), math.sin(rpy[1])
    cy, sy = math.cos(rpy[2]), math.sin(rpy[2])
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def matrix_to_rpy(R: np.ndarray) -> Vec3:
    """URDF roll-pitch-yaw [rad] of a rotation matrix (roll = 0 at pitch = +-pi/2)."""
    c = math.hypot(R[0, 0], R[1, 0])
    pitch = math.atan2(-R[2, 0], c)
    if c < 1e-12:
        return (0.0, pitch, math.atan2(-R[0, 1], R[1, 1]))
    return (math.atan2(R[2, 1], R[2, 2]), pitch, math.atan2(R[1, 0], R[0, 0]))


def _tf(*origins: tuple[Vec3, Vec3]) -> np.ndarray:
    """Homogeneous transform of a chain of (xyz, rpy) origins."""
    T = np.eye(4)
    for xyz, rpy in origins:
        step = np.eye(4)
        step[:3, :3], step[:3, 3] = rpy_to_matrix(rpy), xyz
        T = T @ step
    return T


def _compose(origins: list[tuple[Vec3, Vec3]]) -> tuple[Vec3, Vec3]:
    """xyz/rpy of a chain of origins; a single origin is returned untouched (exact)."""
    if len(origins) <= 1:
        return origins[0] if origins else (_ZERO3, _ZERO3)
    T = _tf(*origins)
    return tuple(float(v) for v in T[:3, 3]), matrix_to_rpy(T[:3, :3])  # type: ignore[return-value]


# --- import -----------------------------------------------------------------------------

Part = tuple[float, np.ndarray, np.ndarray]  # mass [kg], CoM [m], inertia about the CoM


def arm_from_urdf(
    file: str | Path, base_link: str | None = None, tip_link: str | None = None
) -> UrdfArm:
    """Read the arm chain ``base_link`` -> ``tip_link`` of a URDF file (see the module doc)."""
    path = Path(file)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"{path}: cannot read URDF: {e}") from None
    return arm_from_urdf_string(text, base_link, tip_link, source=str(path))


def arm_from_urdf_string(
    text: str, base_link: str | None = None, tip_link: str | None = None, source: str = "<string>"
) -> UrdfArm:
    """Read the arm chain of URDF text; ``base_link`` defaults to the URDF root link and
    ``tip_link`` to the single leaf below it. Errors name ``source`` and the element."""
    tree = _Tree(text, source)
    base = base_link or _single(
        [n for n in tree.links if n not in tree.parent], f"{source}: root link", "base_link"
    )
    if base not in tree.links:
        raise ConfigError(f"{source}: base link {base!r} does not exist")
    tip = tip_link or _single(tree.leaves(base), f"{source}: tip link below {base!r}", "tip_link")
    if tip not in tree.links:
        raise ConfigError(f"{source}: tip link {tip!r} does not exist")
    link = tip
    while link != base:
        if link not in tree.parent or len(tree.chain) > len(tree.links):
            raise ConfigError(f"{source}: tip link {tip!r} is not below base link {base!r}")
        tree.chain.insert(0, tree.parent[link])
        link = _end(tree.parent[link], "parent")

    joints: list[Joint] = []
    parts: list[Part] = []  # inertials rigid with the current moving link, in its frame
    pending: list[tuple[Vec3, Vec3]] = []  # fixed origins since the last moving link
    for el in tree.chain:
        where = f"{source}: joint {el.get('name')!r}"
        kind, child, origin = el.get("type"), _end(el, "child"), _origin(el, where)
        if kind == "fixed":
            pending.append(origin)
            if joints:
                tree.rigid_parts(child, _tf(*pending), parts)
        elif kind in ("revolute", "continuous"):
            if joints:
                joints[-1] = replace(joints[-1], link=_merge(parts))
            xyz, rpy = _compose([*pending, origin])
            pending, parts = [], []
            joints.append(_moving_joint(el, where, kind, xyz, rpy, child))
            tree.rigid_parts(child, np.eye(4), parts)
        else:
            raise ConfigError(
                f"{where}: type {kind!r} is not supported on the arm chain "
                "(only revolute, continuous and fixed)"
            )
    if not joints:
        raise ConfigError(f"{source}: no revolute joint between {base!r} and {tip!r}")
    joints[-1] = replace(joints[-1], link=_merge(parts))
    return UrdfArm(tuple(joints), *_compose(pending), base, tip)


class _Tree:
    """The links and joints of a URDF document, indexed by link name."""

    def __init__(self, text: str, source: str) -> None:
        try:
            root = ET.fromstring(text)
        except ET.ParseError as e:
            raise ConfigError(f"{source}: malformed XML: {e}") from None
        if root.tag != "robot":
            raise ConfigError(f"{source}: root element is <{root.tag}>, expected <robot>")
        self.source = source
        self.links: dict[str, ET.Element] = {}
        for el in root.findall("link"):
            name = el.get("name")
            if not name or name in self.links:
                raise ConfigError(f"{source}: <link name={name!r}>: missing or duplicate name")
            self.links[name] = el
        self.parent: dict[str, ET.Element] = {}  # link -> joint to its parent
        self.children: dict[str, list[ET.Element]] = {name: [] for name in self.links}
        self.chain: list[ET.Element] = []  # joints from the base to the tip
        for el in root.findall("joint"):
            where = f"{source}: joint {el.get('name')!r}"
            if not el.get("name"):
                raise ConfigError(f"{where}: a <joint> needs a name")
            for role in ("parent", "child"):
                ref = el.find(role)
                link = ref.get("link") if ref is not None else None
                if link not in self.links:
                    raise ConfigError(f"{where}: {role} link {link!r} does not exist")
            child = _end(el, "child")
            if child in self.parent:
                raise ConfigError(f"{where}: link {child!r} already has a parent joint")
            self.parent[child] = el
            self.children[_end(el, "parent")].append(el)

    def leaves(self, base: str) -> list[str]:
        """Links without children below ``base``."""
        out, todo = [], [base]
        while todo:
            kids = [_end(j, "child") for j in self.children[todo.pop()]]
            out += [k for k in kids if not self.children[k]]
            todo += [k for k in kids if self.children[k]]
        return out

    def rigid_parts(self, link: str, T: np.ndarray, out: list[Part]) -> None:
        """Append the inertial of ``link`` (whose frame is ``T`` in the moving frame) and of its
        off-chain subtree (moving joints frozen at 0) to ``out``, in the moving frame."""
        where = f"{self.source}: link {link!r}: <inertial>"
        el = self.links[link].find("inertial")
        if el is not None:
            m_el = el.find("mass")
            if m_el is None:
                raise ConfigError(f"{where}: <mass> is missing")
            mass = _number(m_el, "value", where)
            if mass < 0:
                raise ConfigError(f"{where}: <mass value> must be >= 0, got {mass}")
            xyz, rpy = _origin(el, where)
            i_el = el.find("inertia")
            ixx, iyy, izz, ixy, ixz, iyz = (
                0.0 if i_el is None else _number(i_el, k, where, 0.0)
                for k in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")
            )
            inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
            R = T[:3, :3] @ rpy_to_matrix(rpy)  # inertial frame -> moving frame
            out.append((mass, T[:3, :3] @ np.array(xyz) + T[:3, 3], R @ inertia @ R.T))
        for j in self.children[link]:
            if j not in self.chain:
                sub = T @ _tf(_origin(j, f"{self.source}: joint {j.get('name')!r}"))
                self.rigid_parts(_end(j, "child"), sub, out)


def _single(names: list[str], what: str, option: str) -> str:
    if len(names) != 1:
        raise ConfigError(f"{what}: expected exactly one, found {sorted(names)}; give {option}")
    return names[0]


def _end(joint: ET.Element, role: str) -> str:
    return joint.find(role).get("link")  # type: ignore[union-attr,return-value]


def _floats(el: ET.Element | None, attr: str, default: Vec3, where: str) -> Vec3:
    raw = el.get(attr) if el is not None else None
    if raw is None:
        return default
    try:
        vals = tuple(float(v) for v in raw.split())
    except ValueError:
        vals = ()
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
        raise ConfigError(f"{where}: {attr}={raw!r}: expected 3 finite numbers")
    return vals  # type: ignore[return-value]


def _number(el: ET.Element, attr: str, where: str, default: float | None = None) -> float:
    raw = el.get(attr)
    if raw is None:
        if default is None:
            raise ConfigError(f"{where}: <{el.tag} {attr}> is missing")
        return default
    try:
        value = float(raw)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise ConfigError(f"{where}: <{el.tag} {attr}={raw!r}>: expected a finite number")
    return value


def _origin(el: ET.Element, where: str) -> tuple[Vec3, Vec3]:
    o, at = el.find("origin"), f"{where}: <origin>"
    return _floats(o, "xyz", _ZERO3, at), _floats(o, "rpy", _ZERO3, at)


def _moving_joint(el: ET.Element, where: str, kind: str, xyz: Vec3, rpy: Vec3, child: str) -> Joint:
    axis = np.array(_floats(el.find("axis"), "xyz", (1.0, 0.0, 0.0), f"{where}: <axis>"))
    norm = float(np.linalg.norm(axis))
    if norm < 1e-12:
        raise ConfigError(f"{where}: <axis> is zero")
    limit = el.find("limit")
    if limit is None:
        raise ConfigError(f"{where}: <limit> is missing")
    lower, upper = -math.inf, math.inf
    if kind == "revolute":
        lower, upper = _number(limit, "lower", where, 0.0), _number(limit, "upper", where, 0.0)
        if lower > upper:
            raise ConfigError(f"{where}: <limit> lower {lower} is above upper {upper}")
    velocity = _number(limit, "velocity", where)
    if velocity <= 0:
        raise ConfigError(f"{where}: <limit velocity> must be > 0, got {velocity}")
    axis_t: Vec3 = tuple(float(a) for a in axis / norm)  # type: ignore[assignment]
    return Joint(el.get("name") or "", xyz, rpy, axis_t, lower, upper, velocity, child, Inertial(0))


def _merge(parts: list[Part]) -> Inertial:
    """Sum of rigid parts: total mass, mass-weighted CoM, inertia about it (parallel axes)."""
    if len(parts) == 1:
        m, c, t = parts[0]
    else:
        m = sum(p[0] for p in parts)
        c = sum((p[0] * p[1] for p in parts), np.zeros(3)) / m if m > 0 else np.zeros(3)
        t = np.zeros((3, 3))
        for mi, ci, Ii in parts:
            d = ci - c
            t += Ii + mi * (d @ d * np.eye(3) - np.outer(d, d))
    six = (t[0, 0], t[1, 1], t[2, 2], t[0, 1], t[0, 2], t[1, 2])
    return Inertial(float(m), tuple(float(v) for v in c), tuple(float(v) for v in six))  # type: ignore[arg-type]


# --- export -----------------------------------------------------------------------------


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
    ours = {MOUNT_LINK, "arm_mount", f"{spec.ee_link}_joint", "platform_fixed", "world"}
    ours |= {f"platform_{d}{s}" for d in PLATFORM_DOFS for s in ("", "_link")}
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
