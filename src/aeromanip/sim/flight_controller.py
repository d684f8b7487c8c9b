"""A cascaded multirotor inner loop in the style of PX4 (plain Python floats, no simulator).

Two rates, as in PX4 (position control at ~50-100 Hz, attitude and rate control at the gyro
rate). The **outer loop** (``FlightController.outer``, every ``outer_every``-th tick):

1. position P + velocity feed-forward -> velocity set-point (speed-limited);
2. velocity PID -> desired acceleration; desired force ``F = m (a + g e_z)`` [N, world] with
   the tilt limited to ``tilt_max`` (vertical thrust has priority); ``F`` is held until the
   next outer tick.

The **inner loop** (``FlightController.inner``, every tick):

3. desired attitude ``R_sp``: body z along ``F``, heading ``yaw_ref`` (rebuilt every tick, so
   a heading ramp stays smooth between outer ticks);
4. attitude P on the geometric SO(3) error ``e_R = vee(R_d^T R - R^T R_d) / 2`` -> body-rate
   set-point (plus the yaw-rate feed-forward);
5. body-rate PID -> angular acceleration -> torque ``tau = J alpha + w x J w``; collective
   thrust ``T = F . b3`` (``F`` projected on the current body z);
6. ``Mixer``: allocation-matrix pseudo-inverse, saturation to ``[0, f_max]`` giving roll/pitch
   priority over collective thrust, and collective thrust priority over yaw.

``update`` is one tick on arrays. The per-tick path (``outer``/``inner``/``Mixer.mix_floats``)
works on Python floats and tuples: NumPy calls on 3-vectors cost far more than the arithmetic.
Gains are in acceleration units (they are multiplied by the mass and inertia), so one set
suits every built-in robot. Frames: world ENU, body FLU; ``R`` maps body to world.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.sim.base import GRAVITY

Vec3 = tuple[float, float, float]


def rotor_layout(
    rotors: int, arm_length: float, coaxial: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """X layout: rotor xy positions ``(n, 2)`` [m] in the body frame and spin signs ``(n,)``.

    Flat: rotor ``i`` (0-based) sits at angle ``pi/n + 2 pi i/n`` from body x (rotor 1
    front-left for 4 rotors, counting counter-clockwise); spins alternate ``+1, -1, ...``: a
    ``+1`` rotor twists the body about +z by ``k_m`` times its thrust. Coaxial (e.g. the 3DR
    X8: 8 rotors on 4 arms): the ``n/2`` arms of the flat layout each carry an upper rotor
    (even index, the flat layout's spin) and a lower one under it (odd index, the opposite
    spin); the lower rotors' loss of efficiency in the upper ones' wake is not modelled.
    """
    if rotors < 4 or rotors % 2 or (coaxial and (rotors % 4 or rotors < 8)):
        need = (
            "a multiple of 4, >= 8, for coaxial pairs (platform.coaxial)"
            if coaxial
            else "an even integer >= 4"
        )
        raise ConfigError(f"physics.rotors: must be {need}, got {rotors}")
    if coaxial:
        arm_xy, arm_spins = rotor_layout(rotors // 2, arm_length)
        return np.repeat(arm_xy, 2, axis=0), np.column_stack([arm_spins, -arm_spins]).ravel()
    a = math.pi / rotors + 2.0 * math.pi * np.arange(rotors) / rotors
    positions = arm_length * np.column_stack([np.cos(a), np.sin(a)])
    spins = np.where(np.arange(rotors) % 2 == 0, 1.0, -1.0)
    return positions, spins


class Mixer:
    """Maps collective thrust [N] and body torque [N m] to rotor thrusts [N] within limits.

    Allocation ``[T, tau_x, tau_y, tau_z] = A f`` with rows ``1``, ``y_i``, ``-x_i``,
    ``spin_i k_m``; ``B = pinv(A)``.
    """

    def __init__(self, positions: np.ndarray, spins: np.ndarray, k_m: float, f_max: float) -> None:
        positions = np.asarray(positions, dtype=float)
        self.n = positions.shape[0]
        self.f_max = float(f_max)
        self.A = np.vstack([np.ones(self.n), positions[:, 1], -positions[:, 0], k_m * spins])
        self.B = np.linalg.pinv(self.A)
        self._cols = tuple(tuple(self.B[:, j].tolist()) for j in range(4))

    def mix(self, thrust: float, torque: Sequence[float] | np.ndarray) -> np.ndarray:
        """Rotor thrusts [N] (array) for ``thrust`` [N] and body ``torque`` [N m]."""
        tx, ty, tz = (float(t) for t in torque)
        return np.array(self.mix_floats(float(thrust), tx, ty, tz))

    def mix_floats(self, thrust: float, tx: float, ty: float, tz: float) -> list[float]:
        """Rotor thrusts [N] as floats: roll/pitch are scaled down only if their span exceeds
        ``f_max``; the collective thrust is shifted to fit; yaw gets what is left."""
        b0, b1, b2, b3 = self._cols
        f_max = self.f_max
        f_rp = [x * tx + y * ty for x, y in zip(b1, b2, strict=True)]
        span = max(f_rp) - min(f_rp)
        scale = f_max / span if span > f_max else 1.0
        f = [c * thrust + x * scale for c, x in zip(b0, f_rp, strict=True)]
        low, high = min(f), max(f)  # span <= f_max: one uniform shift fits both bounds
        if low < 0.0:
            f = [x - low for x in f]
        elif high > f_max:
            high -= f_max
            f = [x - high for x in f]
        alpha = 1.0  # the share of the yaw demand that fits
        for x, c in zip(f, b3, strict=True):
            y = c * tz
            if y > 1e-12:
                alpha = min(alpha, (f_max - x) / y)
            elif y < -1e-12:
                alpha = min(alpha, x / -y)
        alpha = max(alpha, 0.0)
        return [  # f + alpha f_y, clipped to [0, f_max]
            f_max if (v := x + alpha * (c * tz)) > f_max else (v if v > 0.0 else 0.0)
            for x, c in zip(f, b3, strict=True)
        ]


@dataclass(frozen=True)
class FlightGains:
    """Inner-loop gains (acceleration units) and limits; defaults tuned on the built-in robots.

    Position: ``pos_p`` 1.5 /s over ``vel_p`` 3.5 /s (a damping ratio ~0.7 pair, ~0.35 Hz;
    PX4's defaults are 0.95 / 1.8, a little slower): a 0.5 m step on the x8 overshoots 3.5 %
    and is within 2 cm after 1.2 s. Attitude: 8 /s over a 25 /s rate loop (PX4 scale), about
    4x faster than position. The rate integrator (60 /s^2) absorbs the arm's CoG moment; the
    velocity integrator the slow force biases. D terms are available but off (the simulated
    rotors have no lag). ``tilt_max`` 35 deg bounds the thrust-vector tilt.
    """

    pos_p_xy: float = 1.5  # [1/s] velocity set-point per metre of position error
    pos_p_z: float = 1.5  # [1/s]
    vel_p_xy: float = 3.5  # [1/s] acceleration per m/s of velocity error
    vel_i_xy: float = 0.6  # [1/s^2]
    vel_d_xy: float = 0.0  # [-] on the measured acceleration
    vel_p_z: float = 4.0  # [1/s]
    vel_i_z: float = 2.0  # [1/s^2]
    vel_d_z: float = 0.0  # [-]
    vel_i_max: float = 3.0  # [m/s^2] velocity-integrator bound per axis
    vel_max_xy: float = 3.0  # [m/s] horizontal speed set-point limit
    vel_max_z: float = 2.0  # [m/s] vertical speed set-point limit
    tilt_max: float = math.radians(35.0)  # [rad]
    att_p_rp: float = 8.0  # [1/s] rate set-point per radian of roll/pitch error
    att_p_yaw: float = 3.0  # [1/s]
    rate_p_rp: float = 25.0  # [1/s] angular acceleration per rad/s of rate error
    rate_i_rp: float = 60.0  # [1/s^2]
    rate_d_rp: float = 0.0  # [-] on the measured angular acceleration
    rate_p_yaw: float = 10.0  # [1/s]
    rate_i_yaw: float = 10.0  # [1/s^2]
    rate_d_yaw: float = 0.0  # [-]
    rate_i_max: float = 60.0  # [rad/s^2] rate-integrator bound per axis
    rate_max_rp: float = 3.8  # [rad/s] roll/pitch rate set-point limit
    rate_max_yaw: float = 1.5  # [rad/s]
    d_cutoff_hz: float = 30.0  # [Hz] low-pass of the derivative terms

    @classmethod
    def from_options(cls, options: Mapping[str, Any], path: str = "physics.gains") -> FlightGains:
        """Gains from a table; ``ConfigError`` names an unknown key or a non-finite value."""
        names = {f.name for f in fields(cls)}
        for key, value in options.items():
            if key not in names:
                raise ConfigError(f"{path}.{key}: unknown key (choose from {sorted(names)})")
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ConfigError(f"{path}.{key}: must be a number, got {value!r}")
            if not (math.isfinite(value) and value >= 0):
                raise ConfigError(f"{path}.{key}: must be a finite number >= 0, got {value}")
        return cls(**{k: float(v) for k, v in options.items()})


def _vec3(a: Sequence[float] | np.ndarray) -> Vec3:
    x, y, z = np.asarray(a, dtype=float).ravel().tolist()
    return x, y, z


class FlightController:
    """Cascaded position -> velocity (outer) and attitude -> rate (inner) controller + mixer.

    Args:
        mass: total vehicle mass [kg] (platform + arm).
        inertia: inertia about the body origin [kg m^2], ``(3,)`` diagonal or ``(3, 3)``.
        mixer: rotor allocation and saturation.
        dt: tick (inner-loop) period [s].
        gains: ``FlightGains`` (defaults if ``None``).
        outer_every: the outer loop runs on every ``outer_every``-th tick, i.e. with period
            ``outer_dt = outer_every dt`` [s]; 1 (default) runs both loops every tick.

    Attributes (Python floats and tuples):
        F: thrust-vector set-point of the last outer tick [N, world].
        thrust: collective thrust [N]; torque: body torque [N m]; motors: rotor thrusts [N].
        i_vel: velocity integrator [m/s^2]; i_rate: rate integrator [rad/s^2].
        a_ff: acceleration feed-forward added to the velocity loop's output [m/s^2, world]
            (e.g. a contact force's balance over the mass); zero after ``reset``.
    """

    def __init__(
        self,
        mass: float,
        inertia: Sequence[float] | np.ndarray,
        mixer: Mixer,
        dt: float,
        gains: FlightGains | None = None,
        outer_every: int = 1,
    ) -> None:
        if isinstance(outer_every, bool) or not isinstance(outer_every, int) or outer_every < 1:
            raise ConfigError(f"outer_every: must be an integer >= 1, got {outer_every!r}")
        J = np.asarray(inertia, dtype=float)
        self.J = np.diag(J) if J.ndim == 1 else J
        self.J_inv = np.linalg.inv(self.J)
        self._J = tuple(self.J.ravel().tolist())
        self.mass = float(mass)
        self.mixer = mixer
        self.dt = float(dt)
        self.outer_every = outer_every
        self.outer_dt = self.dt * outer_every
        self.gains = gains or FlightGains()
        g = self.gains
        self._kp_pos = (g.pos_p_xy, g.pos_p_xy, g.pos_p_z)
        self._kp_vel = (g.vel_p_xy, g.vel_p_xy, g.vel_p_z)
        self._ki_vel = (g.vel_i_xy, g.vel_i_xy, g.vel_i_z)
        self._kd_vel = (g.vel_d_xy, g.vel_d_xy, g.vel_d_z)
        # inner-loop constants in one tuple (roll and pitch share their gains)
        self._inner_k = (
            g.att_p_rp, g.att_p_yaw, g.rate_max_rp, g.rate_max_yaw, g.rate_p_rp, g.rate_p_yaw,
            g.rate_i_rp, g.rate_i_yaw, g.rate_i_max, self.dt, mixer.n * mixer.f_max,
        )  # fmt: skip
        self._kd_rate = (g.rate_d_rp, g.rate_d_rp, g.rate_d_yaw)
        self._rate_d_on = any(self._kd_rate)  # the rate D term (and its filter) is optional
        self._tan_tilt = math.tan(g.tilt_max)
        tau = 1.0 / (2.0 * math.pi * g.d_cutoff_hz)
        self._lpf_v = self.outer_dt / (self.outer_dt + tau)  # derivative filters, per tick
        self._lpf_w = self.dt / (self.dt + tau)
        self.reset()

    def reset(self, torque_trim: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0)) -> None:
        """Zero the integrators and filters; the rate integrator starts at ``torque_trim``.

        ``torque_trim`` [N m, body frame] is the steady torque the rotors must produce (e.g.
        the arm's gravity moment), so that a reset into hover is a true equilibrium. The next
        tick runs the outer loop.
        """
        g = self.gains
        self.i_vel: Vec3 = (0.0, 0.0, 0.0)
        self.a_ff: Vec3 = (0.0, 0.0, 0.0)
        trim = self.J_inv @ np.asarray(torque_trim, dtype=float)
        self.i_rate: Vec3 = _vec3(np.clip(trim, -g.rate_i_max, g.rate_i_max))
        self._v_prev: Vec3 | None = None
        self._w_prev: Vec3 | None = None
        self._dv: Vec3 = (0.0, 0.0, 0.0)
        self._dw: Vec3 = (0.0, 0.0, 0.0)
        self.F: Vec3 = (0.0, 0.0, self.mass * GRAVITY)
        self._b3: Vec3 = (0.0, 0.0, 1.0)
        self._R_sp = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
        self.thrust = self.mass * GRAVITY
        self.torque: Vec3 = (0.0, 0.0, 0.0)
        self.motors = self.mixer.mix_floats(self.thrust, 0.0, 0.0, 0.0)
        self._ticks = 0

    @property
    def outer_due(self) -> bool:
        """Whether the next tick runs the outer loop (every ``outer_every``-th tick)."""
        return self._ticks % self.outer_every == 0

    @property
    def R_sp(self) -> np.ndarray:
        """Desired attitude of the last tick (3x3 body-to-world rotation)."""
        return np.array(self._R_sp).reshape(3, 3)

    def update(
        self,
        p: np.ndarray,
        v: np.ndarray,
        R: np.ndarray,
        w: np.ndarray,
        p_ref: np.ndarray,
        v_ref: np.ndarray,
        yaw_ref: float,
        yaw_rate_ref: float = 0.0,
    ) -> np.ndarray:
        """One tick on arrays: the outer loop if due, then the inner loop; rotor thrusts [N].

        Args:
            p, v: position [m] and velocity [m/s] of the body origin, world frame.
            R: body-to-world rotation (3x3). w: body angular velocity [rad/s], body frame.
            p_ref, v_ref: position reference [m] and its velocity feed-forward [m/s].
            yaw_ref, yaw_rate_ref: heading reference [rad] and its rate [rad/s].
        """
        if self.outer_due:
            self.outer(_vec3(p), _vec3(v), _vec3(p_ref), _vec3(v_ref))
        R9 = np.asarray(R, dtype=float).ravel().tolist()
        return np.array(self.inner(R9, _vec3(w), float(yaw_ref), float(yaw_rate_ref)))

    def outer(
        self, p: Sequence[float], v: Sequence[float], p_ref: Sequence[float], v_ref: Sequence[float]
    ) -> None:
        """Position/velocity loop: sets the thrust-vector set-point ``F`` [N, world].

        Arguments as in ``update`` (3 floats each); runs with period ``outer_dt``.
        """
        g, dt, m = self.gains, self.outer_dt, self.mass
        kpx, kpy, kpz = self._kp_pos
        # position -> velocity set-point
        sx = v_ref[0] + kpx * (p_ref[0] - p[0])
        sy = v_ref[1] + kpy * (p_ref[1] - p[1])
        sz = v_ref[2] + kpz * (p_ref[2] - p[2])
        h = math.hypot(sx, sy)
        if h > g.vel_max_xy:
            scale = g.vel_max_xy / h
            sx, sy = sx * scale, sy * scale
        sz = min(max(sz, -g.vel_max_z), g.vel_max_z)
        # velocity PID -> acceleration (D on the low-passed measured acceleration)
        vx, vy, vz = v
        ex, ey, ez = sx - vx, sy - vy, sz - vz
        dx, dy, dz = self._dv
        if self._v_prev is not None:
            c, (ux, uy, uz) = self._lpf_v, self._v_prev
            dx += c * ((vx - ux) / dt - dx)
            dy += c * ((vy - uy) / dt - dy)
            dz += c * ((vz - uz) / dt - dz)
            self._dv = (dx, dy, dz)
        self._v_prev = (vx, vy, vz)
        (kx, ky, kz), (ix, iy, iz) = self._kp_vel, self.i_vel
        (dgx, dgy, dgz), (jx, jy, jz), lim = self._kd_vel, self._ki_vel, g.vel_i_max
        fax, fay, faz = self.a_ff
        ax, ay, az = kx * ex + ix - dgx * dx, ky * ey + iy - dgy * dy, kz * ez + iz - dgz * dz
        ax, ay, az = ax + fax, ay + fay, az + faz
        self.i_vel = (
            min(max(ix + jx * ex * dt, -lim), lim),
            min(max(iy + jy * ey * dt, -lim), lim),
            min(max(iz + jz * ez * dt, -lim), lim),
        )
        # thrust vector with tilt limit (vertical first)
        fx, fy = m * ax, m * ay
        fz = max(m * az + m * GRAVITY, 0.1 * m * GRAVITY)
        fh, fh_max = math.hypot(fx, fy), fz * self._tan_tilt
        if fh > fh_max:
            scale = fh_max / fh
            fx, fy = fx * scale, fy * scale
        self.F = (fx, fy, fz)
        n = math.sqrt(fx * fx + fy * fy + fz * fz)
        self._b3 = (fx / n, fy / n, fz / n)

    def inner(
        self, R: Sequence[float], w: Sequence[float], yaw_ref: float, yaw_rate_ref: float
    ) -> list[float]:
        """Attitude + rate loop and mixing (every tick): rotor thrusts [N].

        Args:
            R: body-to-world rotation, 9 floats row by row. w: body rates [rad/s] (3 floats).
            yaw_ref, yaw_rate_ref: heading reference [rad] and its rate [rad/s].
        """
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = R
        wx, wy, wz = w
        ka, ka_z, wm, wm_z, kp, kp_z, ki, ki_z, lim, dt, thrust_max = self._inner_k
        # desired attitude: columns b1, b2, b3 with b3 along F, b2 = b3 x heading
        b3x, b3y, b3z = self._b3
        c, s = math.cos(yaw_ref), math.sin(yaw_ref)
        b2x, b2y, b2z = -b3z * s, b3z * c, b3x * s - b3y * c
        n = math.sqrt(b2x * b2x + b2y * b2y + b2z * b2z)
        b2x, b2y, b2z = b2x / n, b2y / n, b2z / n
        b1x, b1y, b1z = b2y * b3z - b2z * b3y, b2z * b3x - b2x * b3z, b2x * b3y - b2y * b3x
        self._R_sp = (b1x, b2x, b3x, b1y, b2y, b3y, b1z, b2z, b3z)
        # attitude P on e_R = vee(E - E^T) / 2, E = R_sp^T R: E_ij = b_i . (column j of R);
        # rate set-point = -k e_R + yaw-rate feed-forward, clipped
        ex = 0.5 * ((b3x * r01 + b3y * r11 + b3z * r21) - (b2x * r02 + b2y * r12 + b2z * r22))
        ey = 0.5 * ((b1x * r02 + b1y * r12 + b1z * r22) - (b3x * r00 + b3y * r10 + b3z * r20))
        ez = 0.5 * ((b2x * r00 + b2y * r10 + b2z * r20) - (b1x * r01 + b1y * r11 + b1z * r21))
        sx, sy, sz = (
            -ka * ex + r20 * yaw_rate_ref,
            -ka * ey + r21 * yaw_rate_ref,
            -ka_z * ez + r22 * yaw_rate_ref,
        )
        sx = wm if sx > wm else (-wm if sx < -wm else sx)
        sy = wm if sy > wm else (-wm if sy < -wm else sy)
        sz = wm_z if sz > wm_z else (-wm_z if sz < -wm_z else sz)
        # rate PI(D) -> angular acceleration; the integrator is clipped to +-lim
        ex, ey, ez = sx - wx, sy - wy, sz - wz
        ix, iy, iz = self.i_rate
        ax, ay, az = kp * ex + ix, kp * ey + iy, kp_z * ez + iz
        if self._rate_d_on:
            ax, ay, az = self._rate_d(wx, wy, wz, ax, ay, az)
        ix, iy, iz = ix + ki * ex * dt, iy + ki * ey * dt, iz + ki_z * ez * dt
        self.i_rate = (
            lim if ix > lim else (-lim if ix < -lim else ix),
            lim if iy > lim else (-lim if iy < -lim else iy),
            lim if iz > lim else (-lim if iz < -lim else iz),
        )
        # torque = J alpha + w x (J w); collective thrust = F . b3 (current body z)
        j00, j01, j02, j10, j11, j12, j20, j21, j22 = self._J
        hx = j00 * wx + j01 * wy + j02 * wz
        hy = j10 * wx + j11 * wy + j12 * wz
        hz = j20 * wx + j21 * wy + j22 * wz
        tx = j00 * ax + j01 * ay + j02 * az + (wy * hz - wz * hy)
        ty = j10 * ax + j11 * ay + j12 * az + (wz * hx - wx * hz)
        tz = j20 * ax + j21 * ay + j22 * az + (wx * hy - wy * hx)
        self.torque = (tx, ty, tz)
        fx, fy, fz = self.F
        thrust = fx * r02 + fy * r12 + fz * r22
        self.thrust = thrust = (
            thrust_max if thrust > thrust_max else (thrust if thrust > 0.0 else 0.0)
        )
        self._ticks += 1
        self.motors = self.mixer.mix_floats(thrust, tx, ty, tz)
        return self.motors

    def _rate_d(self, wx: float, wy: float, wz: float, ax: float, ay: float, az: float) -> Vec3:
        """Rate D term: ``alpha - k_d dw`` with ``dw`` the low-passed angular acceleration."""
        dx, dy, dz = self._dw
        if self._w_prev is not None:
            c, dt, (ux, uy, uz) = self._lpf_w, self.dt, self._w_prev
            dx += c * ((wx - ux) / dt - dx)
            dy += c * ((wy - uy) / dt - dy)
            dz += c * ((wz - uz) / dt - dz)
            self._dw = (dx, dy, dz)
        self._w_prev = (wx, wy, wz)
        kx, ky, kz = self._kd_rate
        return ax - kx * dx, ay - ky * dy, az - kz * dz
