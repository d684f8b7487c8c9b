"""Sinusoids along one direction, phase after phase (paper Sec. VI-A)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import casadi as ca
import numpy as np

from aeromanip.config import Table, to_floats
from aeromanip.errors import ConfigError
from aeromanip.references.base import (
    AXES,
    MAX_COORD,
    MAX_FREQUENCY_HZ,
    REFERENCES,
    Reference,
    as_times,
    direction,
    vec3,
)


@REFERENCES.register("sinusoids")
class SinusoidPhases(Reference):
    """Sinusoids along one direction, one per phase (paper Sec. VI-A, Fig. 2).

    Phase ``i`` (start ``t_i``, duration ``T_i``, amplitude ``a_i`` [m], frequency
    ``f_i`` [Hz]) gives ``p(t) = o_i + d a_i sin(2 pi f_i (t - t_i))``, where ``d`` is the
    unit direction and ``o_0 = center``. Each phase starts at zero phase and at the
    point where the previous one ended (``o_{i+1} = p(t_i + T_i)``), so the reference is
    continuous; when every phase lasts a whole number of half periods all ``o_i``
    equal ``center``. After the last phase the end point is held.
    """

    def __init__(
        self,
        center: Sequence[float] | np.ndarray,
        axis: int | str | Sequence[float] | np.ndarray,
        phases: Sequence[tuple[float, float, float]],
        *,
        name: str = "reference",
    ) -> None:
        self.center = vec3(center, f"{name}.center")
        self.direction = direction(axis, f"{name}.axis")
        if len(phases) == 0:
            raise ConfigError(f"{name}.phases: at least one phase is required")
        rows = []
        for i, ph in enumerate(phases):
            where = f"{name}.phases[{i}]"
            if len(ph) != 3:
                raise ConfigError(f"{where}: expected (duration, amplitude, frequency), got {ph!r}")
            dur, amp, freq = (float(v) for v in ph)
            if not (math.isfinite(dur) and dur > 0):
                raise ConfigError(f"{where}.duration: must be > 0 s, got {dur!r}")
            if not (math.isfinite(amp) and abs(amp) <= MAX_COORD):
                raise ConfigError(
                    f"{where}.amplitude: must be within +-{MAX_COORD:g} m, got {amp!r}"
                )
            if not (math.isfinite(freq) and 0 <= freq <= MAX_FREQUENCY_HZ):
                raise ConfigError(
                    f"{where}.frequency: must be in [0, {MAX_FREQUENCY_HZ:g}] Hz, got {freq!r}"
                )
            rows.append((dur, amp, freq))
        self.phases: tuple[tuple[float, float, float], ...] = tuple(rows)
        ph_arr = np.array(rows)
        self._starts = np.concatenate([[0.0], np.cumsum(ph_arr[:, 0])[:-1]])
        end_offsets = ph_arr[:, 1] * np.sin(2 * np.pi * ph_arr[:, 2] * ph_arr[:, 0])
        self._offsets = np.concatenate([[0.0], np.cumsum(end_offsets)])  # along d [m]
        self.duration = float(ph_arr[:, 0].sum())

    def motion_phases(self) -> list[tuple[float, float, np.ndarray]]:
        """Each phase's start and end [s], along the reference's direction."""
        ends = [*self.phase_starts[1:], self.duration]
        return [
            (float(t0), float(t1), self.direction)
            for t0, t1 in zip(self.phase_starts, ends, strict=True)
        ]

    @property
    def phase_starts(self) -> np.ndarray:
        """Start time [s] of each phase."""
        return self._starts.copy()

    def sample(self, times: np.ndarray | Sequence[float]) -> np.ndarray:
        """Reference positions [m] at ``times`` [s], shape (len(times), 3)."""
        t = np.clip(as_times(times), 0.0, self.duration)
        i = np.clip(np.searchsorted(self._starts, t, side="right") - 1, 0, len(self.phases) - 1)
        ph = np.array(self.phases)
        s = self._offsets[i] + ph[i, 1] * np.sin(2 * np.pi * ph[i, 2] * (t - self._starts[i]))
        return self.center + s[:, None] * self.direction

    def expression(self, t: ca.SX) -> ca.SX:
        """``sample`` at one time ``t`` [s] as a CasADi expression (3,)."""
        t = ca.fmin(ca.fmax(t, 0.0), self.duration)
        s = ca.SX(0.0)
        for i, (_, amp, freq) in enumerate(self.phases):
            start = self._starts[i]
            here = self._offsets[i] + amp * ca.sin(2 * np.pi * freq * (t - start))
            s = here if i == 0 else ca.if_else(t >= start, here, s)
        return ca.DM(self.center) + s * ca.DM(self.direction)

    @classmethod
    def from_table(cls, table: Table, base_dir: Path | None = None) -> SinusoidPhases:
        """Keys: ``center`` [m], ``axis`` ("x" | "y" | "z" | [dx, dy, dz]),
        ``phases = [{ duration [s], amplitude [m], frequency [Hz] }, ...]``."""
        center = table.floats("center", size=3)
        axis = _axis(table)
        phases = []
        for ph in table.tables("phases"):
            phases.append((ph.float("duration"), ph.float("amplitude"), ph.float("frequency")))
            ph.done()
        return cls(center, axis, phases, name=table.path or "reference")


def _axis(table: Table) -> int | np.ndarray:
    raw = table.raw("axis")
    if isinstance(raw, str):
        if raw not in AXES:
            raise ConfigError(
                f"{table.key('axis')}: {raw!r} is not one of {list(AXES)} or a 3-vector"
            )
        return AXES[raw]
    return np.array(to_floats(raw, table.key("axis"), size=3))
