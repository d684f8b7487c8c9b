"""Load a ``RobotSpec`` from TOML (a file, a table, or a built-in robot name).

Format (all keys in SI units)::

    name = "my-uam"
    [platform]
    dofs = ["x", "y", "z", "yaw"]      # active subset, in this order
    fixed = { yaw = 0.0 }              # values of inactive DoFs (default 0)
    mass = 2.4                         # kg, without the arm
    inertia = [0.03, 0.03, 0.05]       # kg m^2, principal
    arm_length = 0.3                   # m, centre to rotor
    rotors = 4                         # physics: rotors in an X layout (even, >= 4)
    coaxial = false                    # true: stacked pairs, two per arm (e.g. X8)
    velocity = { x = 1.0, yaw = 0.5 }  # m/s, rad/s speed limits (default 1)
    [mount]                            # arm base in the body frame
    xyz = [0, 0, -0.08]
    rpy = [0, 0, 0]
    [[joints]]                         # one per revolute joint, base to tip
    name = "q1"
    xyz = [0, 0, 0]                    # origin in the parent frame
    rpy = [0, 0, 0]
    axis = [0, 0, 1]
    limits = [-1.57, 1.57]             # rad
    velocity = 1.0                     # rad/s
    link = { name = "link1", mass = 0.1, com = [0, 0, -0.02],
             inertia = [ixx, iyy, izz, ixy, ixz, iyz] }
    [end_effector]                     # fixed in the last link's frame
    xyz = [0, 0, -0.2]
    rpy = [0, 0, 0]

Instead of ``[[joints]]`` an arm may come from a URDF file::

    [arm]
    urdf = "arm.urdf"                  # relative to the TOML file
    base_link = "arm_base"             # optional: the URDF root by default
    tip_link = "gripper"               # optional: the single leaf by default
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from aeromanip.config import Table, builtin_descriptions, load_toml, resolve_toml
from aeromanip.errors import ConfigError
from aeromanip.robot.spec import Inertial, Joint, Platform, RobotSpec

_ZERO3 = (0.0, 0.0, 0.0)


def builtin_robots() -> dict[str, str]:
    """Names of the built-in robots mapped to their one-line description."""
    return builtin_descriptions("aeromanip.robots")


def load_robot(name_or_path: str | Path) -> RobotSpec:
    """Load a built-in robot by name (e.g. ``"x8-3dof"``) or a robot TOML file."""
    path = resolve_toml(name_or_path, "aeromanip.robots", "robot")
    return robot_from_table(load_toml(path), base_dir=path.parent, source=path)


def robot_from_table(
    data: dict[str, Any] | Table,
    base_dir: Path | None = None,
    path: str = "",
    *,
    source: str | Path | None = None,
) -> RobotSpec:
    """Build a spec from a parsed TOML table.

    Every ``ConfigError`` names the full key path (under ``path``, or the ``Table``'s own
    path) and, when ``source`` (the robot's TOML file) is given, starts with that file:
    ``"/path/arm.toml: joints[1].axis: must be non-zero, got [0.0, 0.0, 0.0]"``.
    """
    t = data if isinstance(data, Table) else Table(data, path)
    try:
        return _robot(t, base_dir)
    except ConfigError as e:
        if source is None:
            raise
        raise ConfigError(f"{source}: {e}") from None


def _robot(t: Table, base_dir: Path | None) -> RobotSpec:
    name = t.str("name")
    t.str("description", "")
    pt = t.table("platform")
    dofs = pt.raw("dofs")
    if not isinstance(dofs, list) or not all(isinstance(d, str) for d in dofs):
        raise ConfigError(f"{pt.key('dofs')}: expected an array of strings, got {dofs!r}")
    ft = pt.table("fixed", {})
    fixed = {k: ft.float(k) for k in ft.data}
    vt = pt.table("velocity", {})
    velocity = {k: vt.float(k) for k in vt.data}
    platform = Platform(
        dofs=tuple(dofs),
        fixed=fixed,
        mass=pt.float("mass", 2.0),
        inertia=pt.floats("inertia", [0.03, 0.03, 0.05], size=3),  # type: ignore[arg-type]
        arm_length=pt.float("arm_length", 0.3),
        velocity=velocity,
        rotors=pt.int("rotors", 4),
        coaxial=pt.bool("coaxial", False),
    )
    pt.done()
    mt = t.table("mount", {})
    mount_xyz, mount_rpy = mt.floats("xyz", _ZERO3, size=3), mt.floats("rpy", _ZERO3, size=3)
    mt.done()
    et = t.table("end_effector", {})
    ee_xyz, ee_rpy = et.floats("xyz", _ZERO3, size=3), et.floats("rpy", _ZERO3, size=3)
    ee_link = et.str("name", "end_effector")
    et.done()
    if t.has("arm") == t.has("joints"):
        raise ConfigError(f"{t.key('joints')}: give exactly one of [[joints]] or [arm] urdf")
    if t.has("joints"):
        joints = tuple(_joint(jt) for jt in t.tables("joints"))
    else:
        joints, urdf_ee = _arm_from_urdf(t.table("arm"), base_dir)
        if not t.has("end_effector"):
            ee_xyz, ee_rpy = urdf_ee
    t.done()
    try:
        return RobotSpec(
            name=name,
            platform=platform,
            joints=joints,
            mount_xyz=mount_xyz,  # type: ignore[arg-type]
            mount_rpy=mount_rpy,  # type: ignore[arg-type]
            ee_xyz=ee_xyz,  # type: ignore[arg-type]
            ee_rpy=ee_rpy,  # type: ignore[arg-type]
            ee_link=ee_link,
        )
    except ConfigError as e:  # spec validation names paths relative to the robot table
        if not t.path:
            raise
        raise ConfigError(f"{t.path}.{e}") from None


def _joint(jt: Table) -> Joint:
    lower, upper = jt.floats("limits", size=2, finite=False)
    lt = jt.table("link")
    link = Inertial(
        mass=lt.float("mass"),
        com=lt.floats("com", _ZERO3, size=3),  # type: ignore[arg-type]
        inertia=lt.floats("inertia", (1e-5, 1e-5, 1e-5, 0.0, 0.0, 0.0), size=6),  # type: ignore[arg-type]
    )
    joint = Joint(
        name=jt.str("name"),
        xyz=jt.floats("xyz", _ZERO3, size=3),  # type: ignore[arg-type]
        rpy=jt.floats("rpy", _ZERO3, size=3),  # type: ignore[arg-type]
        axis=jt.floats("axis", size=3),  # type: ignore[arg-type]
        lower=lower,
        upper=upper,
        velocity=jt.float("velocity"),
        link_name=lt.str("name", ""),
        link=link,
    )
    if not joint.link_name:
        joint = replace(joint, link_name=f"{joint.name}_link")
    lt.done()
    jt.done()
    return joint


def _arm_from_urdf(
    at: Table, base_dir: Path | None
) -> tuple[tuple[Joint, ...], tuple[tuple[float, ...], tuple[float, ...]]]:
    from aeromanip.robot.urdf import arm_from_urdf

    file = Path(at.str("urdf"))
    if not file.is_absolute() and base_dir is not None:
        file = base_dir / file
    arm = arm_from_urdf(
        file, base_link=at.str("base_link", "") or None, tip_link=at.str("tip_link", "") or None
    )
    at.done()
    return arm.joints, (arm.ee_xyz, arm.ee_rpy)
