"""Full-dynamics simulator: MuJoCo model of the UAM flown by a PX4-like inner loop.

Rates (PX4-like multi-rate inner loop): every physics step (``1 / rate_hz`` s, 500 Hz by
default) the flight controller's attitude/rate loop, the mixer and the arm servos run once on
the true state (between ``mj_step1`` and ``mj_step2``); the controller's position/velocity
loop runs every ``outer_every`` physics steps (``outer_rate_hz``, 100 Hz by default, rounded
to an integer divisor of ``rate_hz``; PX4 runs it at 50-100 Hz) and its thrust-vector
set-point is held in between. What the NMPC's command sets in the flight controller
(``setpoint``, as in PX4's offboard mode): ``"position"``, a position reference moving
linearly within the control period from the plan's first state along the command ``u``,
with ``u`` as velocity feed-forward; or ``"velocity"``, ``u`` as the velocity and yaw-rate
set-point (no position loop: the NMPC closes it). ``joint_setpoint = "rate"`` makes each
servo's ramp go on from where the last one ended (the joint rate integrated by the servo)
instead of starting at the plan's first joint angle. Inactive platform DoFs are held at
their fixed values. Joint servos are MuJoCo position actuators (PD, see
``mjcf.servo_gains``) whose set-point is shifted every physics step to add velocity
feed-forward and an integral term: ``tau = kp (q_ref - q) + kv (u_q - qdot) + ki int
(q_ref - q)``. The per-step Python works on floats (no NumPy on 3-vectors, no per-step
arrays).

``arm_torque`` (extras) is the wrench the arm exerts on the base through the mount, from
MuJoCo's ``cfrc_int`` of the first arm body (the force/torque its parent transmits to it,
com-based: world orientation, reference point ``subtree_com`` of the tree root), moved to the
base origin (= platform CoM), negated, expressed in the body frame; its xy magnitude is
averaged over the control period, sampled at the outer-loop rate (every ``outer_every``
physics steps, the last sample at the end of the period). ``motor_i`` and ``thrust_total``
are exact means over every physics step of the period.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from operator import add
from pathlib import Path
from typing import Any

import numpy as np

from aeromanip.config import check_range
from aeromanip.errors import ConfigError, StateError
from aeromanip.robot.spec import PLATFORM_DOFS, RobotSpec
from aeromanip.sim.base import SIMULATORS, Simulator
from aeromanip.sim.contact import (
    PROBE_RADIUS,
    ProbeSpring,
    Surface,
    read_probe,
    read_probe_radius,
    read_surfaces,
)
from aeromanip.sim.contact_sensor import CONTACT_COLUMNS, ContactSensor
from aeromanip.sim.feedback import FeedbackNoise
from aeromanip.sim.flight_controller import FlightController, FlightGains, Mixer, rotor_layout
from aeromanip.sim.mjcf import FREE_JOINT, K_M, SERVO_HZ, max_rotor_thrust, robot_to_mjcf
from aeromanip.sim.mujoco_import import mujoco

NOISE_KEYS = ("position", "yaw", "joints", "filter", "force", "torque")
OPTION_KEYS = (
    "rate_hz", "outer_rate_hz", "rotors", "seed", "noise", "gains", "servo_hz", "servo_i",
    "setpoint", "joint_setpoint", "surfaces", "probe_radius", "probe",
)  # fmt: skip
SETPOINTS = ("position", "velocity")  # what a command sets in the flight controller
# where each servo's ramp starts: the plan's first state, or where the last ramp ended
JOINT_SETPOINTS = ("ramp", "rate")
SERVO_I = 4.0  # [1/s] servo integral gain relative to kp (ki = SERVO_I kp)
RATE_HZ = 500.0  # [Hz] default physics and attitude/rate-loop rate
MIN_RATE_HZ = 100.0  # [Hz] lowest accepted physics rate
MAX_RATE_HZ = 10_000.0  # [Hz] highest (every step runs Python)
MAX_SERVO_I = 100.0  # [1/s]
MAX_NOISE = 1.0  # [m, rad, N or N m] a noise std beyond this is no measurement
OUTER_RATE_HZ = 100.0  # [Hz] default rate of the position/velocity loop
MIN_OUTER_RATE_HZ = 10.0  # [Hz] lowest accepted outer-loop rate (position bandwidth ~0.35 Hz)


def _yaw_of(qw: float, qx: float, qy: float, qz: float) -> float:
    return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


def _number(value: Any, path: str, low: float | None = None, high: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{path}: must be a finite number, got {value!r}")
    check_range(value, path, low, high)
    return float(value)


def _surfaces(surfaces: Sequence[Mapping[str, Any] | Surface]) -> tuple[Surface, ...]:
    """``Surface`` objects as given, tables checked (``sim.contact.read_surfaces``)."""
    if isinstance(surfaces, (list, tuple)) and all(isinstance(s, Surface) for s in surfaces):
        return tuple(surfaces)  # type: ignore[arg-type]
    return read_surfaces(surfaces)


@SIMULATORS.register("physics")
class PhysicsSimulator(Simulator):
    """The UAM in MuJoCo with a cascaded flight controller and PID joint servos.

    Args:
        spec: the robot.
        rate_hz: physics and inner-loop (attitude, rate, mixer, servos) rate [Hz] (>= 100).
        outer_rate_hz: position/velocity-loop rate [Hz], in ``[10, rate_hz]``; rounded to
            ``rate_hz / outer_every`` with ``outer_every`` an integer (``rate_hz`` to run it
            every physics step).
        noise: measurement noise std devs ``{"position": m, "yaw": rad, "joints": rad}``,
            white at each ``state()``; with ``"filter": T`` [s] > 0, the error of an
            autopilot's estimate fusing them at the outer-loop rate (``sim.feedback``).
        seed: seed of the noise generator (re-seeded at every ``reset``).
        rotors: number of rotors (default: the platform's), X layout, flat or in coaxial
            pairs as the platform says.
        gains: flight-controller gains (``FlightGains()`` by default).
        servo_hz: joint servo bandwidth at the largest joint inertia [Hz].
        servo_i: servo integral gain relative to kp [1/s].
        setpoint: ``"position"`` or ``"velocity"`` (module docstring).
        joint_setpoint: ``"ramp"``: each servo ramps from the plan's first joint angle along
            its rate; ``"rate"``: from where its last ramp ended (the rate command
            integrated by the servo: a measured, noisy angle never resets it).
        surfaces: rigid surfaces the end effector's probe can touch (``sim.contact``: the
            ``[[physics.surfaces]]`` tables, or ``Surface`` objects); with any, the probe's
            contact and its wrist force/torque sensor (noise ``"force"`` [N], ``"torque"``
            [N m] per axis) are read every control step (``measured_wrench``, ``extras``).
        probe_radius: radius of the end effector's contact sphere [m].
        probe: a spring-loaded probe (``sim.contact``: the ``physics.probe`` table or a
            ``ProbeSpring``); ``None``: the sphere is rigid on the end effector.

    Attributes:
        model, data: the MuJoCo model and data (open ``to_xml()`` in ``mujoco.viewer``).
        controller: the ``FlightController``.
        outer_every: physics steps per outer-loop tick; outer_rate_hz: its actual rate [Hz].
    """

    instant_extras = ("roll", "pitch")
    options_table = "physics"

    def __init__(
        self,
        spec: RobotSpec,
        *,
        rate_hz: float = RATE_HZ,
        outer_rate_hz: float = OUTER_RATE_HZ,
        noise: Mapping[str, float] | None = None,
        seed: int = 0,
        rotors: int | None = None,
        gains: FlightGains | None = None,
        servo_hz: float = SERVO_HZ,
        servo_i: float = SERVO_I,
        setpoint: str = SETPOINTS[0],
        joint_setpoint: str = JOINT_SETPOINTS[0],
        surfaces: Sequence[Mapping[str, Any] | Surface] = (),
        probe_radius: float = PROBE_RADIUS,
        probe: Mapping[str, Any] | ProbeSpring | None = None,
    ) -> None:
        self.spec = spec
        for key, value, allowed in (
            ("setpoint", setpoint, SETPOINTS),
            ("joint_setpoint", joint_setpoint, JOINT_SETPOINTS),
        ):
            if value not in allowed:
                raise ConfigError(f"physics.{key}: {value!r} is not one of {list(allowed)}")
        self.velocity_setpoint = setpoint == "velocity"
        self.joint_rate_setpoint = joint_setpoint == "rate"
        self._read_options(rate_hz, outer_rate_hz, noise, seed, servo_i)
        self.h = 1.0 / self.rate_hz
        rotors = spec.platform.rotors if rotors is None else rotors
        self.surfaces = _surfaces(surfaces)
        self.xml = robot_to_mjcf(
            spec,
            rotors=rotors,
            timestep=self.h,
            servo_hz=servo_hz,
            surfaces=self.surfaces,
            probe_radius=read_probe_radius(probe_radius),
            probe=read_probe(probe) if isinstance(probe, Mapping) else probe,
        )
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        self.rotors = rotors
        self._bind_model()
        self.contact: ContactSensor | None = None
        if self.surfaces:
            self.contact = ContactSensor(
                self.model, self.data, self.surfaces,
                self.noise["force"], self.noise["torque"], self.seed,
            )  # fmt: skip
            self.instant_extras = (*type(self).instant_extras, *CONTACT_COLUMNS)
        positions, spins = rotor_layout(rotors, spec.platform.arm_length, spec.platform.coaxial)
        self.mixer = Mixer(positions, spins, K_M, max_rotor_thrust(spec, rotors))
        self.mass = float(self.model.body_subtreemass[self._base])
        self.gains = gains or FlightGains()
        self.controller = self._make_controller(np.eye(3))
        x0 = np.zeros(spec.nx)
        for i, d in enumerate(spec.platform.dofs):
            x0[i] = 1.0 if d == "z" else 0.0
        x0[self._n_p :] = np.clip(0.0, self._q_lo, self._q_hi)
        self.reset(x0)

    def _read_options(
        self,
        rate_hz: float,
        outer_rate_hz: float,
        noise: Mapping[str, float] | None,
        seed: int,
        servo_i: float,
    ) -> None:
        """Check the options (errors name the ``physics.*`` key) and keep them."""
        self.rate_hz = _number(rate_hz, "physics.rate_hz", MIN_RATE_HZ, MAX_RATE_HZ)
        outer = _number(outer_rate_hz, "physics.outer_rate_hz", MIN_OUTER_RATE_HZ)
        if outer > self.rate_hz:
            raise ConfigError(
                f"physics.outer_rate_hz: must be <= physics.rate_hz ({self.rate_hz}), got {outer}"
            )
        self.outer_every = max(1, round(self.rate_hz / outer))
        self.outer_rate_hz = self.rate_hz / self.outer_every
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

    def _bind_model(self) -> None:
        """Ids, addresses and servo constants of the model; views into MjData for the
        per-step Python (which works on floats)."""
        m, d, spec = self.model, self.data, self.spec
        self._base = m.body(spec.base_link).id
        self._arm1 = m.body(spec.joints[0].link_name).id
        self._ee = m.site(spec.ee_link).id
        self._free_q = m.jnt_qposadr[m.joint(FREE_JOINT).id]
        self._free_v = m.jnt_dofadr[m.joint(FREE_JOINT).id]
        jids = [m.joint(j.name).id for j in spec.joints]
        self._q_adr = np.array([m.jnt_qposadr[i] for i in jids])
        self._v_adr = np.array([m.jnt_dofadr[i] for i in jids])
        servo = np.arange(self.rotors, self.rotors + spec.n_joints)
        self._kp = m.actuator_gainprm[servo, 0].copy()
        self._kv = -m.actuator_biasprm[servo, 2].copy()
        self._q_lo = np.array([j.lower for j in spec.joints])
        self._q_hi = np.array([j.upper for j in spec.joints])
        self._servos = tuple(
            zip(
                self._q_adr.tolist(), self._q_lo.tolist(), self._q_hi.tolist(),
                self._kp.tolist(), self._kv.tolist(), (self.servo_i * self._kp).tolist(),
                strict=True,
            )
        )  # fmt: skip
        self._qpos, self._qvel, self._ctrl = d.qpos, d.qvel, d.ctrl
        root = m.body_rootid[self._arm1]
        self._arm_views = (d.cfrc_int[self._arm1], d.subtree_com[root], d.xpos[self._base])
        self._xmat_base = d.xmat[self._base]
        self._n_p = spec.n_platform
        self._pos_idx = [
            (i, PLATFORM_DOFS.index(d)) for i, d in enumerate(spec.platform.dofs) if d != "yaw"
        ]
        self._yaw_idx = spec.platform.dofs.index("yaw") if "yaw" in spec.platform.dofs else None
        self._fixed = {d: float(spec.platform.fixed.get(d, 0.0)) for d in PLATFORM_DOFS}

    @classmethod
    def from_options(cls, spec: RobotSpec, options: Mapping[str, Any]) -> PhysicsSimulator:
        """Build from a ``[physics]`` table (keys ``OPTION_KEYS``); see ``check_options``."""
        return cls(spec, **cls.check_options(options))

    @classmethod
    def check_options(cls, options: Mapping[str, Any]) -> dict[str, Any]:
        """The ``[physics]`` table as keyword arguments, checked without building
        anything: unknown keys, types and ranges are one ``ConfigError`` line each."""
        kwargs: dict[str, Any] = {}
        for key, value in options.items():
            if key not in OPTION_KEYS:
                raise ConfigError(f"physics.{key}: unknown key (choose from {OPTION_KEYS})")
            if key in ("noise", "gains") and not isinstance(value, Mapping):
                raise ConfigError(f"physics.{key}: must be a table, got {value!r}")
            allowed = {"setpoint": SETPOINTS, "joint_setpoint": JOINT_SETPOINTS}.get(key)
            if allowed is not None and value not in allowed:
                raise ConfigError(f"physics.{key}: {value!r} is not one of {list(allowed)}")
            if key == "surfaces":
                read_surfaces(value)
            if key == "probe_radius":
                read_probe_radius(value)
            if key == "probe":
                read_probe(value)
            if key in ("rotors", "seed") and (
                isinstance(value, bool) or not isinstance(value, int)
            ):
                raise ConfigError(f"physics.{key}: must be an integer, got {value!r}")
            kwargs[key] = value
        if "gains" in kwargs:
            kwargs["gains"] = FlightGains.from_options(dict(kwargs["gains"]))
        rate = _number(kwargs.get("rate_hz", RATE_HZ), "physics.rate_hz", MIN_RATE_HZ, MAX_RATE_HZ)
        _number(
            kwargs.get("outer_rate_hz", OUTER_RATE_HZ),
            "physics.outer_rate_hz",
            MIN_OUTER_RATE_HZ,
            rate,
        )
        _number(kwargs.get("servo_hz", SERVO_HZ), "physics.servo_hz", 0.1, rate / 2.0)
        _number(kwargs.get("servo_i", SERVO_I), "physics.servo_i", 0.0, MAX_SERVO_I)
        for k, v in dict(kwargs.get("noise", {})).items():
            if k not in NOISE_KEYS:
                raise ConfigError(f"physics.noise.{k}: unknown key (choose from {NOISE_KEYS})")
            _number(v, f"physics.noise.{k}", 0.0, MAX_NOISE)
        return kwargs

    def _make_controller(self, inertia: np.ndarray) -> FlightController:
        return FlightController(
            self.mass, inertia, self.mixer, self.h, self.gains, outer_every=self.outer_every
        )

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
        self.controller = self._make_controller(M[fv + 3 : fv + 6, fv + 3 : fv + 6])
        self.controller.reset(torque_trim=d.qfrc_bias[fv + 3 : fv + 6])
        servo_int = d.qfrc_bias[self._v_adr].copy()
        self._servo_int = servo_int.tolist()
        #: where each servo's ramp ended (joint_setpoint "rate": the next one goes on)
        self._servo_ref = [float(q) for q in x0[self._n_p :]]
        d.ctrl[: self.rotors] = self.controller.motors
        d.ctrl[self.rotors :] = x0[self._n_p :] + servo_int / self._kp
        mujoco.mj_forward(m, d)
        mujoco.mj_rnePostConstraint(m, d)
        self._yaw = pose["yaw"]
        self.time = 0.0
        self.feedback = FeedbackNoise(
            self._noise_std(), self.noise["filter"], self.outer_rate_hz, self.seed
        )
        self._arm_torque = self._arm_torque_now()
        if self.contact is not None:
            self.contact.reset(self.seed)
        self._motor_mean = np.array(self.controller.motors)
        self._spread_mean = float(self._motor_mean.max() - self._motor_mean.min())

    def advance(self, u: np.ndarray, plan_x: np.ndarray, dt: float) -> None:
        """Fly ``dt`` [s] (a whole number of physics steps) tracking ramps from ``plan_x[0]``."""
        n, u, start = self._command(u, plan_x, dt)
        m, d, fc = self.model, self.data, self.controller
        p_ref = [self._fixed["x"], self._fixed["y"], self._fixed["z"]]
        v_ff = [0.0, 0.0, 0.0]
        for i, axis in self._pos_idx:
            p_ref[axis], v_ff[axis] = float(start[i]), float(u[i])
        (px, py, pz), (vx, vy, vz) = p_ref, v_ff
        yi = self._yaw_idx
        yaw0, yaw_rate = (self._fixed["yaw"], 0.0) if yi is None else (start[yi], u[yi])
        yaw0, yaw_rate = float(yaw0), float(yaw_rate)
        servos = self._servo_ramps(u, start, n)
        servo_int = self._servo_int
        fq, fv, h, every = self._free_q, self._free_v, self.h, fc.outer_every
        qpos, qvel, ctrl, xmat = self._qpos, self._qvel, self._ctrl, self._xmat_base
        outer, inner, step1, step2 = fc.outer, fc.inner, mujoco.mj_step1, mujoco.mj_step2
        torque_sum, samples, motor_sum, spread_sum = 0.0, 0, [0.0] * self.rotors, 0.0
        velocity_only = self.velocity_setpoint
        for k in range(n):
            t = k * h
            step1(m, d)  # kinematics of the current state: the base rotation in xmat
            qp, qv = qpos.tolist(), qvel.tolist()
            if velocity_only:  # the references follow the body: only the rates are set
                p_ref, yaw_ref = qp[fq : fq + 3], _yaw_of(*qp[fq + 3 : fq + 7])
            else:
                p_ref, yaw_ref = (px + vx * t, py + vy * t, pz + vz * t), yaw0 + yaw_rate * t
            if fc.outer_due:
                outer(qp[fq : fq + 3], qv[fv : fv + 3], p_ref, v_ff)
            motors = inner(xmat.tolist(), qv[fv + 3 : fv + 6], yaw_ref, yaw_rate)
            cmd = motors.copy()
            for j, (adr, lo, hi, kp_inv, ki_h, q0, uq, ff) in enumerate(servos):
                q_ref = q0 + uq * t
                if not lo < q_ref < hi:  # at a limit: hold it, no feed-forward
                    q_ref, ff = (lo if q_ref <= lo else hi), 0.0
                servo_int[j] = integral = servo_int[j] + ki_h * (q_ref - qp[adr])
                cmd.append(q_ref + (ff + integral) * kp_inv)
            ctrl[:] = cmd
            step2(m, d)
            motor_sum = list(map(add, motor_sum, motors))
            spread_sum += max(motors) - min(motors)
            if (n - 1 - k) % every == 0:  # arm torque at the outer rate, ending the period
                mujoco.mj_rnePostConstraint(m, d)
                torque_sum += self._arm_torque_now()
                samples += 1
        self._arm_torque = torque_sum / samples
        self._motor_mean = np.array(motor_sum) / n
        self._spread_mean = spread_sum / n
        self.time += n * self.h
        self.true_state()  # keeps the unwrapped yaw current

    def _command(
        self, u: np.ndarray, plan_x: np.ndarray, dt: float
    ) -> tuple[int, np.ndarray, np.ndarray]:
        """``advance``'s inputs checked: physics steps in ``dt``, ``u``, ``plan_x[0]``."""
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
        return n, u, start

    def _servo_ramps(self, u: np.ndarray, start: np.ndarray, n: int) -> list[tuple]:
        """Per joint: qpos address, limits, 1 / kp, ki h, start and rate of the ramp, kv u_q.
        The ramp starts at the plan's first state, or (joint_setpoint "rate") goes on from
        where the last one ended; where this one ends is kept."""
        ramp_start = self._servo_ref if self.joint_rate_setpoint else start[self._n_p :].tolist()
        servos = [
            (adr, lo, hi, 1.0 / kp, ki * self.h, q0, uq, kv * uq)
            for (adr, lo, hi, kp, kv, ki), q0, uq in zip(
                self._servos, ramp_start, u[self._n_p :].tolist(), strict=True
            )
        ]
        self._servo_ref = [
            min(max(q0 + uq * n * self.h, lo), hi) for (_, lo, hi, *_r, q0, uq, _ff) in servos
        ]
        return servos

    def state(self) -> np.ndarray:
        """Measured NMPC state ``[active platform DoFs, q]``: the true one plus the
        configured noise (``sim.feedback``)."""
        return self.true_state() + self.feedback.error(self.time)

    def _noise_std(self) -> np.ndarray:
        """Per NMPC state DoF, the std of its measurement noise [m, rad]."""
        std = np.zeros(self.spec.nx)
        std[[i for i, _ in self._pos_idx]] = self.noise["position"]
        if self._yaw_idx is not None:
            std[self._yaw_idx] = self.noise["yaw"]
        std[self._n_p :] = self.noise["joints"]
        return std

    def extras(self) -> dict[str, float]:
        """``roll``, ``pitch`` [rad] and, with surfaces, ``CONTACT_COLUMNS`` now; period
        means of ``motor_i``, ``thrust_total``, ``rotor_spread`` (largest minus smallest
        rotor thrust, the differential thrust spent on moments) [N] and ``arm_torque``
        [N m] (xy moment of the arm on the base about its CoM, body frame)."""
        roll, pitch = self._roll_pitch()
        out = {"roll": roll, "pitch": pitch}
        for i, f in enumerate(self._motor_mean):
            out[f"motor_{i + 1}"] = float(f)
        out["thrust_total"] = float(self._motor_mean.sum())
        out["rotor_spread"] = float(self._spread_mean)
        out["arm_torque"] = float(self._arm_torque)
        if self.contact is not None:  # at this instant, as the state
            out.update(self.contact.read(self.time).columns())
        return out

    def measured_attitude(self) -> tuple[float, float] | None:
        """The base's ``(roll, pitch)`` [rad] now, as an autopilot's attitude estimate
        gives them (exact here: no attitude noise is simulated)."""
        return self._roll_pitch()

    def set_force_feedforward(self, force: np.ndarray) -> None:
        """The thrust [N, world] added to the position loop's (as an acceleration
        feed-forward, over the total mass) until the next call or ``reset``."""
        f = np.asarray(force, dtype=float).ravel()
        if f.shape != (3,) or not np.all(np.isfinite(f)):
            raise StateError(f"force feed-forward: expected 3 finite numbers, got {f.tolist()}")
        self.controller.a_ff = (f[0] / self.mass, f[1] / self.mass, f[2] / self.mass)

    def measured_wrench(self) -> np.ndarray | None:
        """The wrist sensor's reading now, with its noise: ``[f (3), tau (3)]`` [N, N m],
        world frame, the force on the end effector and the torque about the sensor site
        (``sim.contact_sensor``); ``None`` without surfaces (no sensor)."""
        if self.contact is None:
            return None
        reading = self.contact.read(self.time)
        return np.concatenate([reading.force, reading.torque])

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

    def rates(self) -> np.ndarray:
        """The actual rates ``dx/dt`` (no noise): the base's world velocity, the yaw rate
        (from the body rates, exact at any tilt) and the joint velocities."""
        qv, fv = self.data.qvel, self._free_v
        r = np.empty(self.spec.nx)
        for i, axis in self._pos_idx:
            r[i] = qv[fv + axis]
        if self._yaw_idx is not None:
            roll, pitch = self._roll_pitch()
            _, wy, wz = qv[fv + 3 : fv + 6]  # body frame
            r[self._yaw_idx] = (wy * math.sin(roll) + wz * math.cos(roll)) / math.cos(pitch)
        r[self._n_p :] = qv[self._v_adr]
        return r

    @classmethod
    def time_step(cls, options: Mapping[str, Any]) -> float:
        """One physics step [s]: ``1 / rate_hz``."""
        return 1.0 / float(cls.check_options(options).get("rate_hz", RATE_HZ))

    def _roll_pitch(self) -> tuple[float, float]:
        """The base's roll and pitch now [rad] (ZYX Euler angles)."""
        w, x, y, z = self.data.qpos[self._free_q + 3 : self._free_q + 7]
        roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
        return roll, math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))

    def ee_position(self) -> np.ndarray:
        """True end-effector position, world frame [m] (includes roll and pitch)."""
        mujoco.mj_kinematics(self.model, self.data)
        return self.data.site_xpos[self._ee].copy()

    def _arm_torque_now(self) -> float:
        """|xy| of the arm's moment on the base about the base origin, body frame [N m].

        Uses the quantities of the last forward pass (``mj_rnePostConstraint`` must have run).
        """
        wrench, com, base = self._arm_views
        tx, ty, tz, fx, fy, fz = wrench.tolist()
        com, base = com.tolist(), base.tolist()
        rx, ry, rz = com[0] - base[0], com[1] - base[1], com[2] - base[2]
        tx, ty, tz = tx + (ry * fz - rz * fy), ty + (rz * fx - rx * fz), tz + (rx * fy - ry * fx)
        r00, r01, _, r10, r11, _, r20, r21, _ = self._xmat_base.tolist()
        return math.hypot(r00 * tx + r10 * ty + r20 * tz, r01 * tx + r11 * ty + r21 * tz)

    def to_xml(self) -> str:
        """The MJCF text of the simulated model."""
        return self.xml

    def save_xml(self, path: str | Path) -> Path:
        """Write the MJCF to ``path`` (view it with ``python -m mujoco.viewer --mjcf=PATH``)."""
        path = Path(path)
        path.write_text(self.xml)
        return path
