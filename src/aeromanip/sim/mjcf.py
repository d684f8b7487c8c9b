"""MJCF (MuJoCo XML) model of a whole UAM from a ``RobotSpec``.

Layout (names are stable, the physics simulator relies on them)::

    worldbody
      ground (visual plane at z = 0, no contacts anywhere: contacts are disabled)
      surface_1..                 with scenario surfaces only (``sim.contact``): rigid boxes
      <spec.base_link>            free joint "base", platform mass/inertia at the body origin,
        rotor_1..rotor_n          sites at spec.platform.arm_length in an X layout
        arm_mount_link            fixed at spec.mount_xyz/rpy (massless, welded)
          <joint i link_name>     pos/quat = joint origin, hinge = joint axis, link inertial
            ...
              <spec.ee_link>      site at ee_xyz/ee_rpy in the last link
              ee_probe            with surfaces only: probe sphere + force/torque site
    actuators
      rotor_1..rotor_n            <motor site=... gear="0 0 1 0 0 +-K_M">, ctrl = thrust [N]
      servo_<joint>               <position kp kv>, ctrl = joint position [rad]

Constants (documented choices):

* ``K_M`` = 0.016 m: rotor drag-torque / thrust ratio of a 10" propeller; rotor ``i`` pushes
  along body z and twists the body about z by ``spin_i * K_M * thrust_i`` (``spin`` alternates
  +1, -1 around the frame, rotor 1 at +45 deg for 4 rotors, i.e. front-left).
* ``THRUST_TO_WEIGHT`` = 2: each rotor's ``ctrlrange`` is ``[0, 2 m_total g / n]``.
* Servos: a PD position loop tuned to ``servo_hz`` (default 8 Hz) with damping ratio
  ``SERVO_DAMPING`` at the largest inertia the joint can see (the whole distal arm stretched
  straight, see ``servo_gains``); lighter configurations get a stiffer, overdamped servo.
  Every joint also gets ``ARMATURE`` = 2e-3 kg m^2 of reflected rotor inertia (a geared
  hobby servo is 1e-3..5e-3), which keeps the stiff servo well conditioned at 500 Hz.
* Links lighter than ``MIN_MASS`` = 1e-4 kg or with a principal inertia below
  ``MIN_INERTIA`` = 1e-9 kg m^2 are bounded to these values (MuJoCo rejects massless moving
  bodies); an inertia violating the triangle inequality is balanced by MuJoCo.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from xml.sax.saxutils import quoteattr

import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.robot.spec import PLATFORM_DOFS, Inertial, RobotSpec
from aeromanip.sim.base import GRAVITY
from aeromanip.sim.contact import (
    PROBE_RADIUS,
    ProbeSpring,
    Surface,
    probe_body,
    sensors,
    surface_geoms,
)
from aeromanip.sim.flight_controller import rotor_layout

K_M = 0.016  # [m] rotor reaction torque per newton of thrust
THRUST_TO_WEIGHT = 2.0  # total max thrust / total weight
ARMATURE = 2e-3  # [kg m^2] reflected servo rotor inertia per arm joint
SERVO_HZ = 8.0  # [Hz] default servo natural frequency at the largest joint inertia
SERVO_DAMPING = 0.9  # servo damping ratio at that inertia
MIN_MASS = 1e-4  # [kg] lower bound of a link mass in the MJCF
MIN_INERTIA = 1e-9  # [kg m^2] lower bound of a link principal inertia in the MJCF
TIMESTEP = 0.002  # [s] default physics step (500 Hz)
MOUNT_BODY = "arm_mount_link"
FREE_JOINT = "base"
LINK_RADIUS = 0.012  # [m] visual capsule radius of the arm links


def _f(v: float) -> str:
    """Exact (round-trip) float text."""
    v = float(v)
    return "0" if v == 0.0 else repr(v)


def _v(values: object) -> str:
    return " ".join(_f(v) for v in values)  # type: ignore[attr-defined]


def _quat(rpy: tuple[float, float, float]) -> str:
    """MuJoCo quaternion (w x y z) of URDF rpy ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    r, p, y = (0.5 * a for a in rpy)
    cr, sr, cp, sp, cy, sy = (
        math.cos(r),
        math.sin(r),
        math.cos(p),
        math.sin(p),
        math.cos(y),
        math.sin(y),
    )
    w = cy * cp * cr + sy * sp * sr
    x = cy * cp * sr - sy * sp * cr
    yy = cy * sp * cr + sy * cp * sr
    z = sy * cp * cr - cy * sp * sr
    return _v((w, x, yy, z))


def link_inertial(link: Inertial) -> tuple[float, tuple[float, ...]]:
    """Mass [kg] and ``(ixx, iyy, izz, ixy, ixz, iyz)`` [kg m^2] as written to the MJCF.

    The mass is bounded below by ``MIN_MASS``; the inertia, when a principal value is below
    ``MIN_INERTIA``, is rebuilt with its eigenvalues bounded (otherwise written unchanged).
    """
    mass = max(float(link.mass), MIN_MASS)
    ixx, iyy, izz, ixy, ixz, iyz = (float(v) for v in link.inertia)
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    w, V = np.linalg.eigh(inertia)
    if w.min() >= MIN_INERTIA:
        return mass, (ixx, iyy, izz, ixy, ixz, iyz)
    fixed = V @ np.diag(np.maximum(w, MIN_INERTIA)) @ V.T
    return mass, (fixed[0, 0], fixed[1, 1], fixed[2, 2], fixed[0, 1], fixed[0, 2], fixed[1, 2])


def total_mass(spec: RobotSpec) -> float:
    """Mass of the whole UAM as simulated (platform + bounded link masses) [kg]."""
    return spec.platform.mass + sum(link_inertial(j.link)[0] for j in spec.joints)


def max_rotor_thrust(spec: RobotSpec, rotors: int) -> float:
    """Thrust limit of one rotor [N]: total thrust-to-weight ``THRUST_TO_WEIGHT``."""
    return THRUST_TO_WEIGHT * total_mass(spec) * GRAVITY / rotors


def servo_gains(
    spec: RobotSpec, servo_hz: float = SERVO_HZ, damping: float = SERVO_DAMPING
) -> list[tuple[float, float]]:
    """``(kp [N m/rad], kv [N m s/rad])`` per joint.

    ``I_j`` bounds the inertia joint ``j`` drives: ``ARMATURE`` plus, for every distal link,
    its largest principal inertia plus ``m r^2`` with ``r`` the chain length from joint ``j``
    to the link's CoM; then ``kp = I_j (2 pi f)^2`` and ``kv = 2 damping sqrt(kp I_j)``.
    """
    if not (servo_hz > 0 and math.isfinite(servo_hz)):
        raise ConfigError(f"physics.servo_hz: must be a finite number > 0, got {servo_hz}")
    if not (damping > 0 and math.isfinite(damping)):
        raise ConfigError(f"physics.servo_damping: must be a finite number > 0, got {damping}")
    out = []
    w = 2.0 * math.pi * servo_hz
    for j in range(spec.n_joints):
        inertia, reach = ARMATURE, 0.0
        for k in range(j, spec.n_joints):
            link = spec.joints[k]
            if k > j:
                reach += float(np.linalg.norm(link.xyz))
            mass, ii = link_inertial(link.link)
            principal = np.linalg.eigvalsh(
                np.array([[ii[0], ii[3], ii[4]], [ii[3], ii[1], ii[5]], [ii[4], ii[5], ii[2]]])
            )
            r = reach + float(np.linalg.norm(link.link.com))
            inertia += float(principal.max()) + mass * r * r
        kp = inertia * w * w
        out.append((kp, 2.0 * damping * math.sqrt(kp * inertia)))
    return out


def _segment_geom(name: str, end: np.ndarray, rgba: str) -> str:
    """A capsule from the body origin to ``end`` (a sphere when ``end`` is ~0)."""
    if float(np.linalg.norm(end)) < 1e-6:
        return f'<geom name="{name}" type="sphere" size="{_f(LINK_RADIUS)}" rgba="{rgba}"/>'
    return (
        f'<geom name="{name}" type="capsule" size="{_f(LINK_RADIUS)}" '
        f'fromto="0 0 0 {_v(end)}" rgba="{rgba}"/>'
    )


def robot_to_mjcf(
    spec: RobotSpec,
    *,
    rotors: int | None = None,
    timestep: float = TIMESTEP,
    servo_hz: float = SERVO_HZ,
    servo_damping: float = SERVO_DAMPING,
    surfaces: Sequence[Surface] = (),
    probe_radius: float = PROBE_RADIUS,
    probe: ProbeSpring | None = None,
) -> str:
    """MJCF text of the UAM ``spec`` with ``rotors`` thrust actuators (default: the
    platform's, flat or in coaxial pairs as it says) and one servo per joint.

    ``timestep`` [s] is the physics step; the base starts at the spec's fixed platform values
    (z = 1 m unless z is fixed) and a ``hover`` keyframe holds every rotor at ``m g / n``.
    With ``surfaces`` (``sim.contact``), contacts are on (elliptic friction cones) between
    them and a probe sphere of ``probe_radius`` [m] at the end effector, which carries a
    force/torque sensor (spring-loaded with ``probe``: ``contact.ProbeSpring``); without,
    the model has no contacts, probe or sensor.
    """
    rotors = spec.platform.rotors if rotors is None else rotors
    if isinstance(rotors, bool) or not isinstance(rotors, int) or rotors < 4 or rotors % 2:
        raise ConfigError(f"physics.rotors: must be an even integer >= 4, got {rotors!r}")
    if not (timestep > 0 and math.isfinite(timestep)):
        raise ConfigError(f"physics.rate_hz: physics step must be > 0, got {timestep}")
    positions, spins = rotor_layout(rotors, spec.platform.arm_length, spec.platform.coaxial)
    gains = servo_gains(spec, servo_hz, servo_damping)
    fixed = {d: float(spec.platform.fixed.get(d, 0.0)) for d in PLATFORM_DOFS}
    start = (fixed["x"], fixed["y"], float(spec.platform.fixed.get("z", 1.0)))
    lines = [
        *_header(spec.name, timestep, contact=bool(surfaces)),
        "  <worldbody>",
        '    <light name="sun" pos="0 0 6" dir="0 0 -1" directional="true"/>',
        '    <geom name="ground" type="plane" size="20 20 0.1" material="grid"/>',
        *surface_geoms(surfaces),
        *_platform(spec, positions, spins, start, fixed["yaw"]),
        *_arm(spec, probe_radius if surfaces else None, probe),
        "    </body>",
        "  </worldbody>",
        *_actuators(spec, spins, max_rotor_thrust(spec, rotors), gains),
        *(sensors() if surfaces else []),
        *_keyframe(spec, start, fixed["yaw"], rotors),
        "</mujoco>",
    ]
    return "\n".join(lines) + "\n"


def _header(name: str, timestep: float, contact: bool = False) -> list[str]:
    """Model, compiler, physics options, visual quality, defaults and the floor texture;
    contacts (elliptic friction cones) only with ``contact``."""
    option = (
        f'  <option timestep="{_f(timestep)}" gravity="0 0 {_f(-GRAVITY)}" '
        'integrator="implicitfast"'
    )
    if contact:
        physics = [option + ' cone="elliptic"/>']
    else:
        physics = [option + ">", '    <flag contact="disable"/>', "  </option>"]
    return [
        f"<mujoco model={quoteattr(name)}>",
        '  <compiler angle="radian" autolimits="true" inertiafromgeom="false" '
        'balanceinertia="true"/>',
        *physics,
        '  <visual><global offwidth="1280" offheight="720"/><quality shadowsize="4096"/></visual>',
        "  <default>",
        '    <geom contype="0" conaffinity="0" group="1"/>',
        '    <site group="3"/>',
        "  </default>",
        "  <asset>",
        '    <texture name="grid" type="2d" builtin="checker" width="512" height="512" '
        'rgb1="0.25 0.3 0.35" rgb2="0.35 0.4 0.45"/>',
        '    <material name="grid" texture="grid" texrepeat="8 8" reflectance="0.1"/>',
        "  </asset>",
    ]


def _platform(
    spec: RobotSpec,
    positions: np.ndarray,
    spins: np.ndarray,
    start: tuple[float, float, float],
    yaw: float,
) -> list[str]:
    """The base body (left open: the arm goes inside it): free joint, inertia, a chase
    camera, the hub, and per rotor its frame arm, disc and thrust site."""
    L, rotors, coaxial = spec.platform.arm_length, len(spins), spec.platform.coaxial
    disc = 0.9 * L * math.sin(math.pi / (rotors // 2 if coaxial else rotors))
    lines = [
        f'    <body name={quoteattr(spec.base_link)} pos="{_v(start)}" '
        f'quat="{_quat((0.0, 0.0, yaw))}">',
        f'      <freejoint name="{FREE_JOINT}"/>',
        f'      <inertial pos="0 0 0" mass="{_f(spec.platform.mass)}" '
        f'diaginertia="{_v(spec.platform.inertia)}"/>',
        '      <camera name="chase" mode="trackcom" pos="-2.5 -2.5 1.5" '
        'xyaxes="1 -1 0 0.3 0.3 1"/>',
        f'      <geom name="hub" type="box" size="{_v((0.3 * L, 0.3 * L, 0.04))}" '
        'rgba="0.2 0.2 0.25 1"/>',
    ]
    for i, (p, s) in enumerate(zip(positions, spins, strict=True)):
        tip = (p[0], p[1], 0.0)
        color = "0.8 0.3 0.2 0.5" if s > 0 else "0.2 0.4 0.8 0.5"
        height = (-0.03 if i % 2 else 0.03) if coaxial else 0.03  # lower rotor of a pair
        lines += [
            f'      <geom name="frame_arm_{i + 1}" type="capsule" size="0.01" '
            f'fromto="0 0 0 {_v(tip)}" rgba="0.3 0.3 0.3 1"/>',
            f'      <geom name="rotor_disc_{i + 1}" type="cylinder" size="{_f(disc)} 0.005" '
            f'pos="{_v((p[0], p[1], height))}" rgba="{color}"/>',
            f'      <site name="rotor_{i + 1}" pos="{_v(tip)}" size="0.01"/>',
        ]
    return lines


def _arm(
    spec: RobotSpec, probe_radius: float | None = None, probe: ProbeSpring | None = None
) -> list[str]:
    """The mount and the chain of link bodies with their hinges, ending in the EE site
    (and, with ``probe_radius``, the contact probe there: ``contact.probe_body``)."""
    indent = "      "
    lines = [
        f'{indent}<body name="{MOUNT_BODY}" pos="{_v(spec.mount_xyz)}" '
        f'quat="{_quat(spec.mount_rpy)}">'
    ]
    closing = ["      </body>"]
    for k, j in enumerate(spec.joints):
        indent += "  "
        mass, ii = link_inertial(j.link)
        nxt = spec.joints[k + 1].xyz if k + 1 < spec.n_joints else spec.ee_xyz
        limited = math.isfinite(j.lower) and math.isfinite(j.upper)
        rng = f' range="{_f(j.lower)} {_f(j.upper)}"' if limited else ""
        lines += [
            f'{indent}<body name={quoteattr(j.link_name)} pos="{_v(j.xyz)}" quat="{_quat(j.rpy)}">',
            f'{indent}  <joint name={quoteattr(j.name)} type="hinge" axis="{_v(j.axis)}" '
            f'limited="{"true" if limited else "false"}"{rng} armature="{_f(ARMATURE)}"/>',
            f'{indent}  <inertial pos="{_v(j.link.com)}" mass="{_f(mass)}" '
            f'fullinertia="{_v(ii)}"/>',
            f"{indent}  " + _segment_geom(f"{j.link_name}_geom", np.array(nxt), "0.7 0.7 0.7 1"),
            f'{indent}  <geom name="{j.link_name}_joint" type="cylinder" size="0.02 0.02" '
            f'zaxis="{_v(j.axis)}" rgba="0.9 0.6 0.1 1"/>',
        ]
        closing.insert(0, f"{indent}</body>")
    lines.append(
        f'{indent}  <site name={quoteattr(spec.ee_link)} pos="{_v(spec.ee_xyz)}" '
        f'quat="{_quat(spec.ee_rpy)}" size="0.015" rgba="1 0.1 0.1 1" group="1"/>'
    )
    if probe_radius is not None:
        lines += probe_body(indent + "  ", _v(spec.ee_xyz), _quat(spec.ee_rpy), probe_radius, probe)
    return lines + closing


def _actuators(
    spec: RobotSpec, spins: np.ndarray, f_max: float, gains: list[tuple[float, float]]
) -> list[str]:
    """One thrust motor per rotor site (with its reaction torque), one servo per joint."""
    lines = ["  <actuator>"]
    for i, s in enumerate(spins):
        lines.append(
            f'    <motor name="rotor_{i + 1}" site="rotor_{i + 1}" '
            f'gear="0 0 1 0 0 {_f(s * K_M)}" ctrlrange="0 {_f(f_max)}"/>'
        )
    for j, (kp, kv) in zip(spec.joints, gains, strict=True):
        lines.append(
            f"    <position name={quoteattr('servo_' + j.name)} joint={quoteattr(j.name)} "
            f'kp="{_f(kp)}" kv="{_f(kv)}"/>'
        )
    return [*lines, "  </actuator>"]


def _keyframe(
    spec: RobotSpec, start: tuple[float, float, float], yaw: float, rotors: int
) -> list[str]:
    """The ``hover`` keyframe: at the start pose, every rotor at ``m g / n``."""
    hover = total_mass(spec) * GRAVITY / rotors
    qpos0 = (*start, *(float(v) for v in _quat((0.0, 0.0, yaw)).split()))
    return [
        "  <keyframe>",
        f'    <key name="hover" qpos="{_v(qpos0)} {_v([0.0] * spec.n_joints)}" '
        f'ctrl="{_v([hover] * rotors)} {_v([0.0] * spec.n_joints)}"/>',
        "  </keyframe>",
    ]
