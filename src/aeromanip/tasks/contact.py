"""The contact model of the NMPC's prediction: a spring along a surface's normal.

A flat surface through ``point`` with outward unit normal ``n`` (world frame) pushes the
end effector's probe (a sphere of radius ``probe_radius`` centred on the EE frame) back
with the normal force [N]::

    f_n(x) = k * softplus_s(d),     d = (p_rest - p_e(x)) . n
    p_rest = point + (probe_radius - rest_offset) n
    softplus_s(d) = s * log(1 + exp(d / s))

``d`` [m] is the penetration of the probe into the spring (positive in contact),
``k`` [N/m] its stiffness, ``rest_offset`` [m] how far behind the face (into the
surface) the spring starts to push, and ``s`` [m] (``smoothing``) the width over which
``max(0, d)`` is rounded so that the NLP stays smooth: ``f_n`` is ``k d`` to within
``k s exp(-d / s)`` in contact, ``k s log 2`` at ``d = 0`` and ``k s exp(d / s)`` apart.

The force is an output of the state, not a state: the prediction (``nmpc.model``) is
unchanged, and tasks (``tasks.force``) put ``f_n(x_k)`` in their residuals.
Against MuJoCo's soft contact (default ``solref``/``solimp``) the x8-3dof's probe
matches ``k = 2800`` N/m, ``rest_offset = 1.3e-4`` m, ``smoothing = 6e-5`` m
(``docs/contact.md``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.tasks.base import Task

PROBE_RADIUS = 0.01  # [m] the probe sphere's radius (the physics simulator's default)
SMOOTHING = 1e-4  # [m] the softplus width s
MAX_STIFFNESS = 1e7  # [N/m]
MAX_SMOOTHING = 0.01  # [m]
MAX_OFFSET = 0.1  # [m] |rest_offset|, and the largest probe radius
MAX_COORDINATE = 1000.0  # [m]
Plane = tuple[Sequence[float], Sequence[float]]  # a surface's (point, outward normal)


def _vector(value: Any, key: str) -> np.ndarray:
    v = np.asarray(value, dtype=float).ravel() if value is not None else np.zeros(0)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or np.any(np.abs(v) > MAX_COORDINATE):
        raise ConfigError(
            f"{key}: must be 3 finite numbers (|v| <= {MAX_COORDINATE:g}), got {value!r}"
        )
    return v


def _number(value: Any, key: str, low: float, high: float, low_open: bool = True) -> float:
    ok = not isinstance(value, bool) and isinstance(value, int | float) and math.isfinite(value)
    if not ok or value > high or value < low or (low_open and value == low):
        bracket = "(" if low_open else "["
        raise ConfigError(f"{key}: must be a number in {bracket}{low:g}, {high:g}], got {value!r}")
    return float(value)


@dataclass(frozen=True)
class ContactSpring:
    """The spring of the module docstring; numbers checked at construction.

    Args:
        point: a point of the surface's face [m] (world frame).
        normal: its outward normal (normalised here).
        stiffness: ``k`` [N/m].
        probe_radius: the probe sphere's radius [m].
        rest_offset: the spring's rest point behind the face [m] (negative: in front).
        smoothing: the softplus width ``s`` [m].
    """

    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    stiffness: float
    probe_radius: float = PROBE_RADIUS
    rest_offset: float = 0.0
    smoothing: float = SMOOTHING

    def __post_init__(self) -> None:
        point = _vector(self.point, "contact.point")
        normal = _vector(self.normal, "contact.normal")
        length = float(np.linalg.norm(normal))
        if length < 1e-9:
            raise ConfigError(f"contact.normal: must not be zero, got {list(self.normal)}")
        object.__setattr__(self, "point", tuple(point.tolist()))
        object.__setattr__(self, "normal", tuple((normal / length).tolist()))
        _number(self.stiffness, "contact.stiffness", 0.0, MAX_STIFFNESS)
        _number(self.probe_radius, "contact.probe_radius", 0.0, MAX_OFFSET, low_open=False)
        _number(self.rest_offset, "contact.rest_offset", -MAX_OFFSET, MAX_OFFSET, False)
        _number(self.smoothing, "contact.smoothing", 0.0, MAX_SMOOTHING)

    def rest_point(self) -> np.ndarray:
        """``p_rest`` [m]: where the EE frame is when the spring starts to push."""
        n = np.array(self.normal)
        return np.array(self.point) + (self.probe_radius - self.rest_offset) * n

    def penetration(self, p: Any) -> Any:
        """``d = (p_rest - p) . n`` [m] of an EE position ``p`` (numbers or CasADi)."""
        n = ca.DM(self.normal)
        return ca.dot(n, ca.DM(self.rest_point()) - p)

    def normal_force(self, p: Any, offset: Any = 0.0) -> Any:
        """``f_n = k softplus_s(d - offset)`` [N] (CasADi expression, or a number for a
        numeric ``p``); ``offset`` [m] moves the rest point further in, on top of
        ``rest_offset`` (e.g. an estimate's: a number or a symbol). Written
        ``max(d, 0) + s log(1 + exp(-|d| / s))``: no overflow."""
        symbolic = isinstance(p, ca.SX | ca.MX)
        numeric = not symbolic and not isinstance(offset, ca.SX | ca.MX)
        d = self.penetration(p if symbolic else ca.DM(np.asarray(p, dtype=float))) - offset
        s = self.smoothing
        f = self.stiffness * (ca.fmax(d, 0) + s * ca.log1p(ca.exp(-ca.fabs(d) / s)))
        return float(f) if numeric else f

    def penetration_of_force(self, force: float) -> float:
        """The ``d`` [m] at which the spring pushes ``force`` [N] (> 0): softplus inverted."""
        s = self.smoothing
        y = force / (self.stiffness * s)
        return s * (y + math.log(-math.expm1(-y)))  # s log(exp(y) - 1), no overflow

    def tangent_projector(self) -> np.ndarray:
        """``I - n n^T`` (3 x 3): a vector's part in the surface's plane."""
        n = np.array(self.normal)
        return np.eye(3) - np.outer(n, n)

    def with_rest_offset(self, rest_offset: float) -> ContactSpring:
        """The same spring, its rest point moved (e.g. estimated from a measured force)."""
        return ContactSpring(
            self.point, self.normal, self.stiffness, self.probe_radius, rest_offset, self.smoothing
        )


def tangents(normal: Sequence[float]) -> np.ndarray:
    """The surface's tangents as rows (2 x 3): ``t1 = normalise(z x n)`` (horizontal;
    ``x`` when ``n`` is vertical) and ``t2 = n x t1``, as the physics simulator's."""
    n = np.asarray(normal, dtype=float)
    t1 = np.cross([0.0, 0.0, 1.0], n)
    norm = np.linalg.norm(t1)
    t1 = np.array([1.0, 0.0, 0.0]) if norm < 1e-9 else t1 / norm
    return np.vstack([t1, np.cross(n, t1)])


class SurfaceTask(Task):
    """A task about one flat surface: given by ``point`` and ``normal`` [m] (world frame),
    or, when both are ``None``, the scenario's ``[[physics.surfaces]]`` entry of index
    ``surface`` (0: the first; ``use_surface``), so that a surface is stated once."""

    surface: int = 0
    point: tuple[float, float, float] | None = None
    normal: tuple[float, float, float] | None = None

    def _set_surface(
        self, surface: int, point: Sequence[float] | None, normal: Sequence[float] | None
    ) -> None:
        if (point is None) != (normal is None):
            raise ConfigError(
                f"{self.name}: give both point and normal, or neither (the scenario's "
                f"[[physics.surfaces]] entry of index surface = {surface})"
            )
        if isinstance(surface, bool) or not isinstance(surface, int) or surface < 0:
            raise ConfigError(f"{self.name}.surface: must be an integer >= 0, got {surface!r}")
        self.surface = surface
        if point is not None and normal is not None:
            self.use_surface(point, normal)

    def use_surface(self, point: Sequence[float], normal: Sequence[float]) -> None:
        """Set the surface (checked; the normal normalised)."""
        p = _vector(point, f"{self.name}.point")
        n = _vector(normal, f"{self.name}.normal")
        if np.linalg.norm(n) < 1e-9:
            raise ConfigError(f"{self.name}.normal: must not be zero, got {list(normal)}")
        self.point = tuple(p.tolist())  # type: ignore[assignment]
        self.normal = tuple((n / np.linalg.norm(n)).tolist())  # type: ignore[assignment]

    def use_scenario(self, planes: Sequence[Plane], probe_radius: float) -> None:
        """Take the scenario's surface of index ``surface`` from ``planes`` ((point,
        normal) of each ``[[physics.surfaces]]`` entry) unless a surface was given, and its
        probe's radius [m] (``physics.probe_radius``) where the task uses it."""
        if self.point is None:
            if self.surface >= len(planes):
                raise ConfigError(
                    f"{self.name}.surface: {self.surface}, but the scenario has "
                    f"{len(planes)} [[physics.surfaces]] (indices from 0); or give point "
                    "and normal"
                )
            self.use_surface(*planes[self.surface])

    def plane(self) -> tuple[np.ndarray, np.ndarray]:
        """The surface's ``point`` and unit ``normal``; an error if none was given."""
        if self.point is None or self.normal is None:
            raise ConfigError(
                f"{self.name}: no surface (give point and normal, or a [[physics.surfaces]] "
                f"entry of index {self.surface} in the scenario)"
            )
        return np.array(self.point), np.array(self.normal)
