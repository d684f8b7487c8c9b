"""End-effector reference trajectories in the world frame (metres, seconds).

Every reference answers ``position(t)`` (3,) and the vectorised ``sample(times)``
(len(times), 3). Before ``t = 0`` a reference holds its initial point; after its
``duration`` the smooth kinds hold their end point (``Lissajous`` keeps looping).

Kinds: ``Constant``, ``SinusoidPhases`` (paper Sec. VI-A), ``Waypoints`` (quintic,
minimum-jerk segments, Sec. VI-B/C), ``Csv`` (tabulated, linear interpolation) and
``Lissajous`` (a smooth 3D loop for long flights). ``reference_from_table`` builds one
from a TOML table such as ``{ kind = "waypoints", points = [[...], ...], times = [...] }``.
"""

from __future__ import annotations

import csv
import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from aeromanip.config import Table, to_floats
from aeromanip.errors import ConfigError

AXES: dict[str, int] = {"x": 0, "y": 1, "z": 2}
KINDS: tuple[str, ...] = ("constant", "sinusoids", "waypoints", "csv", "lissajous")


class Reference(ABC):
    """An end-effector position reference p(t) in the world frame [m]."""

    duration: float
    """Time [s] after which the reference no longer changes (or the nominal run length)."""

    def position(self, t: float) -> np.ndarray:
        """The reference position [m] at time ``t`` [s], shape (3,)."""
        return self.sample(np.array([float(t)]))[0]

    @abstractmethod
    def sample(self, times: np.ndarray | Sequence[float]) -> np.ndarray:
        """Reference positions [m] at ``times`` [s], shape (len(times), 3)."""


def _times(times: np.ndarray | Sequence[float]) -> np.ndarray:
    return np.atleast_1d(np.asarray(times, dtype=float)).reshape(-1)


def _vec3(v: Any, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=float).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ConfigError(f"{name}: expected 3 finite numbers, got {v!r}")
    return a


def _direction(axis: int | str | Sequence[float] | np.ndarray, name: str) -> np.ndarray:
    """A unit vector from an axis index (0..2), an axis name ("x", "y", "z") or a vector."""
    if isinstance(axis, str):
        if axis not in AXES:
            raise ConfigError(f"{name}: {axis!r} is not one of {list(AXES)} or a 3-vector")
        axis = AXES[axis]
    if isinstance(axis, int | np.integer) and not isinstance(axis, bool):
        if not 0 <= int(axis) <= 2:
            raise ConfigError(f"{name}: axis index must be 0, 1 or 2, got {axis}")
        d = np.zeros(3)
        d[int(axis)] = 1.0
        return d
    d = _vec3(axis, name)
    norm = float(np.linalg.norm(d))
    if norm < 1e-12:
        raise ConfigError(f"{name}: direction must be non-zero, got {list(d)}")
    return d / norm


class Constant(Reference):
    """A fixed point [m]; ``duration`` [s] is only the nominal run length."""

    def __init__(
        self, point: Sequence[float] | np.ndarray, duration: float = 0.0, *, name: str = "reference"
    ) -> None:
        self.point = _vec3(point, f"{name}.point")
        if not math.isfinite(duration) or duration < 0:
            raise ConfigError(f"{name}.duration: must be >= 0, got {duration!r}")
        self.duration = float(duration)

    def sample(self, times: np.ndarray | Sequence[float]) -> np.ndarray:
        """Reference positions [m] at ``times`` [s], shape (len(times), 3)."""
        return np.tile(self.point, (_times(times).size, 1))


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
        self.center = _vec3(center, f"{name}.center")
        self.direction = _direction(axis, f"{name}.axis")
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
            if not math.isfinite(amp):
                raise ConfigError(f"{where}.amplitude: must be finite, got {amp!r}")
            if not (math.isfinite(freq) and freq >= 0):
                raise ConfigError(f"{where}.frequency: must be >= 0 Hz, got {freq!r}")
            rows.append((dur, amp, freq))
        self.phases: tuple[tuple[float, float, float], ...] = tuple(rows)
        ph_arr = np.array(rows)
        self._starts = np.concatenate([[0.0], np.cumsum(ph_arr[:, 0])[:-1]])
        end_offsets = ph_arr[:, 1] * np.sin(2 * np.pi * ph_arr[:, 2] * ph_arr[:, 0])
        self._offsets = np.concatenate([[0.0], np.cumsum(end_offsets)])  # along d [m]
        self.duration = float(ph_arr[:, 0].sum())

    @property
    def phase_starts(self) -> np.ndarray:
        """Start time [s] of each phase."""
        return self._starts.copy()

    def sample(self, times: np.ndarray | Sequence[float]) -> np.ndarray:
        """Reference positions [m] at ``times`` [s], shape (len(times), 3)."""
        t = np.clip(_times(times), 0.0, self.duration)
        i = np.clip(np.searchsorted(self._starts, t, side="right") - 1, 0, len(self.phases) - 1)
        ph = np.array(self.phases)
        s = self._offsets[i] + ph[i, 1] * np.sin(2 * np.pi * ph[i, 2] * (t - self._starts[i]))
        return self.center + s[:, None] * self.direction


def _min_jerk(tau: np.ndarray) -> np.ndarray:
    """Quintic blend 10 tau^3 - 15 tau^4 + 6 tau^5: zero velocity/acceleration at 0 and 1."""
    return tau**3 * (10.0 + tau * (-15.0 + 6.0 * tau))


class Waypoints(Reference):
    """A C2 reference through waypoints [m], minimum-jerk (quintic) between each pair.

    Each segment starts and ends with zero velocity and acceleration and passes exactly
    through its waypoints at their times. Give either ``times`` [s] (strictly
    increasing, one per point; before ``times[0]`` the first point is held) or
    ``speed`` [m/s], the average speed of each segment, from which segment durations
    are derived (start at t = 0). ``hold_s`` [s]: with ``speed``, the dwell at every
    intermediate waypoint; in both cases the time the last point is held before
    ``duration`` ends. After the last waypoint the reference holds it.
    """

    def __init__(
        self,
        points: Sequence[Sequence[float]] | np.ndarray,
        times: Sequence[float] | np.ndarray | None = None,
        *,
        speed: float | None = None,
        hold_s: float = 0.0,
        name: str = "reference",
    ) -> None:
        pts = np.asarray(points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 1:
            raise ConfigError(f"{name}.points: expected a list of [x, y, z], got shape {pts.shape}")
        if not np.all(np.isfinite(pts)):
            raise ConfigError(f"{name}.points: must be finite numbers")
        if not (math.isfinite(hold_s) and hold_s >= 0):
            raise ConfigError(f"{name}.hold: must be >= 0 s, got {hold_s!r}")
        if (times is None) == (speed is None):
            raise ConfigError(f"{name}: give exactly one of 'times' and 'speed'")
        self.points = pts
        self.hold_s = float(hold_s)
        if times is not None:
            tk = np.asarray(times, dtype=float).reshape(-1)
            if tk.size != pts.shape[0]:
                raise ConfigError(
                    f"{name}.times: expected {pts.shape[0]} times (one per point), got {tk.size}"
                )
            if not np.all(np.isfinite(tk)):
                raise ConfigError(f"{name}.times: must be finite numbers")
            bad = np.nonzero(np.diff(tk) <= 0)[0]
            if bad.size:
                k = int(bad[0]) + 1
                raise ConfigError(
                    f"{name}.times[{k}]: times must be strictly increasing, "
                    f"got {tk[k - 1]!r} then {tk[k]!r}"
                )
            self.times = tk
            knot_t, knot_p = tk, pts
        else:
            assert speed is not None
            if not (math.isfinite(speed) and speed > 0):
                raise ConfigError(f"{name}.speed: must be > 0 m/s, got {speed!r}")
            knot_t_list, knot_p_list, arrivals = [0.0], [pts[0]], [0.0]
            t = 0.0
            for k in range(1, pts.shape[0]):
                dist = float(np.linalg.norm(pts[k] - pts[k - 1]))
                if dist < 1e-12:
                    raise ConfigError(
                        f"{name}.points[{k}]: repeats the previous point; "
                        "use 'hold' or explicit 'times' to pause"
                    )
                t += dist / speed
                knot_t_list.append(t)
                knot_p_list.append(pts[k])
                arrivals.append(t)
                if self.hold_s > 0 and k < pts.shape[0] - 1:
                    t += self.hold_s
                    knot_t_list.append(t)
                    knot_p_list.append(pts[k])
            self.times = np.array(arrivals)
            knot_t, knot_p = np.array(knot_t_list), np.array(knot_p_list)
        self._knot_t = knot_t
        self._knot_p = knot_p
        self.duration = float(self.times[-1] + self.hold_s)

    def sample(self, times: np.ndarray | Sequence[float]) -> np.ndarray:
        """Reference positions [m] at ``times`` [s], shape (len(times), 3)."""
        t = _times(times)
        if self._knot_t.size == 1:
            return np.tile(self._knot_p[0], (t.size, 1))
        kt, kp = self._knot_t, self._knot_p
        i = np.clip(np.searchsorted(kt, t, side="right") - 1, 0, kt.size - 2)
        tau = np.clip((t - kt[i]) / (kt[i + 1] - kt[i]), 0.0, 1.0)
        s = _min_jerk(tau)
        return kp[i] + s[:, None] * (kp[i + 1] - kp[i])


class Csv(Reference):
    """A tabulated reference from a CSV file with header columns ``t, x, y, z``.

    Times [s] must be strictly increasing; positions [m] are linearly interpolated and
    the first/last rows held outside the table. Extra columns are ignored.
    """

    def __init__(self, path: str | Path, *, name: str = "reference") -> None:
        p = Path(path)
        self.path = p
        try:
            with p.open(newline="") as f:
                rows = list(csv.reader(f))
        except OSError as e:
            raise ConfigError(f"{name}.file: cannot read {str(p)!r}: {e.strerror}") from None
        if not rows:
            raise ConfigError(f"{name}.file: {p}: empty file (a header t,x,y,z is required)")
        header = [h.strip() for h in rows[0]]
        cols = {}
        for c in ("t", "x", "y", "z"):
            if c not in header:
                raise ConfigError(f"{name}.file: {p}: missing column {c!r} in header {header}")
            cols[c] = header.index(c)
        data = np.empty((len(rows) - 1, 4))
        for r, row in enumerate(rows[1:]):
            line = r + 2
            for j, c in enumerate(("t", "x", "y", "z")):
                try:
                    v = float(row[cols[c]])
                except (IndexError, ValueError):
                    cell = row[cols[c]] if cols[c] < len(row) else "<missing>"
                    raise ConfigError(
                        f"{name}.file: {p}: line {line}, column {c!r}: not a number: {cell!r}"
                    ) from None
                if not math.isfinite(v):
                    raise ConfigError(
                        f"{name}.file: {p}: line {line}, column {c!r}: must be finite, got {v!r}"
                    )
                data[r, j] = v
        if data.shape[0] == 0:
            raise ConfigError(f"{name}.file: {p}: no data rows")
        bad = np.nonzero(np.diff(data[:, 0]) <= 0)[0]
        if bad.size:
            line = int(bad[0]) + 3
            raise ConfigError(
                f"{name}.file: {p}: line {line}: t must be strictly increasing, "
                f"got {data[bad[0], 0]!r} then {data[bad[0] + 1, 0]!r}"
            )
        self.t = data[:, 0]
        self.xyz = data[:, 1:]
        self.duration = float(max(self.t[-1], 0.0))

    def sample(self, times: np.ndarray | Sequence[float]) -> np.ndarray:
        """Reference positions [m] at ``times`` [s], shape (len(times), 3)."""
        t = _times(times)
        return np.stack([np.interp(t, self.t, self.xyz[:, j]) for j in range(3)], axis=1)


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
        phase: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0),
        duration: float = 60.0,
        *,
        name: str = "reference",
    ) -> None:
        self.center = _vec3(center, f"{name}.center")
        self.amplitude = _vec3(amplitude, f"{name}.amplitude")
        self.frequency = _vec3(frequency_hz, f"{name}.frequency")
        self.phase = _vec3(phase, f"{name}.phase")
        if np.any(self.frequency < 0):
            raise ConfigError(f"{name}.frequency: must be >= 0 Hz, got {list(self.frequency)}")
        if not (math.isfinite(duration) and duration > 0):
            raise ConfigError(f"{name}.duration: must be > 0 s, got {duration!r}")
        self.duration = float(duration)

    def sample(self, times: np.ndarray | Sequence[float]) -> np.ndarray:
        """Reference positions [m] at ``times`` [s], shape (len(times), 3)."""
        t = np.maximum(_times(times), 0.0)
        arg = 2 * np.pi * t[:, None] * self.frequency + self.phase
        return self.center + self.amplitude * np.sin(arg)


def _points(table: Table, key: str) -> np.ndarray:
    raw = table.raw(key)
    path = table.key(key)
    if not isinstance(raw, list) or not raw:
        raise ConfigError(f"{path}: expected a non-empty array of [x, y, z], got {raw!r}")
    return np.array([to_floats(p, f"{path}[{i}]", size=3) for i, p in enumerate(raw)])


def _axis(table: Table) -> int | np.ndarray:
    raw = table.raw("axis")
    if isinstance(raw, str):
        if raw not in AXES:
            raise ConfigError(
                f"{table.key('axis')}: {raw!r} is not one of {list(AXES)} or a 3-vector"
            )
        return AXES[raw]
    return np.array(to_floats(raw, table.key("axis"), size=3))


def reference_from_table(table: Table, base_dir: str | Path | None = None) -> Reference:
    """Build a reference from a TOML table with a ``kind`` key.

    Keys per kind (units: m, s, Hz, rad):

    - ``constant``: ``point``, optional ``duration``;
    - ``sinusoids``: ``center``, ``axis`` ("x" | "y" | "z" | [dx, dy, dz]),
      ``phases = [{ duration, amplitude, frequency }, ...]``;
    - ``waypoints``: ``points``, and ``times`` or ``speed``; optional ``hold``;
    - ``csv``: ``file`` (relative to ``base_dir``, default the working directory);
    - ``lissajous``: ``center``, ``amplitude``, ``frequency``, optional ``phase``, ``duration``.

    Unknown kinds or keys raise ``ConfigError`` naming the key path.
    """
    name = table.path or "reference"
    kind = table.str("kind", choices=KINDS)
    if kind == "constant":
        point, duration = table.floats("point", size=3), table.float("duration", 0.0)
        table.done()
        return Constant(point, duration, name=name)
    if kind == "sinusoids":
        center = table.floats("center", size=3)
        axis = _axis(table)
        phases = []
        for ph in table.tables("phases"):
            phases.append((ph.float("duration"), ph.float("amplitude"), ph.float("frequency")))
            ph.done()
        table.done()
        return SinusoidPhases(center, axis, phases, name=name)
    if kind == "waypoints":
        points = _points(table, "points")
        times = table.floats("times") if table.has("times") else None
        speed = table.float("speed") if table.has("speed") else None
        hold = table.float("hold", 0.0)
        table.done()
        return Waypoints(points, times, speed=speed, hold_s=hold, name=name)
    if kind == "csv":
        file = Path(table.str("file"))
        table.done()
        if not file.is_absolute() and base_dir is not None:
            file = Path(base_dir) / file
        return Csv(file, name=name)
    center, amplitude = table.floats("center", size=3), table.floats("amplitude", size=3)
    frequency = table.floats("frequency", size=3)
    phase = table.floats("phase", (0.0, 0.0, 0.0), size=3)
    duration = table.float("duration", 60.0)
    table.done()
    return Lissajous(center, amplitude, frequency, phase, duration, name=name)
