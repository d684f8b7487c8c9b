"""URDF import: an arm chain -> ``Joint``s (export is ``robot.urdf_export``).

Import walks the chain from a base link to a tip link. Revolute and continuous joints become
``Joint``s; fixed joints are folded away: a fixed transform is composed into the next moving
joint's origin (or, after the last one, into the end-effector frame) and the inertial of every
link rigidly attached to a moving link (through fixed joints, on or off the chain) is merged
into that link. Off-chain branches through moving joints (e.g. gripper fingers) are merged
rigidly at joint position 0. Links rigidly attached to the base (before the first moving
joint) belong to the platform: their mass is ignored. Prismatic, floating and planar joints on
the chain are rejected.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.robot.spec import Inertial, Joint, Vec3

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
