"""The contact's rest point estimated online from the measured force (closing the loop on
force): the NMPC's spring (``tasks.contact``) moved so that it explains what the wrist
sensor measures, with bounds that keep the push safe.

Each control step, with ``p`` the measured EE position, ``f`` the measured normal force
[N] (the sensor's force along the surface's outward normal) and ``d0(p)`` the spring's
penetration with its configured rest point, the estimate ``offset`` [m] (the model's
penetration is ``d0(p) - offset``) follows:

- **in contact** (``f >= contact_force``): towards ``d0(p) - d(f)``, where ``d(f)`` is
  the spring's penetration for ``f``, low-passed with ``time_constant`` [s];
- **over-force** (``f > force_limit``): set there at once (no low-pass), so that the next
  plan backs off at once; the event is ``"overforce"``;
- **no contact** where the model predicts one: the rest point is at least as far as
  ``p``, so ``offset`` rises to ``d0(p) - d(contact_force)``, at most ``search_speed``
  [m/s] (the surface is searched for at a bounded speed); the event is ``"search"``;
- always within ``[-max_offset, max_offset]`` [m]: however far the surface really is,
  the NMPC never plans the probe more than ``max_offset`` past the configured rest
  point plus its set force's penetration (no runaway push); the event is ``"limit"``
  when bound.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aeromanip.tasks.contact import ContactSpring

TIME_CONSTANT = 0.3  # [s] low-pass of the estimate in contact
CONTACT_FORCE = 0.3  # [N] a measured normal force from which the probe is in contact
MAX_OFFSET = 0.03  # [m] the estimate's bound
SEARCH_SPEED = 0.02  # [m/s] how fast the rest point may move in when no contact is felt
EVENTS = ("", "contact", "overforce", "search", "limit")  # logged as their index


@dataclass
class RestPointEstimator:
    """The estimate of the module docstring, for ``spring`` (its configured rest point).

    Args:
        spring: the NMPC's contact model.
        force_limit: the measured force [N] beyond which the estimate jumps (over-force).
        time_constant, contact_force, max_offset, search_speed: as above [s, N, m, m/s].
    """

    spring: ContactSpring
    force_limit: float
    time_constant: float = TIME_CONSTANT
    contact_force: float = CONTACT_FORCE
    max_offset: float = MAX_OFFSET
    search_speed: float = SEARCH_SPEED
    offset: float = 0.0
    event: str = ""

    def reset(self) -> None:
        """Back to the configured rest point."""
        self.offset, self.event = 0.0, ""

    def update(self, ee: np.ndarray, force: np.ndarray, dt: float) -> float:
        """Take one step's measured EE position ``ee`` [m] and sensor force ``force`` [N]
        (world, on the end effector) ``dt`` [s] after the last; return the offset [m]."""
        n = np.asarray(self.spring.normal)
        f = float(np.dot(force, n))
        d0 = float(self.spring.penetration(ee))
        if f > self.force_limit:
            target, self.event = d0 - self.spring.penetration_of_force(f), "overforce"
        elif f >= self.contact_force:
            target = d0 - self.spring.penetration_of_force(f)
            alpha = dt / (self.time_constant + dt)
            target, self.event = self.offset + alpha * (target - self.offset), "contact"
        else:
            free = d0 - self.spring.penetration_of_force(self.contact_force)
            target, self.event = self.offset, ""
            if free > self.offset:  # the model presses where nothing is felt
                target, self.event = min(free, self.offset + self.search_speed * dt), "search"
        if abs(target) > self.max_offset:
            target, self.event = float(np.clip(target, -self.max_offset, self.max_offset)), "limit"
        self.offset = target
        return target
