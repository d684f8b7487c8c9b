"""Robot description: the platform, the arm chain mounted below it, the end effector.

Conventions (see DESIGN.md): SI units and radians; world ENU, body FLU. The arm is a
chain of revolute joints described URDF-style: joint ``i`` has its origin (xyz, rpy)
in the frame of its parent (the mount frame for the first joint, link ``i-1``
otherwise), an axis in its own frame, and moves link ``i``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from aeromanip.errors import ConfigError

PLATFORM_DOFS: tuple[str, ...] = ("x", "y", "z", "yaw")
"""Every platform DoF the NMPC may control, in state order."""

Vec3 = tuple[float, float, float]
MAX_PLATFORM_MASS = 1e4  # [kg]
MAX_LINK_MASS = 1e3  # [kg]
MAX_INERTIA = 1e4  # [kg m^2] per entry
# principal moments may miss the triangle inequality by this share of the largest one:
# hand-written and CAD-exported inertias round (the MJCF balances what is left)
INERTIA_SLACK = 0.01
MOUNT_LINK = "arm_mount_link"  # the link the first arm joint hangs from, in exports


@dataclass(frozen=True)
class Inertial:
    """Mass [kg], centre of mass [m] in the link frame and inertia [kg m^2] about the CoM.

    ``inertia`` is ``(ixx, iyy, izz, ixy, ixz, iyz)`` in the link frame.
    """

    mass: float
    com: Vec3 = (0.0, 0.0, 0.0)
    inertia: tuple[float, float, float, float, float, float] = (1e-5, 1e-5, 1e-5, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Joint:
    """A revolute arm joint and the link it moves.

    Attributes:
        name: joint name (unique).
        xyz, rpy: joint origin in the parent frame [m, rad] (URDF convention, fixed-axis XYZ).
        axis: rotation axis in the joint frame (unit vector).
        lower, upper: position limits [rad].
        velocity: velocity limit [rad/s] (> 0).
        link_name: name of the child link.
        link: the child link's inertial properties.
    """

    name: str
    xyz: Vec3
    rpy: Vec3
    axis: Vec3
    lower: float
    upper: float
    velocity: float
    link_name: str
    link: Inertial


@dataclass(frozen=True)
class Platform:
    """The multirotor: which DoFs the NMPC controls, the fixed values of the others, its body.

    Attributes:
        dofs: active DoFs, an ordered subset of ``("x", "y", "z", "yaw")``.
        fixed: value of every inactive DoF [m or rad] (default 0).
        mass: platform mass without the arm [kg].
        inertia: principal inertia ``(ixx, iyy, izz)`` about the platform CoM [kg m^2].
        arm_length: distance from the centre to each rotor [m] (used by physics).
        rotors: number of rotors (physics); coaxial: rotors in stacked pairs, two per arm
            (e.g. the 3DR X8: 8 rotors on 4 arms).
        velocity: speed limit per DoF [m/s or rad/s]; DoFs not named here are limited to 1.
    """

    dofs: tuple[str, ...]
    fixed: Mapping[str, float] = field(default_factory=dict)
    mass: float = 2.0
    inertia: Vec3 = (0.03, 0.03, 0.05)
    arm_length: float = 0.3
    velocity: Mapping[str, float] = field(default_factory=dict)
    rotors: int = 4
    coaxial: bool = False

    def velocity_limit(self, dof: str) -> float:
        """Speed limit of one platform DoF [m/s or rad/s]."""
        return float(self.velocity.get(dof, 1.0))


@dataclass(frozen=True)
class RobotSpec:
    """A UAM: platform + arm mounted at ``mount_xyz/rpy`` in the body frame + end-effector frame.

    The end-effector frame is fixed in the last link's frame at ``ee_xyz/ee_rpy``.
    """

    name: str
    platform: Platform
    joints: tuple[Joint, ...]
    mount_xyz: Vec3 = (0.0, 0.0, 0.0)
    mount_rpy: Vec3 = (0.0, 0.0, 0.0)
    ee_xyz: Vec3 = (0.0, 0.0, 0.0)
    ee_rpy: Vec3 = (0.0, 0.0, 0.0)
    base_link: str = "base_link"
    ee_link: str = "end_effector"

    def __post_init__(self) -> None:
        validate(self)

    @property
    def n_platform(self) -> int:
        """Number of active platform DoFs."""
        return len(self.platform.dofs)

    @property
    def n_joints(self) -> int:
        """Number of arm joints."""
        return len(self.joints)

    @property
    def nx(self) -> int:
        """NMPC state size: active platform DoFs + arm joints."""
        return self.n_platform + self.n_joints

    @property
    def state_names(self) -> tuple[str, ...]:
        """Names of the state entries, e.g. ``("x", "y", "z", "yaw", "q1", "q2", "q3")``."""
        return self.platform.dofs + tuple(f"q{i + 1}" for i in range(self.n_joints))

    @property
    def arm_mass(self) -> float:
        """Total arm mass [kg]."""
        return sum(j.link.mass for j in self.joints)


_FRAME_KEYS = {
    "mount_xyz": "mount.xyz",
    "mount_rpy": "mount.rpy",
    "ee_xyz": "end_effector.xyz",
    "ee_rpy": "end_effector.rpy",
}
"""Spec attributes of the fixed frames -> their key paths in a robot TOML."""


def _finite(value: float, path: str) -> None:
    if not math.isfinite(value):
        raise ConfigError(f"{path}: must be a finite number, got {value!r}")


def _vec(value: Sequence[float], path: str) -> None:
    if len(value) != 3:
        raise ConfigError(f"{path}: must have 3 entries, got {len(value)}")
    for i, v in enumerate(value):
        _finite(v, f"{path}[{i}]")


def validate(spec: RobotSpec) -> None:
    """Check a spec; raise ``ConfigError`` naming the key path of the first problem.

    Key paths are those of the robot TOML format (``joints[1].axis``, ``end_effector.xyz``),
    relative to the robot table; ``robot_from_table`` adds the table's prefix and file.
    """
    _validate_platform(spec.platform)
    if not spec.joints:
        raise ConfigError("joints: the arm needs at least one joint")
    for attr, key in _FRAME_KEYS.items():
        _vec(getattr(spec, attr), key)
    names: set[str] = set()  # links and joints share one namespace (TF frames, MJCF)
    for key, nm in (("base_link", spec.base_link), ("end_effector.name", spec.ee_link)):
        _new_name(nm, key, names, spec)
    for i, j in enumerate(spec.joints):
        p = f"joints[{i}]"
        _validate_joint(j, p)
        _new_name(j.name, f"{p}.name", names, spec)
        _new_name(j.link_name, f"{p}.link.name", names, spec)
    if spec.arm_mass <= 0:
        raise ConfigError("joints[*].link.mass: the arm must have a positive total mass")


def _new_name(name: str, key: str, seen: set[str], spec: RobotSpec) -> None:
    """A link or joint name: non-empty, unused, not reserved by the URDF export."""
    if not name:
        raise ConfigError(f"{key}: must be a non-empty string")
    if name in seen:
        raise ConfigError(f"{key}: name {name!r} is used twice (links and joints included)")
    if name in reserved_names(spec.ee_link):
        raise ConfigError(f"{key}: name {name!r} is reserved by the URDF export")
    seen.add(name)


def reserved_names(ee_link: str) -> set[str]:
    """Link and joint names the URDF export adds to a robot's own."""
    out = {MOUNT_LINK, "arm_mount", f"{ee_link}_joint", "platform_fixed", "world"}
    return out | {f"platform_{d}{s}" for d in PLATFORM_DOFS for s in ("", "_link")}


def _validate_platform(pf: Platform) -> None:
    """The ``[platform]`` table: DoFs, fixed values, velocities, mass, inertia, rotors."""
    dofs = pf.dofs
    for i, d in enumerate(dofs):
        if d not in PLATFORM_DOFS:
            raise ConfigError(
                f"platform.dofs[{i}]: unknown platform DoF {d!r} (choose from {PLATFORM_DOFS})"
            )
    if list(dofs) != [d for d in PLATFORM_DOFS if d in dofs]:
        raise ConfigError(f"platform.dofs: must be unique and in the order {PLATFORM_DOFS}")
    for k, v in pf.fixed.items():
        if k not in PLATFORM_DOFS:
            raise ConfigError(f"platform.fixed.{k}: unknown platform DoF")
        if k in dofs:
            raise ConfigError(f"platform.fixed.{k}: DoF is active, it cannot also be fixed")
        _finite(v, f"platform.fixed.{k}")
    for k, v in pf.velocity.items():
        if k not in PLATFORM_DOFS:
            raise ConfigError(f"platform.velocity.{k}: unknown platform DoF")
        if not (v > 0 and math.isfinite(v)):
            raise ConfigError(f"platform.velocity.{k}: must be a finite number > 0, got {v}")
    if not 0 < pf.mass <= MAX_PLATFORM_MASS:
        raise ConfigError(f"platform.mass: must be in (0, {MAX_PLATFORM_MASS:g}] kg, got {pf.mass}")
    _vec(pf.inertia, "platform.inertia")
    if min(pf.inertia) <= 0:
        raise ConfigError("platform.inertia: every entry must be > 0")
    _physical_inertia((*pf.inertia, 0.0, 0.0, 0.0), "platform.inertia")
    if not pf.arm_length > 0:
        raise ConfigError(f"platform.arm_length: must be > 0, got {pf.arm_length}")
    n = pf.rotors
    if isinstance(n, bool) or not isinstance(n, int) or n < 4 or n % 2:
        raise ConfigError(f"platform.rotors: must be an even integer >= 4, got {n!r}")
    if pf.coaxial and (n % 4 or n < 8):
        raise ConfigError(f"platform.rotors: coaxial pairs need a multiple of 4, >= 8, got {n}")


def _validate_joint(j: Joint, p: str) -> None:
    """One ``[[joints]]`` entry (key path ``p``): frames, axis, limits, link inertia."""
    for key in ("xyz", "rpy", "axis"):
        _vec(getattr(j, key), f"{p}.{key}")
    norm = math.sqrt(sum(a * a for a in j.axis))
    if norm < 1e-9:
        raise ConfigError(f"{p}.axis: must be non-zero, got {list(j.axis)}")
    if abs(norm - 1.0) > 1e-6:
        raise ConfigError(f"{p}.axis: must be a unit vector, got norm {norm:.6g}")
    if math.isnan(j.lower) or math.isnan(j.upper):
        raise ConfigError(f"{p}.limits: must be numbers")
    if j.lower > j.upper:
        raise ConfigError(f"{p}.limits: lower {j.lower} is above upper {j.upper}")
    if not (j.velocity > 0 and math.isfinite(j.velocity)):
        raise ConfigError(f"{p}.velocity: must be a finite number > 0, got {j.velocity}")
    if not 0 <= j.link.mass <= MAX_LINK_MASS:
        raise ConfigError(f"{p}.link.mass: must be in [0, {MAX_LINK_MASS:g}] kg, got {j.link.mass}")
    _vec(j.link.com, f"{p}.link.com")
    if len(j.link.inertia) != 6:
        raise ConfigError(f"{p}.link.inertia: must be [ixx, iyy, izz, ixy, ixz, iyz]")
    if min(j.link.inertia[:3]) < 0:
        raise ConfigError(f"{p}.link.inertia: diagonal entries must be >= 0")
    _physical_inertia(j.link.inertia, f"{p}.link.inertia")


def _physical_inertia(ii: Sequence[float], key: str) -> None:
    """Finite, positive semi-definite, principal moments obeying the triangle inequality
    (``I1 + I2 >= I3``: what any mass distribution gives)."""
    for k, v in enumerate(ii):
        _finite(v, f"{key}[{k}]")
        if abs(v) > MAX_INERTIA:
            raise ConfigError(f"{key}[{k}]: must be within +-{MAX_INERTIA:g} kg m^2, got {v!r}")
    ixx, iyy, izz, ixy, ixz, iyz = ii
    m = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    lam = np.linalg.eigvalsh(m)
    tol = 1e-9 * max(float(np.abs(lam).max()), 1e-12)
    if lam[0] < -tol:
        raise ConfigError(f"{key}: not positive semi-definite (principal moments {lam.tolist()})")
    if lam[0] + lam[1] < (1.0 - INERTIA_SLACK) * lam[2] - tol:
        raise ConfigError(
            f"{key}: principal moments {lam.tolist()} break the triangle inequality "
            "I1 + I2 >= I3 (no mass distribution has them)"
        )
