"""The contact of a saved run, for its replay and its MCAP: the surfaces and a force arrow.

A run with surfaces logs the wrist sensor's force ``f_x, f_y, f_z`` (the force on the end
effector, world frame, with its noise), the contact flag and the probe sphere's centre
``tip_x, tip_y, tip_z``; its ``meta.json`` holds the surfaces and the probe's radius.
The arrow of a row in contact starts at the contact point (the probe's centre less its
radius along the surface's outward normal ``n``), points along ``n`` (the way the surface
pushes the probe) and is ``ARROW_M_PER_N`` long per newton of the **measured** normal
force ``f . n``; a row out of contact (or with ``f . n <= 0``) has none. With several
surfaces, ``n`` is the one the measured force is most along.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aeromanip.experiment.runlog import RunLog

ARROW_M_PER_N = 0.1  # [m] of arrow per newton of measured normal force
ARROW_COLUMNS = ("f_x", "f_y", "f_z", "contact", "tip_x", "tip_y", "tip_z")


@dataclass(frozen=True)
class SurfaceBox:
    """A surface slab [m]: its face's ``point``, outward ``normal``, face ``tangents``
    (t1, t2), face ``size`` along them and ``thickness`` behind the face."""

    point: np.ndarray
    normal: np.ndarray
    tangents: np.ndarray
    size: np.ndarray
    thickness: float

    @property
    def centre(self) -> np.ndarray:
        """The slab's centre [m] (half its thickness behind the face)."""
        return self.point - 0.5 * self.thickness * self.normal

    @property
    def rotation(self) -> np.ndarray:
        """Columns t1, t2, n: the slab's frame in the world."""
        return np.column_stack([self.tangents[0], self.tangents[1], self.normal])


def surfaces_of(log: RunLog) -> list[SurfaceBox]:
    """The run's surfaces from its ``meta.json`` (empty for a run without)."""
    return [
        SurfaceBox(
            np.asarray(s["point"], float),
            np.asarray(s["normal"], float),
            np.asarray(s["tangents"], float),
            np.asarray(s["size"], float),
            float(s["thickness"]),
        )
        for s in log.meta.get("surfaces") or []
    ]


@dataclass(frozen=True)
class ForceArrows:
    """Per logged row: the arrow's ``start`` (N, 3) [m], unit ``direction`` (N, 3), the
    measured force along it ``along`` (N,) [N] and whether the row has an arrow
    ``drawn`` (N,)."""

    start: np.ndarray
    direction: np.ndarray
    along: np.ndarray
    drawn: np.ndarray

    @classmethod
    def of_run(cls, log: RunLog) -> ForceArrows | None:
        """The arrows of a logged run (module docstring); ``None`` when it has no contact
        columns or no surfaces."""
        normals = np.asarray(log.meta.get("surface_normals") or np.zeros((0, 3)), float)
        if not normals.size or any(c not in log for c in ARROW_COLUMNS):
            return None
        normals = normals.reshape(-1, 3)
        f = np.stack([log.column(c) for c in ("f_x", "f_y", "f_z")], axis=1)
        tip = np.stack([log.column(c) for c in ("tip_x", "tip_y", "tip_z")], axis=1)
        each = f @ normals.T  # (N, surfaces): f . n of each
        which = np.argmax(each, axis=1)
        n = normals[which]
        along = each[np.arange(len(f)), which]
        radius = float(log.meta.get("probe_radius") or 0.0)
        drawn = (log.column("contact") > 0) & (along > 0)
        return cls(tip - radius * n, n, along, drawn)

    @property
    def force(self) -> np.ndarray:
        """The measured normal force the arrows show [N] (0 where none is drawn)."""
        return np.where(self.drawn, self.along, 0.0)

    def segment(self, k: int) -> tuple[np.ndarray, np.ndarray] | None:
        """Tail and head [m] of row ``k``'s arrow (``None`` if it has none)."""
        if not self.drawn[k]:
            return None
        return self.start[k], self.start[k] + ARROW_M_PER_N * self.along[k] * self.direction[k]
