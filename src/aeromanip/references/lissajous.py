"""A smooth periodic 3D loop (long flights)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import casadi as ca
import numpy as np

from aeromanip.config import Table
from aeromanip.errors import ConfigError
from aeromanip.references.base import MAX_FREQUENCY_HZ, REFERENCES, Reference, as_times, vec3

PHASE = (0.0, 0.0, 0.0)  # [rad] per axis
DURATION = 60.0  # [s] nominal run length


@REFERENCES.register("lissajous")
class Lissajous(Reference):
    """A smooth 3D loop: ``p(t) = center + amplitude * sin(2 pi frequency t + phase)``.

    ``amplitude`` [m], ``frequency`` [Hz] and ``phase`` [rad] are per axis (3,);
    ``duration`` [s] is the nominal run length (the curve is periodic, it does not stop).
    """

    def __init__(
        self,
        center: Sequence[float] | np.ndarray,
        amplitude: Sequence[float] | np.ndarray,
        frequency_hz: Sequence[float] | np.ndarray,
        phase: Sequence[float] | np.ndarray = PHASE,
        duration: float = DURATION,
        *,
        name: str = "reference",
    ) -> None:
        self.center = vec3(center, f"{name}.center")
        self.amplitude = vec3(amplitude, f"{name}.amplitude")
        self.frequency = vec3(frequency_hz, f"{name}.frequency", MAX_FREQUENCY_HZ)
        self.phase = vec3(phase, f"{name}.phase")
        if np.any(self.frequency < 0):
            raise ConfigError(
                f"{name}.frequency: must be in [0, {MAX_FREQUENCY_HZ:g}] Hz, "
                f"got {self.frequency.tolist()}"
            )
        if not (math.isfinite(duration) and duration > 0):
            raise ConfigError(f"{name}.duration: must be > 0 s, got {duration!r}")
        self.duration = float(duration)

    def sample(self, times: np.ndarray | Sequence[float]) -> np.ndarray:
        """Reference positions [m] at ``times`` [s], shape (len(times), 3)."""
        t = np.maximum(as_times(times), 0.0)
        arg = 2 * np.pi * t[:, None] * self.frequency + self.phase
        return self.center + self.amplitude * np.sin(arg)

    def expression(self, t: ca.SX) -> ca.SX:
        """``sample`` at one time ``t`` [s] as a CasADi expression (3,)."""
        arg = 2 * np.pi * ca.fmax(t, 0.0) * ca.DM(self.frequency) + ca.DM(self.phase)
        return ca.DM(self.center) + ca.DM(self.amplitude) * ca.sin(arg)

    @classmethod
    def from_table(cls, table: Table, base_dir: Path | None = None) -> Lissajous:
        """Keys: ``center``, ``amplitude`` [m], ``frequency`` [Hz] (3 each), optional
        ``phase`` [rad] (3), ``duration`` [s]."""
        center, amplitude = table.floats("center", size=3), table.floats("amplitude", size=3)
        frequency = table.floats("frequency", size=3)
        phase = table.floats("phase", PHASE, size=3)
        duration = table.float("duration", DURATION)
        return cls(center, amplitude, frequency, phase, duration, name=table.path or "reference")
