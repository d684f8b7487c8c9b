"""The end effector's contact, read from MuJoCo: the true contact force and the wrist
force/torque sensor's reading (with its noise).

Signs: every force here is the one the environment exerts ON the end effector (its probe),
world frame [N]; a push on a surface gives a positive normal force ``f_n``, the component
along the contact normal (which points out of the surface, into the probe); ``f_t`` is the
magnitude of the tangential (friction) part. The sensor (MuJoCo ``force``/``torque`` on a
site of the massless probe body) measures what the last link exerts on the probe, i.e.
minus the contact wrench; it is turned into the force on the end effector and the torque
about the sensor site, world frame, plus white noise of the configured std per axis.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from aeromanip.sim.contact import (
    FORCE_SENSOR,
    PROBE_GEOM,
    PROBE_SLIDE,
    SENSOR_SITE,
    TORQUE_SENSOR,
    Surface,
)
from aeromanip.sim.mujoco_import import mujoco

#: log columns of a run with surfaces: the measured force (world), the true normal and
#: tangential contact forces, the contact flag (1 in contact), the probe sphere's centre
#: (world) and the compliant probe's travel (0 for a rigid one)
CONTACT_COLUMNS = (
    "f_x", "f_y", "f_z", "f_n", "f_t", "contact", "tip_x", "tip_y", "tip_z", "probe_travel",
)  # fmt: skip
FORCE_NOISE_SEED = 0xF0  # the sensor noise generator's stream, beside the state noise's


@dataclass(frozen=True)
class ContactReading:
    """The end effector's contact at one instant (module docstring for the signs).

    ``force``/``torque``: the wrist sensor's reading [N, N m], world frame, with noise;
    ``contact_force``: the true total contact force on the probe [N], world frame;
    ``normal_force``, ``tangential_force``: its components at the contact [N];
    ``in_contact``: whether the probe touches a surface; ``surface``: which one (0-based
    index in the scenario's list, -1 if none); ``tip``: the probe sphere's centre [m],
    world frame (true); ``travel``: how far the compliant probe's tip is pushed in [m]
    (0 for a rigid probe).
    """

    force: np.ndarray
    torque: np.ndarray
    contact_force: np.ndarray
    normal_force: float
    tangential_force: float
    in_contact: bool
    surface: int
    tip: np.ndarray
    travel: float

    def columns(self) -> dict[str, float]:
        """The values of ``CONTACT_COLUMNS``."""
        fx, fy, fz = self.force.tolist()
        return {
            "f_x": fx,
            "f_y": fy,
            "f_z": fz,
            "f_n": self.normal_force,
            "f_t": self.tangential_force,
            "contact": 1.0 if self.in_contact else 0.0,
            "tip_x": float(self.tip[0]),
            "tip_y": float(self.tip[1]),
            "tip_z": float(self.tip[2]),
            "probe_travel": self.travel,
        }


class ContactSensor:
    """Reads the probe's contacts and its force/torque sensor from ``model``/``data``.

    Args:
        model, data: a MuJoCo model built with surfaces (``mjcf.robot_to_mjcf``).
        surfaces: the surfaces, in the model's order.
        force_std: sensor force noise std per axis [N]; torque_std: [N m].
        seed: the simulator's seed (the noise has its own stream of it).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        surfaces: Sequence[Surface],
        force_std: float = 0.0,
        torque_std: float = 0.0,
        seed: int = 0,
    ) -> None:
        self.model, self.data = model, data
        self.surfaces = tuple(surfaces)
        self.probe = model.geom(PROBE_GEOM).id
        self.surface_ids = {model.geom(f"surface_{i + 1}").id: i for i in range(len(surfaces))}
        self.site = model.site(SENSOR_SITE).id
        slide = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, PROBE_SLIDE)
        self.slide_adr = int(model.jnt_qposadr[slide]) if slide >= 0 else -1
        self.force_adr = int(model.sensor_adr[model.sensor(FORCE_SENSOR).id])
        self.torque_adr = int(model.sensor_adr[model.sensor(TORQUE_SENSOR).id])
        self.force_std, self.torque_std = float(force_std), float(torque_std)
        self._buf = np.zeros(6)
        self.reset(seed)

    def reset(self, seed: int) -> None:
        """Re-seed the noise and forget the last reading."""
        self.rng = np.random.default_rng([seed, FORCE_NOISE_SEED])
        self._last: tuple[float, ContactReading] | None = None

    def read(self, time: float) -> ContactReading:
        """The reading at simulation ``time`` [s] of the current state (the same one,
        noise included, for every call at the same time)."""
        if self._last is not None and self._last[0] == time:
            return self._last[1]
        m, d = self.model, self.data
        mujoco.mj_forward(m, d)  # contacts and sensors of this state (not of the last step's)
        total, normal, tangential, surface = self._true_contact()
        rot = d.site_xmat[self.site].reshape(3, 3)
        force = -rot @ d.sensordata[self.force_adr : self.force_adr + 3]
        torque = -rot @ d.sensordata[self.torque_adr : self.torque_adr + 3]
        if self.force_std > 0:
            force = force + self.rng.normal(0.0, self.force_std, 3)
        if self.torque_std > 0:
            torque = torque + self.rng.normal(0.0, self.torque_std, 3)
        travel = float(d.qpos[self.slide_adr]) if self.slide_adr >= 0 else 0.0
        tip = d.geom_xpos[self.probe].copy()
        reading = ContactReading(
            force, torque, total, normal, tangential, surface >= 0, surface, tip, travel
        )  # fmt: skip
        self._last = (time, reading)
        return reading

    def _true_contact(self) -> tuple[np.ndarray, float, float, int]:
        """Total contact force on the probe (world), its normal and tangential parts and
        the surface touched (the one with the largest normal force; -1: none)."""
        m, d, buf = self.model, self.data, self._buf
        total, normal, tangential = np.zeros(3), 0.0, np.zeros(3)
        surface, strongest = -1, -1.0
        for i in range(d.ncon):
            c = d.contact[i]
            if self.probe not in (c.geom1, c.geom2):
                continue
            mujoco.mj_contactForce(m, d, i, buf)
            frame = c.frame.reshape(3, 3)  # rows: normal (geom1 -> geom2), tangents
            sign = -1.0 if c.geom1 == self.probe else 1.0  # force on the probe
            f = sign * (frame.T @ buf[:3])
            n_out = sign * frame[0]  # out of the surface, into the probe
            fn = float(f @ n_out)
            total += f
            normal += fn
            tangential += f - fn * n_out
            other = c.geom2 if c.geom1 == self.probe else c.geom1
            if fn > strongest:
                surface, strongest = self.surface_ids.get(int(other), -1), fn
        return total, normal, float(np.linalg.norm(tangential)), surface
