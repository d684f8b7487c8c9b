"""What the NMPC measures of the simulated vehicle: the true state plus a noise model.

White noise of std ``s`` per DoF at each reading is a motion-capture sample fed straight
to the NMPC. A flight controller's estimate is smoother: it fuses those samples (at its
position-loop rate ``1 / h``) with its inertial sensors; with the inertial sensors taken
as ideal its error is the measurement noise through a first-order filter of time constant
``T``: ``e <- a e + (1 - a) n`` at every sample, ``a = exp(-h / T)``, of stationary std
``s sqrt((1 - a) / (1 + a))``. The error is drawn exactly over the samples between two
readings, so it does not depend on how often the NMPC reads it.
"""

from __future__ import annotations

import math

import numpy as np


class FeedbackNoise:
    """The error of the state fed back (module docstring).

    Args:
        std: per DoF, the measurement noise std [m, rad].
        filter_s: the estimator's time constant ``T`` [s]; 0: white at each reading.
        sample_hz: the rate of the measurements fused by the estimator [Hz].
        seed: seed of the generator (the same seed, the same noise).
    """

    def __init__(self, std: np.ndarray, filter_s: float, sample_hz: float, seed: int) -> None:
        self.std = np.asarray(std, dtype=float)
        self.filter_s, self.sample_hz = float(filter_s), float(sample_hz)
        self.rng = np.random.default_rng(seed)
        self._a = a = math.exp(-1.0 / (sample_hz * filter_s)) if filter_s > 0 else 0.0
        self._time = 0.0
        self._error = np.zeros(self.std.size)
        if filter_s > 0:  # at the stationary distribution from the start
            self._error = self.std * math.sqrt((1 - a) / (1 + a)) * self._normal()

    def _normal(self) -> np.ndarray:
        return self.rng.normal(size=self.std.size)

    def error(self, time: float) -> np.ndarray:
        """The error of a reading at ``time`` [s] (not before the last reading's)."""
        if self.filter_s <= 0:  # white; per DoF group, in the generator's historic order
            return np.array([self.rng.normal(0.0, s) if s > 0 else 0.0 for s in self.std])
        a, m = self._a, round((time - self._time) * self.sample_hz)
        spread = (1 - a) * math.sqrt((1 - a ** (2 * m)) / (1 - a * a))
        self._error = a**m * self._error + self.std * spread * self._normal()
        self._time = time
        return self._error.copy()
