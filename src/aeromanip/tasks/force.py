"""Normal-force regulation: the contact spring's predicted force to a set force.

``r = f_n(x) - f_ref(t)`` [N] with ``f_n`` the spring of ``tasks.contact``
(``ContactSpring``: stiffness, rest offset, softplus width) on one surface. ``f_ref`` is
the constant ``f_ref`` or, with ``schedule = [[t, f], ...]`` (times in s, increasing),
linear between its points and held beyond them. Out of contact the residual's gradient
is nearly zero (``f_n`` is flat there): a force task regulates the push once the probe
touches, the approach belongs to a position task.

Closing the loop on force (``estimate = true``): the task takes the wrist sensor's
reading each control step (``observe``) and moves its spring's rest point so that the
spring explains the measured force (``tasks.contact_estimate``); the estimate is a second
stage parameter, so model error does not bias the force. ``feedforward = true`` also asks
the flight controller for the thrust that balances the planned contact force
(``force_feedforward``, applied while the sensor feels contact), as a position
controller's acceleration feed-forward: without it a multirotor's soft position loop
gives way to the push and builds it only through its integrator. With either, a contact
lost (not felt for ``LOSS_S`` while a force is set) drops the set force to 0 until
contact is felt again: the NMPC stops pressing into nothing, and logs it.
"""

from __future__ import annotations

from collections.abc import Sequence

import casadi as ca
import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.references import Reference
from aeromanip.tasks.base import TASKS, Stage
from aeromanip.tasks.contact import PROBE_RADIUS, SMOOTHING, ContactSpring, Plane, SurfaceTask
from aeromanip.tasks.contact_estimate import (
    EVENTS,
    MAX_OFFSET,
    SEARCH_SPEED,
    TIME_CONSTANT,
    RestPointEstimator,
)
from aeromanip.tasks.contact_feedforward import RATE as FEEDFORWARD_RATE
from aeromanip.tasks.contact_feedforward import ThrustFeedforward

F_REF = 0.0  # [N] the set normal force without a schedule
MAX_FORCE = 1000.0  # [N]
FORCE_LIMIT_RATIO = 2.5  # default over-force limit, times the largest set force
MAX_FRICTION = 10.0  # a Coulomb coefficient beyond this is not a surface
MIN_FORCE_LIMIT = 1.0  # [N] the default over-force limit's floor (a set force of 0)


def _schedule(schedule: Sequence[Sequence[float]], key: str) -> np.ndarray:
    """``[[t, f], ...]`` checked: (n, 2), times increasing, forces in ``[0, MAX_FORCE]``."""
    try:
        a = np.asarray(schedule, dtype=float)
    except (TypeError, ValueError):
        a = np.zeros((0, 0))
    ok = a.ndim == 2 and a.shape[0] >= 1 and a.shape[1] == 2 and np.all(np.isfinite(a))
    if not ok or np.any(np.diff(a[:, 0]) <= 0) or np.any(a[:, 1] < 0) or a[:, 1].max() > MAX_FORCE:
        raise ConfigError(
            f"{key}: must be [[t, f], ...] with times increasing [s] and forces in "
            f"[0, {MAX_FORCE:g}] N, got {schedule!r}"
        )
    return a


_HIGHEST = {
    "time_constant": 100.0, "max_offset": 1.0, "search_speed": 10.0, "feedforward_rate": 1000.0,
}  # fmt: skip


def _checked(task: str, **options: float) -> dict[str, float]:
    """The estimator's (and the feed-forward's) options, each in ``(0, highest]`` (a
    one-line error otherwise)."""
    for key, value in options.items():
        high = _HIGHEST.get(key, MAX_FORCE)
        if isinstance(value, bool) or not isinstance(value, int | float) or not 0 < value <= high:
            raise ConfigError(f"{task}.{key}: must be in (0, {high:g}], got {value!r}")
    return {k: float(v) for k, v in options.items()}


@TASKS.register("force")
class NormalForce(SurfaceTask):
    """``f_n(x) - f_ref(t)`` [N] (module docstring).

    Args:
        stiffness: the spring's ``k`` [N/m].
        f_ref: the set normal force [N] (without ``schedule``).
        schedule: ``[[t, f], ...]``: the set force [N] against time [s].
        surface, point, normal: the surface (``SurfaceTask``).
        probe_radius: the probe's radius [m]; ``None``: the scenario's
            ``physics.probe_radius`` (else ``PROBE_RADIUS``).
        rest_offset: the spring's rest point behind the face [m].
        smoothing: the softplus width [m].
        estimate: estimate the rest point online from the measured force (module
            docstring); ``time_constant`` [s], ``max_offset`` [m], ``search_speed`` [m/s]
            as in ``tasks.contact_estimate``.
        force_limit: the measured force [N] taken as over-force (default
            ``FORCE_LIMIT_RATIO`` times the largest set force, at least
            ``MIN_FORCE_LIMIT``).
        feedforward: ask for the thrust that balances the planned force and the friction
            (module docstring, ``force_feedforward``).
        friction: the Coulomb coefficient the friction feed-forward assumes (0: none).
        feedforward_rate: the feed-forward's largest change [N/s] (a slow control rate
            wants a slow one: each step's change is held for the step).
        reference: the EE reference (the scenario's), whose tangential velocity gives the
            friction feed-forward its direction; ``None``: no friction feed-forward.
    """

    name = "force"

    def __init__(
        self,
        stiffness: float,
        f_ref: float = F_REF,
        schedule: list[tuple[float, float]] | None = None,
        surface: int = 0,
        point: tuple[float, float, float] | None = None,
        normal: tuple[float, float, float] | None = None,
        probe_radius: float | None = None,
        rest_offset: float = 0.0,
        smoothing: float = SMOOTHING,
        estimate: bool = False,
        time_constant: float = TIME_CONSTANT,
        max_offset: float = MAX_OFFSET,
        search_speed: float = SEARCH_SPEED,
        force_limit: float | None = None,
        feedforward: bool = False,
        friction: float = 0.0,
        feedforward_rate: float = FEEDFORWARD_RATE,
        reference: Reference | None = None,
    ) -> None:
        if not (0.0 <= f_ref <= MAX_FORCE):
            raise ConfigError(f"{self.name}.f_ref: must be in [0, {MAX_FORCE:g}] N, got {f_ref}")
        self.f_ref = float(f_ref)
        self.schedule = None if schedule is None else _schedule(schedule, f"{self.name}.schedule")
        self.stiffness, self.rest_offset, self.smoothing = stiffness, rest_offset, smoothing
        self.probe_radius = probe_radius
        self.estimate, self.feedforward = bool(estimate), bool(feedforward)
        self.reference = reference
        self.param_size = 2 if self.estimate else 1  # set force, and the rest-point estimate
        self._set_surface(surface, point, normal)
        ContactSpring((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), *self._spring_numbers())  # checked now
        largest = self.f_ref if self.schedule is None else float(self.schedule[:, 1].max())
        limit = (
            max(FORCE_LIMIT_RATIO * largest, MIN_FORCE_LIMIT)
            if force_limit is None
            else force_limit
        )
        self._estimator_options = _checked(
            self.name, time_constant=time_constant, max_offset=max_offset,
            search_speed=search_speed, force_limit=limit,
        )  # fmt: skip
        if isinstance(friction, bool) or not (0.0 <= friction <= MAX_FRICTION):
            raise ConfigError(
                f"{self.name}.friction: must be in [0, {MAX_FRICTION:g}], got {friction!r}"
            )
        self.estimator: RestPointEstimator | None = None
        rate = _checked(self.name, feedforward_rate=feedforward_rate)["feedforward_rate"]
        self._thrust = ThrustFeedforward(float(friction), rate=rate)
        self._lost = False
        self._t_last: float | None = None

    def _spring_numbers(self) -> tuple[float, float, float, float]:
        radius = PROBE_RADIUS if self.probe_radius is None else self.probe_radius
        return self.stiffness, radius, self.rest_offset, self.smoothing

    def use_scenario(self, planes: Sequence[Plane], probe_radius: float) -> None:
        """The scenario's surface (``SurfaceTask``) and, unless given, its probe radius."""
        super().use_scenario(planes, probe_radius)
        if self.probe_radius is None:
            self.probe_radius = float(probe_radius)
        self.spring()
        self.estimator = None

    def spring(self) -> ContactSpring:
        """The contact model of this task's surface."""
        point, normal = self.plane()
        return ContactSpring(tuple(point), tuple(normal), *self._spring_numbers())

    def residual(self, stage: Stage) -> ca.SX:
        """Predicted minus set normal force [N] (the spring moved by the estimate)."""
        offset = stage.params[1] if self.estimate else 0.0
        p = stage.kin.ee_position(stage.x)
        return self.spring().normal_force(p, offset) - stage.params[0]

    def set_force(self, times: np.ndarray) -> np.ndarray:
        """The set normal force at each time [N]: (len(times),)."""
        t = np.asarray(times, dtype=float)
        if self.schedule is None:
            return np.full(len(t), self.f_ref)
        return np.interp(t, self.schedule[:, 0], self.schedule[:, 1])

    def param_values(self, times: np.ndarray) -> np.ndarray:
        """The set force at each time [N] (0 while a contact is lost) and (``estimate``)
        the rest-point estimate [m]: (len(times), param_size)."""
        f = self.set_force(times)[:, None]
        if self._lost:  # dropped until contact is felt again
            f = np.zeros_like(f)
        if not self.estimate:
            return f
        return np.hstack([f, np.full_like(f, self._estimator().offset)])

    def _estimator(self) -> RestPointEstimator:
        if self.estimator is None:
            self.estimator = RestPointEstimator(self.spring(), **self._estimator_options)
        return self.estimator

    def reset(self) -> None:
        """Forget the estimate (a new run)."""
        self._estimator().reset()
        self._thrust.reset()
        self._t_last, self._lost = None, False

    def observe(
        self,
        ee: np.ndarray,
        wrench: np.ndarray | None,
        t: float,
        ee_tilted: np.ndarray | None = None,
    ) -> None:
        """The measured EE position [m] and wrist wrench ``[f, tau]`` [N, N m] (world) at
        ``t`` [s]: updates the estimate (``estimate``) and whether contact is felt."""
        if wrench is None:
            return
        est = self._estimator()
        force = np.asarray(wrench, dtype=float)[:3]
        normal = np.asarray(est.spring.normal)
        self._thrust.feel(t, float(force @ normal) >= est.contact_force)
        uses_sensor = self.estimate or self.feedforward
        self._lost = uses_sensor and self._thrust.lost(t) and self.set_force([t])[0] > 0
        dt = 0.0 if self._t_last is None else max(t - self._t_last, 0.0)
        self._t_last = t
        if self.estimate:
            est.update(np.asarray(ee, dtype=float), force, dt)

    def observations(self, t: float) -> dict[str, float]:
        """Logged each step: the set force ``f_ref`` [N] at ``t``; with ``feedforward``
        the normal force it balances ``f_ff`` [N]; with either (the sensor used)
        ``contact_lost`` (1: contact felt before, not for ``LOSS_S`` while a force is set:
        the set force is dropped until contact is felt again); with ``estimate`` the
        rest-point estimate ``rest_offset`` [m] and the estimator's event (index in
        ``EVENTS``). ``f_ref`` is the schedule's, lost contact or not."""
        out = {"f_ref": float(self.set_force(np.array([t]))[0])}
        if self.feedforward:
            out["f_ff"] = self._thrust.level
        if self.estimate or self.feedforward:
            out["contact_lost"] = float(self._lost)
        if self.estimate:
            out["rest_offset"] = self._estimator().offset
            out["contact_event"] = float(EVENTS.index(self._estimator().event))
        return out

    def force_feedforward(
        self, ee_now: np.ndarray, ee_next: np.ndarray, dt: float
    ) -> np.ndarray | None:
        """The thrust [N, world] that balances the normal force planned at the plan's next
        EE position ``ee_next`` [m] (bounded by the over-force limit) and the friction
        (``tasks.contact_feedforward``); ``None`` without ``feedforward``."""
        if not self.feedforward or self._t_last is None:
            return None if not self.feedforward else np.zeros(3)
        est = self._estimator()
        n = np.asarray(est.spring.normal)
        offset = est.offset if self.estimate else 0.0
        f = min(float(est.spring.normal_force(ee_next, offset)), est.force_limit)
        v_ref = np.zeros(3)
        if self.reference is not None:
            ends = self.reference.sample(np.array([self._t_last, self._t_last + dt]))
            v_ref = (np.asarray(ends[1]) - np.asarray(ends[0])) / dt
        return self._thrust.thrust(f, n, v_ref, self._t_last, dt)
