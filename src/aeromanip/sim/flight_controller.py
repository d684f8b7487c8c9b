"""A cascaded multirotor inner loop in the style of PX4 (pure NumPy, no simulator inside).

Per call of ``FlightController.update`` (one inner-loop tick, typically 500 Hz):

1. position P + velocity feed-forward -> velocity set-point (speed-limited);
2. velocity PID -> desired acceleration; desired force ``F = m (a + g e_z)`` with the tilt
   limited to ``tilt_max`` (vertical thrust has priority);
3. desired attitude: body z along ``F``, heading ``yaw_ref``;
4. attitude P on the geometric SO(3) error ``e_R = vee(R_d^T R - R^T R_d) / 2`` -> body-rate
   set-point (plus the yaw-rate feed-forward);
5. body-rate PID -> angular acceleration -> torque ``tau = J alpha + w x J w``; collective
   thrust ``T = F . b3``;
6. ``Mixer``: allocation-matrix pseudo-inverse, saturation to ``[0, f_max]`` giving roll/pitch
   priority over collective thrust, and collective thrust priority over yaw.

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

GRAVITY = 9.81  # [m/s^2]


def rotor_layout(rotors: int, arm_length: float) -> tuple[np.ndarray, np.ndarray]:
    """X layout: rotor xy positions ``(n, 2)`` [m] in the body frame and spin signs ``(n,)``.

    Rotor ``i`` (0-based) sits at angle ``pi/n + 2 pi i/n`` from body x (rotor 1 front-left
    for 4 rotors, counting counter-clockwise); spins alternate ``+1, -1, ...``: a ``+1`` rotor
    twists the body about +z by ``k_m`` times its thrust.
    """
    if rotors < 4 or rotors % 2:
        raise ConfigError(f"physics.rotors: must be an even integer >= 4, got {rotors}")
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

    def mix(self, thrust: float, torque: np.ndarray) -> np.ndarray:
        """Rotor thrusts [N]: roll/pitch are scaled down only if their span exceeds ``f_max``;
        the collective thrust is shifted to fit; yaw gets what is left."""
        B, f_max = self.B, self.f_max
        f_rp = B[:, 1] * torque[0] + B[:, 2] * torque[1]
        span = f_rp.max() - f_rp.min()
        if span > f_max:
            f_rp = f_rp * (f_max / span)
        f = B[:, 0] * thrust + f_rp
        low, high = f.min(), f.max()  # span <= f_max: one uniform shift fits both bounds
        if low < 0.0:
            f = f - low
        elif high > f_max:
            f = f - (high - f_max)
        f_y = B[:, 3] * torque[2]
        alpha = 1.0
        up, down = f_y > 1e-12, f_y < -1e-12
        if up.any():
            alpha = min(alpha, float(np.min((f_max - f[up]) / f_y[up])))
        if down.any():
            alpha = min(alpha, float(np.min(f[down] / -f_y[down])))
        f = f + max(alpha, 0.0) * f_y
        return np.clip(f, 0.0, f_max)


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


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


class FlightController:
    """Cascaded position -> velocity -> attitude -> rate controller plus mixer.

    Args:
        mass: total vehicle mass [kg] (platform + arm).
        inertia: inertia about the body origin [kg m^2], ``(3,)`` diagonal or ``(3, 3)``.
        mixer: rotor allocation and saturation.
        dt: tick period [s].
        gains: ``FlightGains`` (defaults if ``None``).
    """

    def __init__(
        self,
        mass: float,
        inertia: Sequence[float] | np.ndarray,
        mixer: Mixer,
        dt: float,
        gains: FlightGains | None = None,
    ) -> None:
        J = np.asarray(inertia, dtype=float)
        self.J = np.diag(J) if J.ndim == 1 else J
        self.J_inv = np.linalg.inv(self.J)
        self.mass = float(mass)
        self.mixer = mixer
        self.dt = float(dt)
        self.gains = gains or FlightGains()
        g = self.gains
        self._kp_pos = np.array([g.pos_p_xy, g.pos_p_xy, g.pos_p_z])
        self._kp_vel = np.array([g.vel_p_xy, g.vel_p_xy, g.vel_p_z])
        self._ki_vel = np.array([g.vel_i_xy, g.vel_i_xy, g.vel_i_z])
        self._kd_vel = np.array([g.vel_d_xy, g.vel_d_xy, g.vel_d_z])
        self._kp_att = np.array([g.att_p_rp, g.att_p_rp, g.att_p_yaw])
        self._kp_rate = np.array([g.rate_p_rp, g.rate_p_rp, g.rate_p_yaw])
        self._ki_rate = np.array([g.rate_i_rp, g.rate_i_rp, g.rate_i_yaw])
        self._kd_rate = np.array([g.rate_d_rp, g.rate_d_rp, g.rate_d_yaw])
        self._rate_max = np.array([g.rate_max_rp, g.rate_max_rp, g.rate_max_yaw])
        tau = 1.0 / (2.0 * math.pi * g.d_cutoff_hz)
        self._lpf = self.dt / (self.dt + tau)
        self.reset()

    def reset(self, torque_trim: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0)) -> None:
        """Zero the integrators and filters; the rate integrator starts at ``torque_trim``.

        ``torque_trim`` [N m, body frame] is the steady torque the rotors must produce (e.g.
        the arm's gravity moment), so that a reset into hover is a true equilibrium.
        """
        g = self.gains
        self.i_vel = np.zeros(3)
        trim = self.J_inv @ np.asarray(torque_trim, dtype=float)
        self.i_rate = np.clip(trim, -g.rate_i_max, g.rate_i_max)
        self._v_prev: np.ndarray | None = None
        self._w_prev: np.ndarray | None = None
        self._dv = np.zeros(3)
        self._dw = np.zeros(3)
        self.thrust = self.mass * GRAVITY
        self.torque = np.zeros(3)
        self.R_sp = np.eye(3)
        self.motors = self.mixer.mix(self.thrust, self.torque)

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
        """One tick: rotor thrusts [N] from the state and the references.

        Args:
            p, v: position [m] and velocity [m/s] of the body origin, world frame.
            R: body-to-world rotation (3x3). w: body angular velocity [rad/s], body frame.
            p_ref, v_ref: position reference [m] and its velocity feed-forward [m/s].
            yaw_ref, yaw_rate_ref: heading reference [rad] and its rate [rad/s].
        """
        g, dt = self.gains, self.dt
        # position -> velocity set-point
        v_sp = v_ref + self._kp_pos * (p_ref - p)
        h = math.hypot(v_sp[0], v_sp[1])
        if h > g.vel_max_xy:
            v_sp[:2] *= g.vel_max_xy / h
        v_sp[2] = min(max(v_sp[2], -g.vel_max_z), g.vel_max_z)
        # velocity PID -> acceleration
        e_v = v_sp - v
        if self._v_prev is not None:
            self._dv += self._lpf * ((v - self._v_prev) / dt - self._dv)
        self._v_prev = v.copy()
        a_sp = self._kp_vel * e_v + self.i_vel - self._kd_vel * self._dv
        self.i_vel = np.clip(self.i_vel + self._ki_vel * e_v * dt, -g.vel_i_max, g.vel_i_max)
        # thrust vector with tilt limit (vertical first)
        F = self.mass * a_sp
        F[2] = max(F[2] + self.mass * GRAVITY, 0.1 * self.mass * GRAVITY)
        fh = math.hypot(F[0], F[1])
        fh_max = F[2] * math.tan(g.tilt_max)
        if fh > fh_max:
            F[:2] *= fh_max / fh
        # desired attitude
        b3 = F / math.sqrt(F @ F)
        c = np.array([math.cos(yaw_ref), math.sin(yaw_ref), 0.0])
        b2 = _cross(b3, c)
        b2 /= math.sqrt(b2 @ b2)
        R_sp = np.column_stack([_cross(b2, b3), b2, b3])
        self.R_sp = R_sp
        # attitude P on the SO(3) error -> rate set-point
        E = R_sp.T @ R
        E = E - E.T
        e_R = 0.5 * np.array([E[2, 1], E[0, 2], E[1, 0]])
        w_sp = -self._kp_att * e_R + R[2, :] * yaw_rate_ref
        w_sp = np.clip(w_sp, -self._rate_max, self._rate_max)
        # rate PID -> torque
        e_w = w_sp - w
        if self._w_prev is not None:
            self._dw += self._lpf * ((w - self._w_prev) / dt - self._dw)
        self._w_prev = w.copy()
        alpha = self._kp_rate * e_w + self.i_rate - self._kd_rate * self._dw
        self.i_rate = np.clip(self.i_rate + self._ki_rate * e_w * dt, -g.rate_i_max, g.rate_i_max)
        Jw = self.J @ w
        self.torque = self.J @ alpha + _cross(w, Jw)
        self.thrust = float(min(max(F @ R[:, 2], 0.0), self.mixer.n * self.mixer.f_max))
        self.motors = self.mixer.mix(self.thrust, self.torque)
        return self.motors
