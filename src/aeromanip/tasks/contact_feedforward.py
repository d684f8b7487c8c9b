"""The thrust a multirotor adds to hold a contact force: the planned normal force and
the sliding friction, balanced by the flight controller as an acceleration feed-forward.

Without it the platform's position loop, soft against a spring-loaded probe (a few N/m
against 150), gives way to the push and builds it only through its velocity integrator,
over seconds. The feed-forward is on while contact is felt, and for ``hold_s`` [s] after
the sensor last felt it (one control step of sensor noise does not switch it), then
goes off: a lost contact is not pushed after. It changes by at most ``rate`` [N/s], so
that neither a first touch nor a loss kicks the platform. A contact not felt for
``loss_s`` [s] after it was is **lost** (``lost``): the force task then drops its set
force until contact is felt again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

HOLD_S = 0.1  # [s] the feed-forward stays on this long after contact was last felt
LOSS_S = 0.5  # [s] a contact not felt for this long is lost
RATE = 10.0  # [N/s] its largest change
SLIDE_SPEED = 0.005  # [m/s] below this reference speed the friction feed-forward fades out


@dataclass
class ThrustFeedforward:
    """The feed-forward of the module docstring; ``friction``: the Coulomb coefficient
    assumed for the sliding friction (0: none)."""

    friction: float = 0.0
    hold_s: float = HOLD_S
    loss_s: float = LOSS_S
    rate: float = RATE
    level: float = 0.0  # [N] the normal force being balanced now
    last_contact: float | None = None  # [s] when contact was last felt

    def reset(self) -> None:
        """Off, no contact felt yet."""
        self.level, self.last_contact = 0.0, None

    def feel(self, t: float, in_contact: bool) -> None:
        """Whether the sensor feels contact at ``t`` [s]."""
        if in_contact:
            self.last_contact = t

    def lost(self, t: float) -> bool:
        """Contact was felt before, but not for longer than ``loss_s`` at ``t`` [s]."""
        return self.last_contact is not None and t - self.last_contact > self.loss_s

    def thrust(
        self, force: float, normal: np.ndarray, v_ref: np.ndarray, t: float, dt: float
    ) -> np.ndarray:
        """The thrust [N, world] for the planned normal force ``force`` [N] on a surface
        of outward ``normal``, sliding at the reference velocity ``v_ref`` [m/s], at ``t``
        [s], for the next ``dt`` [s]: ``-level n`` plus ``friction level`` along the
        reference's tangential velocity (its direction from the reference, not the plan:
        a feed-forward that answered errors would make the slide oscillate)."""
        held = self.last_contact is not None and t - self.last_contact <= self.hold_s
        target = force if held else 0.0
        step = self.rate * dt
        self.level += float(np.clip(target - self.level, -step, step))
        v_t = v_ref - float(v_ref @ normal) * normal
        direction = v_t / np.sqrt(float(v_t @ v_t) + SLIDE_SPEED**2)  # a smooth sign
        return -self.level * normal + self.friction * self.level * direction
