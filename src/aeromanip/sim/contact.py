"""Rigid surfaces the end effector can touch, from a scenario's ``[[physics.surfaces]]``.

Each surface is a finite rigid slab (a MuJoCo box) whose contact face passes through
``point`` with outward unit normal ``normal`` (world frame, ENU)::

    [[physics.surfaces]]
    kind = "wall"              # "wall": any orientation; "ceiling": normal pointing down
    point = [1.0, 0.0, 1.0]    # a point of the contact face (its centre) [m]
    normal = [-1.0, 0.0, 0.0]  # outward normal (normalised here); ceiling default [0, 0, -1]
    size = [2.0, 2.0]          # face extents [m] along its tangents t1, t2 (below)
    friction = 0.5             # Coulomb coefficient mu (>= 0)
    thickness = 0.1            # [m] depth of the slab behind the face (optional)

The face tangents are ``t1 = normalise(z x n)`` (horizontal; ``x`` when ``n`` is vertical)
and ``t2 = n x t1``. Only the end effector's probe (a sphere of ``physics.probe_radius``
centred on the EE frame, default ``PROBE_RADIUS``) touches surfaces: no other robot geometry
collides with anything. A contact's friction is the surface's (MuJoCo takes the larger of
the two geoms' coefficients: the probe's are 0); the probe has no mass. It hangs from the
last link through a massless body whose site carries MuJoCo ``force``/``torque`` sensors:
the wrist force/torque sensor.

A compliant probe (``physics.probe``, ``ProbeSpring``) puts the sphere on a spring-loaded
slide instead, as on inspection UAMs::

    probe = { stiffness = 150.0, damping = 3.0, travel = 0.04, axis = [0.0, 0.0, -1.0] }

``axis`` (end-effector frame, normalised) is where the tip points; pushed, the tip slides
back along it against the spring [N/m] and damper [N s/m], up to ``travel`` [m] (a hard
stop). At rest the sphere is centred on the EE frame. The tip body has ``mass`` [kg]
(default ``PROBE_MASS``: a slide needs one); the sensor measures through the spring.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from aeromanip.config import check_range
from aeromanip.errors import ConfigError

SURFACE_KINDS = ("wall", "ceiling")
SURFACE_KEYS = ("kind", "point", "normal", "size", "friction", "thickness")
REQUIRED_KEYS = ("kind", "point", "size", "friction")
PROBE_RADIUS = 0.01  # [m] default radius of the end effector's contact sphere
MAX_PROBE_RADIUS = 0.1  # [m]
THICKNESS = 0.1  # [m] default depth of a surface slab
MAX_FRICTION = 10.0  # a Coulomb coefficient beyond this is not a surface
MAX_EXTENT = 1000.0  # [m] largest coordinate, extent or thickness
PROBE_BODY = "ee_probe"
PROBE_GEOM = "ee_probe"
SENSOR_SITE = "ee_ft"
FORCE_SENSOR, TORQUE_SENSOR = "ee_force", "ee_torque"
CEILING_NORMAL = (0.0, 0.0, -1.0)
PROBE_KEYS = ("stiffness", "damping", "travel", "axis", "mass")
PROBE_SLIDE = "ee_probe_slide"
PROBE_TIP_BODY = "ee_probe_tip"
PROBE_MASS = 0.01  # [kg] the spring-loaded tip's mass
PROBE_AXIS = (0.0, 0.0, -1.0)  # EE frame: the tool axis of an arm hanging down
MAX_PROBE_STIFFNESS = 1e5  # [N/m]
MAX_PROBE_TRAVEL = 0.2  # [m]


@dataclass(frozen=True)
class ProbeSpring:
    """A spring-loaded probe tip: ``stiffness`` [N/m], ``damping`` [N s/m], ``travel``
    [m] before the hard stop, ``axis`` (EE frame, unit) where the tip points, tip ``mass``
    [kg]."""

    stiffness: float
    damping: float
    travel: float
    axis: tuple[float, float, float] = PROBE_AXIS
    mass: float = PROBE_MASS


def read_probe(table: Any, path: str = "physics.probe") -> ProbeSpring:
    """The ``physics.probe`` table checked (every error names its key)."""
    if not isinstance(table, Mapping):
        raise ConfigError(f"{path}: must be a table, got {table!r}")
    for key in table:
        if key not in PROBE_KEYS:
            raise ConfigError(f"{path}.{key}: unknown key (choose from {PROBE_KEYS})")
    for key in ("stiffness", "travel"):
        if key not in table:
            raise ConfigError(f"{path}.{key}: missing (a compliant probe needs stiffness, travel)")
    axis = _vector(table.get("axis", PROBE_AXIS), f"{path}.axis", 3)
    length = math.sqrt(sum(c * c for c in axis))
    if length < 1e-9:
        raise ConfigError(f"{path}.axis: must not be zero, got {list(axis)}")
    return ProbeSpring(
        stiffness=_scalar(table["stiffness"], f"{path}.stiffness", 0.0, MAX_PROBE_STIFFNESS, True),
        damping=_scalar(table.get("damping", 0.0), f"{path}.damping", 0.0, MAX_PROBE_STIFFNESS),
        travel=_scalar(table["travel"], f"{path}.travel", 0.0, MAX_PROBE_TRAVEL, True),
        axis=tuple(c / length for c in axis),  # type: ignore[arg-type]
        mass=_scalar(table.get("mass", PROBE_MASS), f"{path}.mass", 0.0, 1.0, True),
    )


@dataclass(frozen=True)
class Surface:
    """A rigid slab: contact face through ``point`` [m], outward unit ``normal``, face
    ``size`` [m] along ``tangents()``, Coulomb ``friction``, ``thickness`` [m]."""

    kind: str
    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    size: tuple[float, float]
    friction: float
    thickness: float = THICKNESS

    def tangents(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """``t1`` (horizontal unless the normal is vertical) and ``t2 = n x t1``."""
        n = self.normal
        t1 = _cross((0.0, 0.0, 1.0), n)
        norm = math.sqrt(sum(c * c for c in t1))
        t1 = (1.0, 0.0, 0.0) if norm < 1e-9 else tuple(c / norm for c in t1)
        return t1, _cross(n, t1)


def _cross(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float]:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _vector(value: Any, path: str, n: int, positive: bool = False) -> tuple[float, ...]:
    """``n`` finite numbers (each > 0 with ``positive``), or a one-line ``ConfigError``."""
    what = f"a list of {n} finite numbers" + (" > 0" if positive else "")
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise ConfigError(f"{path}: must be {what}, got {value!r}")
    for v in value:
        ok = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
        if not ok or abs(v) > MAX_EXTENT or (positive and not v > 0):
            raise ConfigError(f"{path}: must be {what} (|v| <= {MAX_EXTENT:g}), got {value!r}")
    return tuple(float(v) for v in value)


def _scalar(value: Any, path: str, low: float, high: float, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{path}: must be a finite number, got {value!r}")
    check_range(value, path, low, high, positive=positive)
    return float(value)


def read_surface(table: Any, path: str) -> Surface:
    """One ``[[physics.surfaces]]`` table checked (every error names its key)."""
    if not isinstance(table, Mapping):
        raise ConfigError(f"{path}: must be a table, got {table!r}")
    for key in table:
        if key not in SURFACE_KEYS:
            raise ConfigError(f"{path}.{key}: unknown key (choose from {SURFACE_KEYS})")
    for key in REQUIRED_KEYS:
        if key not in table:
            raise ConfigError(f"{path}.{key}: missing (a surface needs {REQUIRED_KEYS})")
    kind = table["kind"]
    if kind not in SURFACE_KINDS:
        raise ConfigError(f"{path}.kind: {kind!r} is not one of {list(SURFACE_KINDS)}")
    if "normal" not in table and kind != "ceiling":
        raise ConfigError(f"{path}.normal: missing (a {kind} needs its outward normal)")
    normal = _vector(table.get("normal", CEILING_NORMAL), f"{path}.normal", 3)
    length = math.sqrt(sum(c * c for c in normal))
    if length < 1e-9:
        raise ConfigError(f"{path}.normal: must not be zero, got {list(normal)}")
    normal = tuple(c / length for c in normal)
    if kind == "ceiling" and not normal[2] < 0:
        raise ConfigError(
            f"{path}.normal: a ceiling faces down (normal z < 0), got {table.get('normal')!r}"
        )
    return Surface(
        kind=kind,
        point=_vector(table["point"], f"{path}.point", 3),  # type: ignore[arg-type]
        normal=normal,  # type: ignore[arg-type]
        size=_vector(table["size"], f"{path}.size", 2, positive=True),  # type: ignore[arg-type]
        friction=_scalar(table["friction"], f"{path}.friction", 0.0, MAX_FRICTION),
        thickness=_scalar(
            table.get("thickness", THICKNESS), f"{path}.thickness", 0.0, MAX_EXTENT, True
        ),
    )


def read_surfaces(value: Any, path: str = "physics.surfaces") -> tuple[Surface, ...]:
    """The ``[[physics.surfaces]]`` array of tables checked, in order."""
    if isinstance(value, Mapping) or not isinstance(value, (list, tuple)):
        raise ConfigError(f"{path}: must be an array of tables ([[{path}]]), got {value!r}")
    return tuple(read_surface(t, f"{path}[{i}]") for i, t in enumerate(value))


def read_probe_radius(value: Any, path: str = "physics.probe_radius") -> float:
    """The probe sphere's radius [m], in ``(0, MAX_PROBE_RADIUS]``."""
    return _scalar(value, path, 0.0, MAX_PROBE_RADIUS, positive=True)


def _f(v: float) -> str:
    v = float(v)
    return "0" if v == 0.0 else repr(v)


def _v(values: Sequence[float]) -> str:
    return " ".join(_f(v) for v in values)


def surface_geoms(surfaces: Sequence[Surface]) -> list[str]:
    """MJCF worldbody lines: one box per surface (``surface_<i>``, colliding only with
    the probe), its face on ``point``, elliptic-cone friction ``friction``."""
    lines = []
    for i, s in enumerate(surfaces):
        t1, t2 = s.tangents()
        half = s.thickness / 2.0
        centre = [p - n * half for p, n in zip(s.point, s.normal, strict=True)]
        condim = 3 if s.friction > 0 else 1
        lines.append(
            f'    <geom name="surface_{i + 1}" type="box" '
            f'size="{_v((s.size[0] / 2.0, s.size[1] / 2.0, half))}" pos="{_v(centre)}" '
            f'xyaxes="{_v((*t1, *t2))}" contype="0" conaffinity="1" condim="{condim}" '
            f'friction="{_f(s.friction)} 0.005 0.0001" rgba="0.55 0.5 0.45 0.6" group="1"/>'
        )
    return lines


def probe_body(
    indent: str, pos: str, quat: str, radius: float, spring: ProbeSpring | None = None
) -> list[str]:
    """MJCF lines of the probe: a massless body welded to the last link at the EE frame
    (``pos``, ``quat`` as MJCF text), holding the contact sphere and the sensor site; with
    ``spring``, those two sit on a tip body sliding back along the probe's axis."""
    tip = [
        f'{indent}  <site name="{SENSOR_SITE}" size="0.005"/>',
        f'{indent}  <geom name="{PROBE_GEOM}" type="sphere" size="{_f(radius)}" '
        'contype="1" conaffinity="0" condim="3" mass="0" friction="0 0 0" '
        'rgba="0.1 0.8 0.2 1"/>',
    ]
    if spring is not None:
        back = tuple(-c for c in spring.axis)  # positive joint travel: the tip pushed in
        inertia = 0.4 * spring.mass * radius * radius
        tip = [
            f'{indent}  <body name="{PROBE_TIP_BODY}">',
            f'{indent}    <joint name="{PROBE_SLIDE}" type="slide" axis="{_v(back)}" '
            f'limited="true" range="0 {_f(spring.travel)}" stiffness="{_f(spring.stiffness)}" '
            f'damping="{_f(spring.damping)}"/>',
            f'{indent}    <inertial pos="0 0 0" mass="{_f(spring.mass)}" '
            f'diaginertia="{_v((inertia, inertia, inertia))}"/>',
            *(["  " + line for line in tip]),
            f"{indent}  </body>",
        ]
    return [
        f'{indent}<body name="{PROBE_BODY}" pos="{pos}" quat="{quat}">',
        *tip,
        f"{indent}</body>",
    ]


def sensors() -> list[str]:
    """MJCF lines of the wrist force/torque sensor (site frame; the force the last link
    exerts on the probe body)."""
    return [
        "  <sensor>",
        f'    <force name="{FORCE_SENSOR}" site="{SENSOR_SITE}"/>',
        f'    <torque name="{TORQUE_SENSOR}" site="{SENSOR_SITE}"/>',
        "  </sensor>",
    ]
