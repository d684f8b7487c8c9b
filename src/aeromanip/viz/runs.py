"""Saved runs read back for a replay or an MCAP: the log, the robot models, the pose at any
time, the platform's box bounds.

A run directory holds ``log.csv`` (+ ``meta.json``), ``robot.xml`` and ``robot.urdf``
(DESIGN.md); a scenario with variants holds one such directory per variant, in the order
``DIR/summary.json`` lists them. The platform pose of a row is ``x, y, z, yaw`` and, in
physics runs, ``roll, pitch`` (zero when not logged): ``R = Rz(yaw) Ry(pitch) Rx(roll)``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.experiment.runlog import LOG_FILE, META_FILE, SUMMARY_FILE, RunLog, bound_pair

MJCF_FILE = "robot.xml"
URDF_FILE = "robot.urdf"
POSE_COLUMNS = ("t", "x", "y", "z", "yaw")
POINT_COLUMNS = ("ee_x", "ee_y", "ee_z", "ref_x", "ref_y", "ref_z")
BOX_MARGIN = 0.5  # [m] beyond the flown extent, for an open side of the box bounds


@dataclass(frozen=True)
class Trajectory:
    """A run's poses and end-effector data per logged row (SI units, world frame).

    Attributes:
        t: row times [s], increasing.
        pos: platform position (N, 3) [m]; rpy: roll, pitch, yaw (N, 3) [rad], yaw unwrapped.
        q: arm joint angles (N, n) [rad].
        ee, ref: end-effector and reference positions (N, 3) [m].
        status: the controller's status of each step.
    """

    t: np.ndarray
    pos: np.ndarray
    rpy: np.ndarray
    q: np.ndarray
    ee: np.ndarray
    ref: np.ndarray
    status: np.ndarray

    @classmethod
    def from_log(cls, log: RunLog) -> Trajectory:
        """The trajectory of a log (``ConfigError`` naming a missing column)."""
        missing = [c for c in (*POSE_COLUMNS, *POINT_COLUMNS) if c not in log]
        if missing:
            raise ConfigError(f"log: replay needs the columns {missing}")
        col = log.column
        n = len(log)
        zeros = np.zeros(n)
        rpy = np.stack(
            [
                col("roll") if "roll" in log else zeros,
                col("pitch") if "pitch" in log else zeros,
                col("yaw"),
            ],
            axis=1,
        )
        t = col("t")
        if n > 1 and not np.all(np.diff(t) > 0):
            raise ConfigError("log: the times t must increase row by row")
        return cls(
            t=t,
            pos=np.stack([col("x"), col("y"), col("z")], axis=1),
            rpy=np.unwrap(rpy, axis=0),
            q=np.array([col(f"q{i + 1}") for i in range(log.n_joints)]).T.reshape(n, -1),
            ee=np.stack([col(c) for c in POINT_COLUMNS[:3]], axis=1),
            ref=np.stack([col(c) for c in POINT_COLUMNS[3:]], axis=1),
            status=col("status") if "status" in log else np.full(n, ""),
        )

    def __len__(self) -> int:
        return int(self.t.size)

    def row(self, t: float) -> int:
        """The row in effect at time ``t`` [s]: the last one logged at or before it."""
        return int(np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self) - 1))

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Platform position, rpy and joint angles at ``t`` [s], linear between rows."""
        k = self.row(t)
        if k + 1 >= len(self) or t <= self.t[k]:
            return self.pos[k], self.rpy[k], self.q[k]
        a = (t - self.t[k]) / (self.t[k + 1] - self.t[k])
        pos, rpy, q = ((1.0 - a) * v[k] + a * v[k + 1] for v in (self.pos, self.rpy, self.q))
        return pos, rpy, q

    def error(self, k: int) -> float:
        """||ee - ref|| of row ``k`` [m]."""
        return float(np.linalg.norm(self.ee[k] - self.ref[k]))


@dataclass(frozen=True)
class SavedRun:
    """One run directory: its name, log, trajectory and robot models (MJCF, URDF text)."""

    name: str
    path: Path
    log: RunLog
    traj: Trajectory
    mjcf: str
    urdf: str | None
    problems: tuple[str, ...] = ()  # what is damaged (a log cut short, no meta.json)


def load_run(path: Path) -> SavedRun:
    """Read one run directory (``ConfigError`` naming what is missing)."""
    path = Path(path)
    if not (path / LOG_FILE).is_file():
        raise ConfigError(f"{path}: not a run directory (no {LOG_FILE})")
    log = RunLog.load(path, require_rows=True)
    xml = path / MJCF_FILE
    if not xml.is_file():
        raise ConfigError(
            f"{path}: no {MJCF_FILE} (the robot's MJCF); re-run the scenario to write it"
        )
    urdf = path / URDF_FILE
    name = log.meta.get("scenario") or path.name
    return SavedRun(
        name=str(name),
        path=path,
        log=log,
        traj=Trajectory.from_log(log),
        mjcf=xml.read_text(),
        urdf=urdf.read_text() if urdf.is_file() else None,
        problems=damage(path, len(log)),
    )


def damage(path: Path, rows: int) -> tuple[str, ...]:
    """What is wrong with a run directory that still loads: its ``log.csv`` cut short
    (a last row without its line end: dropped) or no ``meta.json``."""
    found = []
    with (path / LOG_FILE).open("rb") as f:
        f.seek(0, 2)
        if f.tell() > 0:
            f.seek(-1, 2)
            if f.read(1) != b"\n":
                found.append(f"{path / LOG_FILE}: its last row is cut short (dropped; {rows} kept)")
    if not (path / META_FILE).is_file():
        found.append(f"{path}: no {META_FILE} (the run's bounds and names are missing)")
    return tuple(found)


def run_dirs(root: Path) -> list[Path]:
    """The run directories under ``root``: itself, or its variants in their run order."""
    root = Path(root)
    if not root.is_dir():
        raise ConfigError(f"{root}: not a run directory")
    if (root / LOG_FILE).is_file():
        return [root]
    dirs = sorted(p.parent for p in root.glob(f"*/{LOG_FILE}"))
    if not dirs:
        raise ConfigError(f"{root}: no {LOG_FILE} here nor in its sub-directories")
    order = _variant_order(root)
    dirs.sort(key=lambda d: order.index(d.name) if d.name in order else len(order))
    return dirs


def find_runs(root: Path) -> list[SavedRun]:
    """Every run under ``root`` (see ``run_dirs``), loaded."""
    return [load_run(d) for d in run_dirs(root)]


def _variant_order(root: Path) -> list[str]:
    """The variant names in the order ``root/summary.json`` lists them (empty if none)."""
    try:
        data = json.loads((root / SUMMARY_FILE).read_text())
    except (OSError, ValueError):
        return []
    return [k for k, v in data.items() if isinstance(v, dict)] if isinstance(data, dict) else []


def box_bounds(log: RunLog, traj: Trajectory) -> tuple[np.ndarray, np.ndarray] | None:
    """Centre and half extents [m] of the platform's x, y, z bounds (``meta.bounds``), open
    sides closed at the flown extent plus ``BOX_MARGIN``; ``None`` without any bound."""
    bounds = log.meta.get("bounds") or {}
    lo, hi = traj.pos.min(axis=0) - BOX_MARGIN, traj.pos.max(axis=0) + BOX_MARGIN
    found = False
    for i, name in enumerate(("x", "y", "z")):
        if name in bounds:
            a, b = bound_pair(bounds[name], name)
            found |= math.isfinite(a) or math.isfinite(b)
            lo[i] = a if math.isfinite(a) else lo[i]
            hi[i] = b if math.isfinite(b) else hi[i]
    return ((lo + hi) / 2, (hi - lo) / 2) if found else None
