"""The NMPC's prediction model: how the state follows the commanded rates.

The paper's model (eq. 3) integrates the command, ``x[k+1] = x[k] + dt u[k]``: the inner
loops follow a rate command at once. A real inner loop follows it with a lag; when the
control period is short against that lag (10-50 Hz), each DoF's actual rate ``r`` may be
modelled as a first-order response to its command with a time constant ``tau`` [s],
``dr/dt = (u - r) / tau``. Holding ``u`` over a period ``h`` (zero-order hold), exactly::

    r(h) = u + a (r - u),                   a = exp(-h / tau)
    x(h) = x + h u + tau (1 - a) (r - u)

``tau = 0`` is the paper's model. The NMPC's augmented state carries the previous command
``v`` (for the control-rate cost and the command-rate bounds) and the actual rates of the
DoFs that lag (``tau > 0``; the others' rate is their command): ``z = [x; v; r_lagged]``,
and ``z[k+1] = A z[k] + B u[k]``. Leaving a DoF whose lag is far below the control period
at ``tau = 0`` keeps the state, and the QPs, smaller.
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError

MAX_TAU = 10.0  # [s] a slower response is not a rate loop
SHORT_ROLLOUT = 8  # steps up to which a rollout with rate responses is a loop, not a filter


def _response_terms(tau: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Per DoF ``a = exp(-h / tau)`` and ``c = tau (1 - a)`` (both 0 where ``tau = 0``)."""
    a = np.zeros_like(tau)
    pos = tau > 0
    a[pos] = np.exp(-h / tau[pos])
    return a, tau * (1.0 - a)


class RateModel:
    """The linear prediction model of the augmented state (module docstring).

    Args:
        nx: state size.
        dt: control period [s].
        tau: per DoF, the time constant of the rate response [s] (0: follows at once);
            ``None``: the paper's model for every DoF.
    """

    def __init__(self, nx: int, dt: float, tau: np.ndarray | None = None) -> None:
        self.nx, self.dt = nx, float(dt)
        self.tau = np.zeros(nx) if tau is None else np.asarray(tau, dtype=float).ravel()
        if self.tau.shape != (nx,):
            raise ConfigError(f"response.tau: expected {nx} values, got {self.tau.size}")
        if not np.all(np.isfinite(self.tau)) or np.any(self.tau < 0) or np.any(self.tau > MAX_TAU):
            raise ConfigError(f"response.tau: must be in [0, {MAX_TAU}] s, got {self.tau}")
        #: the DoFs whose actual rate is part of the state (``tau > 0``)
        self.lagged = np.flatnonzero(self.tau > 0)
        self.has_response = bool(self.lagged.size)
        self.nz = 2 * nx + self.lagged.size
        self.A, self.B = self.matrices(self.dt)
        self._filters: dict[int, np.ndarray] = {}  # _lag_filter's, by rollout length

    def matrices(self, h: float) -> tuple[np.ndarray, np.ndarray]:
        """``A`` (nz, nz) and ``B`` (nz, nx) of holding a command for ``h`` [s]."""
        nx, eye, lag = self.nx, np.eye(self.nx), self.lagged
        A, B = np.zeros((self.nz, self.nz)), np.zeros((self.nz, nx))
        A[:nx, :nx] = eye
        B[:nx] = h * eye
        B[nx : 2 * nx] = eye  # v[k+1] = u[k]
        if self.has_response:
            a, c = _response_terms(self.tau[lag], h)
            rows = np.arange(lag.size)
            A[lag, 2 * nx + rows] = c
            B[lag, lag] -= c
            A[2 * nx + rows, 2 * nx + rows] = a
            B[2 * nx + rows, lag] = 1.0 - a
        return A, B

    def next_sx(self, z: Any, u: Any) -> ca.SX:
        """``z[k+1]`` as an expression (element-wise: no structural zeros multiplied)."""
        nx = self.nx
        x_next = z[:nx] + self.dt * u
        if not self.has_response:
            return ca.vertcat(x_next, u)
        lag = self.lagged.tolist()
        a, c = _response_terms(self.tau[self.lagged], self.dt)
        dr = z[2 * nx :] - u[lag]  # actual minus commanded rate, lagged DoFs
        x_next[lag] = x_next[lag] + ca.DM(c) * dr
        return ca.vertcat(x_next, u, u[lag] + ca.DM(a) * dr)

    def initial(
        self, x0: np.ndarray, u_prev: np.ndarray, rates: np.ndarray | None = None
    ) -> np.ndarray:
        """The augmented state ``z0`` from the actual rates ``rates`` (nx; default
        ``u_prev``, as if followed at once)."""
        r0 = u_prev if rates is None else rates
        return np.concatenate([x0, u_prev, np.asarray(r0, dtype=float)[self.lagged]])

    def rates_of(self, z: np.ndarray) -> np.ndarray:
        """The actual rates (nx) in an augmented state: the lagged DoFs' from ``z``, the
        others' their last command ``v``."""
        nx = self.nx
        r = np.array(z[nx : 2 * nx], dtype=float)
        r[self.lagged] = z[2 * nx :]
        return r

    def rollout(self, z0: np.ndarray, U: np.ndarray) -> np.ndarray:
        """The augmented states (N+1, nz) under commands ``U`` (N, nx)."""
        Z = np.empty((len(U) + 1, self.nz))
        Z[0] = z0
        nx, U = self.nx, np.asarray(U, dtype=float)
        if self.has_response and len(U) <= SHORT_ROLLOUT:  # a filter costs more here
            for k, u in enumerate(U):
                Z[k + 1] = self.A @ Z[k] + self.B @ u
            return Z
        step = self.dt * U  # x[k+1] - x[k], before the lag's share
        Z[1:, nx : 2 * nx] = U  # v[k] = u[k-1]
        if self.has_response:  # per lagged DoF r[k+1] = a r[k] + (1 - a) u[k]: a filter
            lag = self.lagged
            c = _response_terms(self.tau[lag], self.dt)[1]
            inputs = np.concatenate([z0[None, 2 * nx :], U[:, lag]]).T[:, :, None]
            R = (self._lag_filter(len(U)) @ inputs)[:, :, 0].T  # (n, lagged): r[1..n]
            Z[1:, 2 * nx :] = R
            before = np.concatenate([z0[None, 2 * nx :], R[:-1]])  # r[0..n-1]
            step[:, lag] += c * (before - U[:, lag])
        Z[1:, :nx] = z0[:nx] + np.cumsum(step, axis=0)
        return Z

    def _lag_filter(self, n: int) -> np.ndarray:
        """Per lagged DoF the map (n, 1 + n) from ``[r[0], u[0..n-1]]`` to ``r[1..n]``
        (``a^(k+1)`` on ``r[0]``, ``(1 - a) a^(k-j)`` on ``u[j]``, ``j <= k``), shape
        (lagged, n, 1 + n), ``a = exp(-dt / tau)``; built once per length."""
        cache = self._filters
        if n not in cache:
            a = _response_terms(self.tau[self.lagged], self.dt)[0]
            k = np.arange(n)[:, None]
            j = np.arange(n)[None, :]
            power = np.where(j <= k, k - j, 0)[None]  # (1, n, n)
            aa = a[:, None, None]
            gain = np.where(j <= k, (1.0 - aa) * aa**power, 0.0)
            cache[n] = np.concatenate([aa ** (k[None] + 1), gain], axis=2)
        return cache[n]

    def reach(self, z0: np.ndarray, max_change: np.ndarray) -> np.ndarray:
        """Per DoF, a bound [m, rad] on the distance travelled while the command is brought
        to zero as fast as allowed (``max_change`` per step): no rate exceeds the larger
        of the actual one and the command, ``m``, until the command is zero (``n`` steps,
        one held), and a lagging rate then covers at most ``m tau``."""
        nx = self.nx
        u = np.abs(z0[nx : 2 * nx])
        m = np.maximum(u, np.abs(self.rates_of(z0)))
        with np.errstate(invalid="ignore", divide="ignore"):
            n = np.where(u > 0, np.ceil(u / max_change), 0.0)
        return m * (self.dt * (n + 1.0) + self.tau)

    def recovery(
        self,
        z0: np.ndarray,
        steps: int,
        max_change: np.ndarray,
        box: tuple[np.ndarray, np.ndarray],
        rate_limits: tuple[np.ndarray, np.ndarray],
    ) -> np.ndarray:
        """The states ``x[1..steps]`` (steps, nx) of a plan that exists from any ``z0``:
        at each step, per DoF, the command that puts the next state in the ``box``
        (nearest to it if none can) and is nearest to zero among those, within the rate
        bounds ``rate_limits`` and ``max_change`` of the last command (``inf``: any)."""
        nx, (lo, hi), (u_lo, u_hi) = self.nx, box, rate_limits
        a, c = _response_terms(self.tau, self.dt)
        gain = self.dt - c  # x[k+1] = x[k] + c r[k] + gain u[k]; gain > 0
        x = np.array(z0[:nx], dtype=float)
        u = np.array(z0[nx : 2 * nx], dtype=float)
        r = self.rates_of(np.asarray(z0, dtype=float))
        out = np.empty((steps, nx))
        for k in range(steps):
            base = x + c * r
            f_lo, f_hi = np.maximum(u - max_change, u_lo), np.minimum(u + max_change, u_hi)
            d_lo, d_hi = (lo - base) / gain, (hi - base) / gain
            lo_k, hi_k = np.maximum(d_lo, f_lo), np.minimum(d_hi, f_hi)
            u = np.where(lo_k <= hi_k, np.clip(0.0, lo_k, hi_k), np.where(d_hi < f_lo, f_lo, f_hi))
            x = base + gain * u
            r = u + a * (r - u)
            out[k] = x
        return out

    def predict(self, z0: np.ndarray, u: np.ndarray, h: float) -> np.ndarray:
        """``z`` after holding ``u`` for ``h`` [s] (e.g. over the computation delay)."""
        if h <= 0:
            return np.asarray(z0, dtype=float).copy()
        A, B = self.matrices(h)
        return A @ z0 + B @ u
