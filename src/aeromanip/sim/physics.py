"""Full-dynamics simulator: MuJoCo model of the UAM flown by a PX4-like inner loop.

Each physics step (``1 / rate_hz`` s) the flight controller and the arm servos run once on
the true state; the references move linearly within a control period from the plan's first
state along the command ``u`` (with ``u`` as velocity feed-forward). Inactive platform DoFs
are held at their fixed values. Joint servos are MuJoCo position actuators (PD, see
``mjcf.servo_gains``) whose set-point is shifted to add velocity feed-forward and an
integral term: ``tau = kp (q_ref - q) + kv (u_q - qdot) + ki int (q_ref - q)``.

``arm_torque`` (extras) is the wrench the arm exerts on the base through the mount, from
MuJoCo's ``cfrc_int`` of the first arm body (the force/torque its parent transmits to it,
com-based: world orientation, reference point ``subtree_com`` of the tree root), moved to the
base origin (= platform CoM), negated, expressed in the body frame; its xy magnitude is
averaged over the control period.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from aeromanip.errors import ConfigError, StateError
from aeromanip.robot.spec import PLATFORM_DOFS, RobotSpec
from aeromanip.sim.base import Simulator
from aeromanip.sim.flight_controller import FlightController, FlightGains, Mixer, rotor_layout
from aeromanip.sim.mjcf import FREE_JOINT, K_M, SERVO_HZ, max_rotor_thrust, robot_to_mjcf

NOISE_KEYS = ("position", "yaw", "joints")
OPTION_KEYS = ("rate_hz", "rotors", "seed", "noise", "gains", "servo_hz", "servo_i")
SERVO_I = 4.0  # [1/s] servo integral gain relative to kp (ki = SERVO_I kp)


def _yaw_of(qw: float, qx: float, qy: float, qz: float) -> float:
    return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


def _number(value: Any, path: str, low: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{path}: must be a finite number, got {value!r}")
    if low is not None and value < low:
        raise ConfigError(f"{path}: must be >= {low}, got {value}")
    return float(value)


class PhysicsSimulator(Simulator):
    """The UAM in MuJoCo with a cascaded flight controller and PID joint servos.

    Args:
        spec: the robot.
        rate_hz: physics and inner-loop rate [Hz] (>= 100).
        noise: measurement noise std devs ``{"position": m, "yaw": rad, "joints": rad}``.
        seed: seed of the noise generator (re-seeded at every ``reset``).
        rotors: number of rotors (even, >= 4), X layout.
        gains: flight-controller gains (``FlightGains()`` by default).
        servo_hz: joint servo bandwidth at the largest joint inertia [Hz].
        servo_i: servo integral gain relative to kp [1/s].

    Attributes:
        model, data: the MuJoCo model and data (open ``to_xml()`` in ``mujoco.viewer``).
        controller: the ``FlightController``.
    """

    def __init__(
        self,
        spec: RobotSpec,
        *,
        rate_hz: float = 500.0,
        noise: Mapping[str, float] | None = None,
        seed: int = 0,
        rotors: int = 4,
        gains: FlightGains | None = None,
        servo_hz: float = SERVO_HZ,
        servo_i: float = SERVO_I,
    ) -> None:
        self.spec = spec
        self.rate_hz = _number(rate_hz, "physics.rate_hz", 100.0)
        self.noise = {k: 0.0 for k in NOISE_KEYS}
        if noise is not None and not isinstance(noise, Mapping):
            raise ConfigError(f"physics.noise: must be a table, got {noise!r}")
        for key, value in (noise or {}).items():
            if key not in NOISE_KEYS:
                raise ConfigError(f"physics.noise.{key}: unknown key (choose from {NOISE_KEYS})")
            self.noise[key] = _number(value, f"physics.noise.{key}", 0.0)
        if isinstance(seed, bool) or not isinstance(seed, int):
            raise ConfigError(f"physics.seed: must be an integer, got {seed!r}")
        self.seed = seed
        self.servo_i = _number(servo_i, "physics.servo_i", 0.0)
        self.h = 1.0 / self.rate_hz
        self.xml = robot_to_mjcf(spec, rotors=rotors, timestep=self.h, servo_hz=servo_hz)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.rotors = rotors
        self._base = m.body(spec.base_link).id
        self._arm1 = m.body(spec.joints[0].link_name).id
        self._ee = m.site(spec.ee_link).id
        self._free_q = m.jnt_qposadr[m.joint(FREE_JOINT).id]
        self._free_v = m.jnt_dofadr[m.joint(FREE_JOINT).id]
        jids = [m.joint(j.name).id for j in spec.joints]
        self._q_adr = np.array([m.jnt_qposadr[i] for i in jids])
        self._v_adr = np.array([m.jnt_dofadr[i] for i in jids])
        servo = np.arange(rotors, rotors + spec.n_joints)
        self._kp = m.actuator_gainprm[servo, 0].copy()
        self._kv = -m.actuator_biasprm[servo, 2].copy()
        self._q_lo = np.array([j.lower for j in spec.joints])
        self._q_hi = np.array([j.upper for j in spec.joints])
        self._n_p = spec.n_platform
        self._pos_idx = [
            (i, PLATFORM_DOFS.index(d)) for i, d in enumerate(spec.platform.dofs) if d != "yaw"
        ]
        self._yaw_idx = spec.platform.dofs.index("yaw") if "yaw" in spec.platform.dofs else None
        self._fixed = {d: float(spec.platform.fixed.get(d, 0.0)) for d in PLATFORM_DOFS}
        positions, spins = rotor_layout(rotors, spec.platform.arm_length)
        self.mixer = Mixer(positions, spins, K_M, max_rotor_thrust(spec, rotors))
        self.mass = float(m.body_subtreemass[self._base])
        self.gains = gains or FlightGains()
        self.controller = FlightController(self.mass, np.eye(3), self.mixer, self.h, self.gains)
        x0 = np.zeros(spec.nx)
        for i, d in enumerate(spec.platform.dofs):
            x0[i] = 1.0 if d == "z" else 0.0
        x0[self._n_p :] = np.clip(0.0, self._q_lo, self._q_hi)
        self.reset(x0)

    @classmethod
    def from_options(cls, spec: RobotSpec, options: Mapping[str, Any]) -> PhysicsSimulator:
        """Build from a ``[physics]`` table (keys ``OPTION_KEYS``); unknown key: ConfigError."""
        kwargs: dict[str, Any] = {}
        for key, value in options.items():
            if key not in OPTION_KEYS:
                raise ConfigError(f"physics.{key}: unknown key (choose from {OPTION_KEYS})")
            if key in ("noise", "gains") and not isinstance(value, Mapping):
                raise ConfigError(f"physics.{key}: must be a table, got {value!r}")
            if key in ("rotors", "seed") and (
                isinstance(value, bool) or not isinstance(value, int)
            ):
                raise ConfigError(f"physics.{key}: must be an integer, got {value!r}")
            kwargs[key] = value
        if "gains" in kwargs:
            kwargs["gains"] = FlightGains.from_options(dict(kwargs["gains"]))
        return cls(spec, **kwargs)

    # --- Simulator interface -------------------------------------------------------------

    def reset(self, x0: np.ndarray) -> None:
        """Hover at rest at ``x0`` (roll = pitch = 0, arm still): an exact equilibrium.

        The controller uses the total mass and the composite inertia about the base origin at
        this configuration; its velocity integrator starts at zero, its rate integrator and the
        servo integrators at the gravity trims (MuJoCo ``qfrc_bias`` at rest: the arm's moment
        on the base, the joints' holding torques), so a bent arm does not kick the platform.
        """
        x0 = np.asarray(x0, dtype=float).ravel()
        if x0.shape != (self.spec.nx,) or not np.all(np.isfinite(x0)):
            raise StateError(f"initial state: expected {self.spec.nx} finite values, got {x0}")
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        pose = dict(self._fixed)
        for i, dof in enumerate(self.spec.platform.dofs):
            pose[dof] = float(x0[i])
        fq = self._free_q
        d.qpos[fq : fq + 3] = (pose["x"], pose["y"], pose["z"])
        half = 0.5 * pose["yaw"]
        d.qpos[fq + 3 : fq + 7] = (math.cos(half), 0.0, 0.0, math.sin(half))
        d.qpos[self._q_adr] = x0[self._n_p :]
        mujoco.mj_forward(m, d)
        fv = self._free_v
        # composite inertia about the base origin (body frame) and the gravity trims
        M = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, M)
        self.controller = FlightController(
            self.mass, M[fv + 3 : fv + 6, fv + 3 : fv + 6], self.mixer, self.h, self.gains
        )
        self.controller.reset(torque_trim=d.qfrc_bias[fv + 3 : fv + 6])
        self._servo_int = d.qfrc_bias[self._v_adr].copy()
        d.ctrl[: self.rotors] = self.controller.motors
        d.ctrl[self.rotors :] = x0[self._n_p :] + self._servo_int / self._kp
        mujoco.mj_forward(m, d)
        mujoco.mj_rnePostConstraint(m, d)
        self._yaw = pose["yaw"]
        self.time = 0.0
        self.rng = np.random.default_rng(self.seed)
        self._arm_torque = self._arm_torque_now()
        self._motor_mean = self.controller.motors.copy()

    def advance(self, u: np.ndarray, plan_x: np.ndarray, dt: float) -> None:
        """Fly ``dt`` [s] (a whole number of physics steps) tracking ramps from ``plan_x[0]``."""
        n = math.floor(float(dt) * self.rate_hz + 0.5)
        if n < 1 or abs(n * self.h - dt) > 1e-9:
            raise ConfigError(
                f"dt: {dt} s is not a positive multiple of the physics step {self.h} s"
            )
        u = np.asarray(u, dtype=float).ravel()
        start = np.asarray(plan_x, dtype=float)
        start = start[0] if start.ndim == 2 else start.ravel()
        nx = self.spec.nx
        if u.shape != (nx,) or start.shape != (nx,):
            raise StateError(f"command: expected u and plan_x[0] of size {nx}")
        if not (np.all(np.isfinite(u)) and np.all(np.isfinite(start))):
            raise StateError("command: u and plan_x[0] must be finite")
        m, d, fc = self.model, self.data, self.controller
        p0 = np.array([self._fixed["x"], self._fixed["y"], self._fixed["z"]])
        v_ff = np.zeros(3)
        for i, axis in self._pos_idx:
            p0[axis], v_ff[axis] = start[i], u[i]
        yi = self._yaw_idx
        yaw0, yaw_rate = (self._fixed["yaw"], 0.0) if yi is None else (start[yi], u[yi])
        q0, uq = start[self._n_p :], u[self._n_p :]
        fq, fv, nr = self._free_q, self._free_v, self.rotors
        kp, kv, ki = self._kp, self._kv, self.servo_i * self._kp
        torque_sum, motor_sum = 0.0, np.zeros(nr)
        for k in range(n):
            t = k * self.h
            mujoco.mj_step1(m, d)
            R = d.xmat[self._base].reshape(3, 3)
            motors = fc.update(
                d.qpos[fq : fq + 3].copy(), d.qvel[fv : fv + 3].copy(), R,
                d.qvel[fv + 3 : fv + 6].copy(), p0 + v_ff * t, v_ff, yaw0 + yaw_rate * t, yaw_rate,
            )  # fmt: skip
            d.ctrl[:nr] = motors
            q_ref = q0 + uq * t
            ff = np.where((q_ref > self._q_lo) & (q_ref < self._q_hi), uq, 0.0)
            q_ref = np.clip(q_ref, self._q_lo, self._q_hi)
            self._servo_int += ki * (q_ref - d.qpos[self._q_adr]) * self.h
            d.ctrl[nr:] = q_ref + (kv * ff + self._servo_int) / kp
            mujoco.mj_step2(m, d)
            mujoco.mj_rnePostConstraint(m, d)
            torque_sum += self._arm_torque_now()
            motor_sum += motors
        self._arm_torque = torque_sum / n
        self._motor_mean = motor_sum / n
        self.time += n * self.h
        self.true_state()  # keeps the unwrapped yaw current

    def state(self) -> np.ndarray:
        """Measured NMPC state ``[active platform DoFs, q]`` (with noise if configured)."""
        x = self.true_state()
        s = self.noise
        if s["position"] > 0:
            for i, _ in self._pos_idx:
                x[i] += self.rng.normal(0.0, s["position"])
        if s["yaw"] > 0 and self._yaw_idx is not None:
            x[self._yaw_idx] += self.rng.normal(0.0, s["yaw"])
        if s["joints"] > 0:
            x[self._n_p :] += self.rng.normal(0.0, s["joints"], self.spec.n_joints)
        return x

    def extras(self) -> dict[str, float]:
        """``roll``, ``pitch`` [rad] now; period means of ``motor_i``, ``thrust_total`` [N] and
        ``arm_torque`` [N m] (xy moment of the arm on the base about its CoM, body frame)."""
        w, x, y, z = self.data.qpos[self._free_q + 3 : self._free_q + 7]
        out = {
            "roll": math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y)),
            "pitch": math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x)))),
        }
        for i, f in enumerate(self._motor_mean):
            out[f"motor_{i + 1}"] = float(f)
        out["thrust_total"] = float(self._motor_mean.sum())
        out["arm_torque"] = float(self._arm_torque)
        return out

    # --- helpers -------------------------------------------------------------------------

    def true_state(self) -> np.ndarray:
        """The exact NMPC state (yaw unwrapped continuously)."""
        qpos = self.data.qpos
        fq = self._free_q
        x = np.empty(self.spec.nx)
        for i, axis in self._pos_idx:
            x[i] = qpos[fq + axis]
        yaw = _yaw_of(*qpos[fq + 3 : fq + 7])
        self._yaw += math.remainder(yaw - self._yaw, 2.0 * math.pi)
        if self._yaw_idx is not None:
            x[self._yaw_idx] = self._yaw
        x[self._n_p :] = qpos[self._q_adr]
        return x

    def ee_position(self) -> np.ndarray:
        """True end-effector position, world frame [m] (includes roll and pitch)."""
        mujoco.mj_kinematics(self.model, self.data)
        return self.data.site_xpos[self._ee].copy()

    def _arm_torque_now(self) -> float:
        """|xy| of the arm's moment on the base about the base origin, body frame [N m]."""
        d = self.data
        wrench = d.cfrc_int[self._arm1]
        c = d.subtree_com[self.model.body_rootid[self._arm1]]
        tau = wrench[:3] + _cross(c - d.xpos[self._base], wrench[3:])
        tau_b = d.xmat[self._base].reshape(3, 3).T @ tau
        return math.hypot(tau_b[0], tau_b[1])

    def to_xml(self) -> str:
        """The MJCF text of the simulated model."""
        return self.xml

    def save_xml(self, path: str | Path) -> Path:
        """Write the MJCF to ``path`` (view it with ``python -m mujoco.viewer --mjcf=PATH``)."""
        path = Path(path)
        path.write_text(self.xml)
        return path
