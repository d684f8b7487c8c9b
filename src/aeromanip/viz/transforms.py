"""The robot's frames along a run: world -> platform base -> every URDF link, per logged row.

The tree is read from the run's ``robot.urdf`` (what Foxglove draws), so the transforms are
named as its links: ``world`` -> ``<base_link>`` (the logged platform pose) -> the URDF
joints' children (fixed joints: their origin; revolute/continuous: origin then rotation
``q_i`` about the axis, the ``i``-th movable joint taking log column ``q<i>``).
Quaternions are ``(w, x, y, z)`` arrays, one row per logged step.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.viz.runs import Trajectory

WORLD = "world"
MOVABLE = ("revolute", "continuous")


def quat_from_rpy(rpy: np.ndarray) -> np.ndarray:
    """Quaternions (N, 4) of ``R = Rz(yaw) Ry(pitch) Rx(roll)`` for rows ``rpy`` (N, 3)."""
    rpy = np.atleast_2d(np.asarray(rpy, dtype=float))
    cr, sr = np.cos(rpy[:, 0] / 2), np.sin(rpy[:, 0] / 2)
    cp, sp = np.cos(rpy[:, 1] / 2), np.sin(rpy[:, 1] / 2)
    cy, sy = np.cos(rpy[:, 2] / 2), np.sin(rpy[:, 2] / 2)
    return np.stack(
        [
            cy * cp * cr + sy * sp * sr,
            cy * cp * sr - sy * sp * cr,
            cy * sp * cr + sy * cp * sr,
            sy * cp * cr - cy * sp * sr,
        ],
        axis=1,
    )


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise Hamilton products ``a b`` of quaternions (N, 4) or (4,)."""
    a, b = np.atleast_2d(a), np.atleast_2d(b)
    aw, ax, ay, az = a[:, 0], a[:, 1], a[:, 2], a[:, 3]
    bw, bx, by, bz = b[:, 0], b[:, 1], b[:, 2], b[:, 3]
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=1,
    )


def quat_axis_angle(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Quaternions (N, 4) of rotations by ``angles`` (N,) [rad] about the unit ``axis``."""
    half = np.asarray(angles, dtype=float) / 2
    return np.column_stack([np.cos(half), np.outer(np.sin(half), axis)])


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectors ``v`` (N, 3) rotated by quaternions ``q`` (N, 4), row by row."""
    w, u = q[:, :1], q[:, 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


@dataclass(frozen=True)
class UrdfJoint:
    """One URDF joint: its kind, the links it joins, its origin and axis."""

    name: str
    kind: str
    parent: str
    child: str
    xyz: np.ndarray
    quat: np.ndarray
    axis: np.ndarray


@dataclass(frozen=True)
class Transform:
    """``parent`` -> ``child`` per row: translation (N, 3) [m], rotation (N, 4) (w, x, y, z)."""

    parent: str
    child: str
    translation: np.ndarray
    rotation: np.ndarray


def _vector(el: ET.Element | None, attr: str, default: str, where: str) -> np.ndarray:
    text = default if el is None else el.get(attr, default)
    try:
        v = np.array([float(s) for s in text.split()])
    except ValueError:
        v = np.array([])
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ConfigError(f"{where}: {attr}: expected 3 numbers, got {text!r}")
    return v


def read_joints(urdf: str, source: str = "robot.urdf") -> list[UrdfJoint]:
    """The joints of a URDF text, in document order (``ConfigError`` if malformed)."""
    try:
        root = ET.fromstring(urdf)
    except ET.ParseError as e:
        raise ConfigError(f"{source}: malformed URDF: {e}") from None
    joints = []
    for el in root.iter("joint"):
        name, kind = el.get("name", "?"), el.get("type", "")
        where = f"{source}: joint {name!r}"
        if kind not in (*MOVABLE, "fixed"):
            raise ConfigError(f"{where}: type {kind!r} (allowed: revolute, continuous, fixed)")
        parent, child = el.find("parent"), el.find("child")
        if parent is None or child is None or not parent.get("link") or not child.get("link"):
            raise ConfigError(f"{where}: needs <parent link=...> and <child link=...>")
        origin = el.find("origin")
        axis = _vector(el.find("axis"), "xyz", "1 0 0", where)
        if kind in MOVABLE and np.linalg.norm(axis) < 1e-12:
            raise ConfigError(f"{where}: axis is zero")
        joints.append(
            UrdfJoint(
                name,
                kind,
                parent.get("link", ""),
                child.get("link", ""),
                _vector(origin, "xyz", "0 0 0", where),
                quat_from_rpy(_vector(origin, "rpy", "0 0 0", where))[0],
                axis / max(np.linalg.norm(axis), 1e-300),
            )
        )
    return joints


class FrameTree:
    """The transforms of a run's robot (module docstring), from its URDF text."""

    def __init__(self, urdf: str, source: str = "robot.urdf") -> None:
        self.joints = read_joints(urdf, source)
        children = {j.child for j in self.joints}
        roots = sorted({j.parent for j in self.joints} - children)
        if len(roots) != 1 or len(children) != len(self.joints):
            raise ConfigError(f"{source}: expected a tree of joints with one root, got {roots}")
        self.base = roots[0]
        self.movable = [j for j in self.joints if j.kind in MOVABLE]
        self.source = source

    @property
    def joint_names(self) -> list[str]:
        """Names of the movable joints, in the order of the log's ``q1..qn``."""
        return [j.name for j in self.movable]

    @property
    def tip(self) -> str:
        """The end-effector link: the leaf farthest (in joints) from the base."""
        parent = {j.child: j.parent for j in self.joints}
        depth = {}
        for link in parent:
            d, x = 0, link
            while x in parent:
                d, x = d + 1, parent[x]
            depth[link] = d
        return max(depth, key=lambda k: depth[k]) if depth else self.base

    def chain(self, link: str) -> list[str]:
        """The frames from ``world`` down to ``link``."""
        parent = {j.child: j.parent for j in self.joints} | {self.base: WORLD}
        out = [link]
        while out[-1] in parent:
            out.append(parent[out[-1]])
        return out[::-1]

    def transforms(self, traj: Trajectory) -> list[Transform]:
        """``world -> base`` and every joint's ``parent -> child``, one row per log row."""
        n, nq = len(traj), traj.q.shape[1]
        if nq != len(self.movable):
            raise ConfigError(
                f"{self.source}: {len(self.movable)} movable joints, but the log has {nq} (q1..)"
            )
        out = [Transform(WORLD, self.base, traj.pos.copy(), quat_from_rpy(traj.rpy))]
        index = {j.name: i for i, j in enumerate(self.movable)}
        for j in self.joints:
            rot = np.tile(j.quat, (n, 1))
            if j.kind in MOVABLE:
                rot = quat_mul(rot, quat_axis_angle(j.axis, traj.q[:, index[j.name]]))
            out.append(Transform(j.parent, j.child, np.tile(j.xyz, (n, 1)), rot))
        return out

    def positions(self, traj: Trajectory, link: str | None = None) -> np.ndarray:
        """World positions (N, 3) [m] of ``link`` (default: ``tip``) along ``traj``."""
        by_child = {tf.child: tf for tf in self.transforms(traj)}
        pos, rot = np.zeros((len(traj), 3)), np.tile([1.0, 0.0, 0.0, 0.0], (len(traj), 1))
        for frame in self.chain(link or self.tip)[1:]:
            tf = by_child[frame]
            pos = pos + quat_rotate(rot, tf.translation)
            rot = quat_mul(rot, tf.rotation)
        return pos
