"""Identify the inner loops' rate response from step responses (``aeromanip identify``).

For each DoF in turn, the simulator hovers at the start state, then holds a step of
that DoF's rate command (the others zero) and its actual rate (``Simulator.rates``) is
recorded. A first-order response ``r(t) = s (1 - exp(-t / tau))`` is fitted to each
record by least squares in ``tau``; the result is the NMPC's ``[controller.response]``
(``nmpc.model``). How well the model then predicts the position reached is reported
beside the paper's model (``tau = 0``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.nmpc.model import MAX_TAU
from aeromanip.sim.base import Simulator

SAMPLE_S = 0.01  # [s] the record's sampling period
SETTLE_S = 1.0  # [s] hover before each step
GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass
class StepResponse:
    """One DoF's record: times [s] from the step, commanded step ``s``, actual rates and
    positions (relative to the step's start) [m, rad; /s]."""

    dof: str
    step: float
    t: np.ndarray
    rate: np.ndarray
    position: np.ndarray


@dataclass
class Fit:
    """The first-order fit of one step response.

    Attributes:
        tau: the time constant [s].
        rate_rms: RMS rate error of the fit [unit/s].
        r2: share of the rate's variance the fit explains.
        position_rms: RMS error of the position predicted by the fitted model [unit].
        position_rms_0: the same predicted with ``tau = 0`` [unit].
    """

    dof: str
    tau: float
    rate_rms: float
    r2: float
    position_rms: float
    position_rms_0: float


def record_step(
    sim: Simulator, x0: np.ndarray, dof: int, name: str, step: float, duration: float
) -> StepResponse:
    """Hover at ``x0``, then command rate ``step`` on DoF ``dof`` for ``duration`` [s]."""
    nx = len(x0)
    sim.reset(x0)
    start = np.asarray(x0, dtype=float).copy()
    hold = round(SETTLE_S / SAMPLE_S)
    zero = np.zeros(nx)
    for _ in range(hold):
        sim.advance(zero, start, SAMPLE_S)
    u = np.zeros(nx)
    u[dof] = step
    x_start = sim.true_state()[dof]
    n = round(duration / SAMPLE_S)
    t, rate, pos = np.zeros(n + 1), np.zeros(n + 1), np.zeros(n + 1)
    rates = sim.rates()
    if rates is None:
        raise ConfigError(f"identify: the {sim.kind} simulator does not measure rates")
    rate[0] = rates[dof]
    for k in range(1, n + 1):
        sim.advance(u, start, SAMPLE_S)
        start = start + SAMPLE_S * u  # the ramp goes on (a held command)
        t[k] = k * SAMPLE_S
        rate[k] = sim.rates()[dof]
        pos[k] = sim.true_state()[dof] - x_start
    return StepResponse(name, step, t, rate, pos)


def first_order(t: np.ndarray, step: float, tau: float) -> tuple[np.ndarray, np.ndarray]:
    """Rate and position from rest of a first-order response to ``step`` (``nmpc.model``)."""
    if tau <= 0:
        return np.full_like(t, step), step * t
    e = np.exp(-t / tau)
    return step * (1.0 - e), step * (t - tau * (1.0 - e))


def fit_first_order(rec: StepResponse) -> Fit:
    """The ``tau`` in ``[0, MAX_TAU]`` of least rate error (golden-section on ``log tau``
    after a coarse grid; the squared error is smooth and, in practice, unimodal)."""

    def sse(log_tau: float) -> float:
        model_rate = first_order(rec.t[1:], rec.step, math.exp(log_tau))[0]
        return float(np.sum((model_rate - rec.rate[1:]) ** 2))

    grid = np.linspace(math.log(1e-4), math.log(MAX_TAU), 60)
    best = int(np.argmin([sse(g) for g in grid]))
    lo, hi = grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]
    for _ in range(60):
        a, b = hi - GOLDEN * (hi - lo), lo + GOLDEN * (hi - lo)
        lo, hi = (lo, b) if sse(a) <= sse(b) else (a, hi)
    tau = math.exp(0.5 * (lo + hi))
    tau = 0.0 if tau < 1e-3 else tau  # below a millisecond: followed at once
    rate, pos = first_order(rec.t, rec.step, tau)
    resid = rate[1:] - rec.rate[1:]
    var = float(np.sum((rec.rate[1:] - rec.rate[1:].mean()) ** 2))
    return Fit(
        rec.dof,
        tau,
        float(np.sqrt(np.mean(resid**2))),
        1.0 - float(np.sum(resid**2)) / var if var > 0 else 1.0,
        float(np.sqrt(np.mean((pos - rec.position) ** 2))),
        float(np.sqrt(np.mean((first_order(rec.t, rec.step, 0.0)[1] - rec.position) ** 2))),
    )
