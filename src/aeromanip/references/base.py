"""End-effector reference trajectories in the world frame (metres, seconds).

Every reference answers ``position(t)`` (3,) and the vectorised ``sample(times)``
(len(times), 3). Before ``t = 0`` a reference holds its initial point; after its
``duration`` the smooth kinds hold their end point (``Lissajous`` keeps looping).

Kinds (one module each, registered by name in ``REFERENCES``): ``constant``,
``sinusoids`` (paper Sec. VI-A), ``waypoints`` (quintic, minimum-jerk segments, Sec.
VI-B/C), ``csv`` (tabulated, linear interpolation) and ``lissajous`` (a smooth 3D loop for
long flights). ``reference_from_table`` builds one from a TOML table such as
``{ kind = "waypoints", points = [[...], ...], times = [...] }``; ``kind =
"package.module:Class"`` names a ``Reference`` subclass of your own.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from aeromanip.config import Table, to_floats
from aeromanip.errors import ConfigError
from aeromanip.registry import Registry

AXES: dict[str, int] = {"x": 0, "y": 1, "z": 2}
MAX_COORD = 1e4  # [m] positions and amplitudes beyond this are no UAM's
MAX_FREQUENCY_HZ = 100.0  # [Hz] a reference faster than this is not one a UAM follows


class Reference(ABC):
    """An end-effector position reference p(t) in the world frame [m]."""

    duration: float
    """Time [s] after which the reference no longer changes (or the nominal run length)."""

    def position(self, t: float) -> np.ndarray:
        """The reference position [m] at time ``t`` [s], shape (3,)."""
        return self.sample(np.array([float(t)]))[0]

    def expression(self, t: ca.SX) -> ca.SX:
        """The position [m] at the time ``t`` [s] (a scalar expression) as a CasADi
        expression (3,): what a controller exported to C computes (``aeromanip export``).
        A kind without one cannot be exported."""
        raise ConfigError(
            f"reference: a {type(self).__name__} reference cannot be exported to C "
            "(kinds that can: constant, sinusoids, waypoints, csv, lissajous)"
        )

    @abstractmethod
    def sample(self, times: np.ndarray | Sequence[float]) -> np.ndarray:
        """Reference positions [m] at ``times`` [s], shape (len(times), 3)."""

    def markers(self) -> np.ndarray | None:
        """Points [m] to mark in run metadata, plots and replays (e.g. waypoints), shape
        (n, 3); ``None`` (the default) for none."""
        return None

    def motion_phases(self) -> list[tuple[float, float, np.ndarray]] | None:
        """``(t0, t1, direction)`` of each phase of motion along one unit direction, for
        the run summary's share of that motion carried by the arm and by the platform;
        ``None`` (the default) for none."""
        return None

    @classmethod
    def from_table(cls, table: Table, base_dir: Path | None = None) -> Reference:
        """Build from the keys of a TOML table (``kind`` excluded); ``base_dir`` anchors
        relative file names. Read keys through ``table`` so that errors name them."""
        raise ConfigError(f"{table.path or 'reference'}: {cls.__name__} has no from_table")


REFERENCES: Registry[Reference] = Registry("reference", "aeromanip.references", Reference)


def as_times(times: np.ndarray | Sequence[float]) -> np.ndarray:
    """``times`` [s] as a flat float array."""
    return np.atleast_1d(np.asarray(times, dtype=float)).reshape(-1)


def vec3(v: Any, name: str, limit: float = MAX_COORD) -> np.ndarray:
    """``v`` as 3 finite floats of magnitude at most ``limit``, or a ``ConfigError``
    naming ``name``."""
    try:
        a = np.asarray(v, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ConfigError(f"{name}: expected 3 finite numbers, got {v!r}") from None
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ConfigError(f"{name}: expected 3 finite numbers, got {v!r}")
    if np.abs(a).max() > limit:
        raise ConfigError(f"{name}: values must be within +-{limit:g}, got {a.tolist()}")
    return a


def direction(axis: int | str | Sequence[float] | np.ndarray, name: str) -> np.ndarray:
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
    d = vec3(axis, name)
    norm = float(np.linalg.norm(d))
    if norm < 1e-12:
        raise ConfigError(f"{name}: direction must be non-zero, got {list(d)}")
    return d / norm


def points_from_table(table: Table, key: str) -> np.ndarray:
    """An array of ``[x, y, z]`` points [m] stored under ``key``, shape (n, 3)."""
    raw = table.raw(key)
    path = table.key(key)
    if not isinstance(raw, list) or not raw:
        raise ConfigError(f"{path}: expected a non-empty array of [x, y, z], got {raw!r}")
    return np.array([to_floats(p, f"{path}[{i}]", size=3) for i, p in enumerate(raw)])


def reference_from_table(table: Table, base_dir: str | Path | None = None) -> Reference:
    """Build a reference from a TOML table with a ``kind`` key (see each kind's
    ``from_table`` for its keys; units m, s, Hz, rad). Unknown kinds or keys raise
    ``ConfigError`` naming the key path."""
    cls = REFERENCES.get(table.str("kind"), table.key("kind"))
    ref = cls.from_table(table, None if base_dir is None else Path(base_dir))
    table.done()
    if not isinstance(ref, Reference):
        raise ConfigError(f"{table.key('kind')}: {cls.__name__}.from_table returned {ref!r}")
    return ref
