"""What a replay frame shows besides the robot, and where it looks from.

Overlays are geoms appended to MuJoCo's ``MjvScene`` after ``mjv_updateScene`` (no model
change): the end-effector reference path (green line), the EE's trail over the last
``TRAIL_S`` seconds (red line), the waypoints (yellow spheres) and the platform's box
bounds (blue wireframe; an open side at the flown extent plus ``runs.BOX_MARGIN``) and a
soft dark disc on the ground under the platform (its "shadow": how high it flies); in runs
with surfaces (drawn by the run's ``robot.xml``) the force arrow at the probe
(``viz.contact``: orange, along the surface's normal, ``ARROW_M_PER_N`` per newton measured).
The camera follows the UAM: it looks at the midpoint of the base and the end effector from
``FRAMING`` times the distance that fits the robot's bounding sphere, across the main
horizontal direction of the reference path (so the arm's motion is seen side-on), turned
by ``SKEW_DEG`` and looking down ``ELEVATION_DEG``; in a run pressing a wall, from the
wall's free side, ``SURFACE_VIEW_DEG`` into it (``surface_azimuth``).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from aeromanip.experiment.runlog import RunLog
from aeromanip.viz.contact import ARROW_M_PER_N, ForceArrows
from aeromanip.viz.gl import import_mujoco
from aeromanip.viz.runs import Trajectory, box_bounds

mujoco = import_mujoco()

TRAIL_S = 60.0  # [s] of flight the EE trail covers
MAX_PATH_POINTS = 400  # reference path drawn with at most this many points
MAX_TRAIL_POINTS = 200
LINE_PX = 3.0  # [px] line width
FRAMING = 1.35  # camera distance / distance that just fits the robot
SKEW_DEG = 25.0  # camera azimuth off the side-on view [deg]
ELEVATION_DEG = -12.0
DEFAULT_AZIMUTH_DEG = 135.0  # when the reference does not move horizontally
SURFACE_VIEW_DEG = 35.0  # a wall seen this far into it off its face [deg]
REF_RGBA = np.array([0.1, 0.85, 0.3, 1.0], dtype=np.float32)
TRAIL_RGBA = np.array([0.95, 0.2, 0.15, 1.0], dtype=np.float32)
WAYPOINT_RGBA = np.array([1.0, 0.85, 0.1, 1.0], dtype=np.float32)
BOX_RGBA = np.array([0.3, 0.6, 1.0, 0.45], dtype=np.float32)
WAYPOINT_RADIUS = 0.025  # [m]
DISC_SHARE = 0.7  # ground disc radius / robot radius
DISC_RGBA = np.array([0.0, 0.0, 0.0, 0.35], dtype=np.float32)
ARROW_RGBA = np.array([1.0, 0.45, 0.0, 1.0], dtype=np.float32)
ARROW_WIDTH = 0.015  # [m] shaft radius of the force arrow
_EYE = np.eye(3).ravel()
_ZERO3 = np.zeros(3)


def decimate(points: np.ndarray, max_points: int) -> np.ndarray:
    """At most ``max_points`` of ``points`` (N, 3), evenly spaced, first and last kept."""
    n = len(points)
    if n <= max_points:
        return points
    return points[np.unique(np.linspace(0, n - 1, max_points).round().astype(int))]


@dataclass
class Overlays:
    """The run's static overlays and its EE trail source (module docstring)."""

    path: np.ndarray
    waypoints: np.ndarray
    box: tuple[np.ndarray, np.ndarray] | None
    traj: Trajectory
    arrows: ForceArrows | None = None
    probe_radius: float = 0.0

    @classmethod
    def of_run(cls, log: RunLog, traj: Trajectory) -> Overlays:
        """The overlays of a logged run."""
        points = np.asarray(log.meta.get("waypoints") or np.zeros((0, 3)), dtype=float)
        return cls(
            decimate(traj.ref, MAX_PATH_POINTS),
            points.reshape(-1, 3),
            box_bounds(log, traj),
            traj,
            ForceArrows.of_run(log),
            float(log.meta.get("probe_radius") or 0.0),
        )

    def count(self) -> int:
        """How many scene geoms the overlays can take at most."""
        return len(self.path) + len(self.waypoints) + MAX_TRAIL_POINTS + 4

    def force_arrow(self, t: float, tip: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Tail and head [m] of the force arrow at ``t`` [s] for the probe drawn with its
        centre at ``tip``: from its contact point along the normal, ``ARROW_M_PER_N`` per
        newton of the row's measured normal force (``None``: no arrow)."""
        if self.arrows is None:
            return None
        k = self.traj.row(t)
        if not self.arrows.drawn[k]:
            return None
        n = self.arrows.direction[k]
        tail = np.asarray(tip, dtype=float) - self.probe_radius * n
        return tail, tail + ARROW_M_PER_N * self.arrows.along[k] * n

    def draw(
        self, scene: mujoco.MjvScene, t: float, ee_now: np.ndarray, line_px: float = LINE_PX
    ) -> None:
        """Append the overlays at time ``t`` [s] (``ee_now``: the EE drawn; lines
        ``line_px`` pixels wide) to ``scene``."""
        _polyline(scene, self.path, REF_RGBA, line_px)
        for p in self.waypoints:
            _geom(
                scene, mujoco.mjtGeom.mjGEOM_SPHERE, np.full(3, WAYPOINT_RADIUS), p, WAYPOINT_RGBA
            )
        if self.box is not None:
            _geom(scene, mujoco.mjtGeom.mjGEOM_LINEBOX, self.box[1], self.box[0], BOX_RGBA)
        k = self.traj.row(t)
        k0 = self.traj.row(t - TRAIL_S)
        trail = decimate(self.traj.ee[k0 : k + 1], MAX_TRAIL_POINTS - 1)
        _polyline(scene, np.vstack([trail, ee_now]), TRAIL_RGBA, line_px)
        arrow = self.force_arrow(t, ee_now)
        if arrow is not None:
            g = _geom(scene, mujoco.mjtGeom.mjGEOM_ARROW, _ZERO3, _ZERO3, ARROW_RGBA)
            if g is not None:
                mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_ARROW, ARROW_WIDTH, *arrow)
                g.size[2] *= 2.0  # MuJoCo draws an arrow half its size[2] long

    @staticmethod
    def ground_disc(scene: mujoco.MjvScene, base: np.ndarray, radius: float) -> None:
        """The platform's "shadow": a disc of ``radius`` [m] on the ground (z = 0) below it."""
        pos = np.array([base[0], base[1], 1e-3])
        _geom(scene, mujoco.mjtGeom.mjGEOM_CYLINDER, np.array([radius, 5e-4, 0.0]), pos, DISC_RGBA)


def _geom(
    scene: mujoco.MjvScene, kind: int, size: np.ndarray, pos: np.ndarray, rgba: np.ndarray
) -> mujoco.MjvGeom | None:
    """Append one geom (``None`` when the scene is full)."""
    if scene.ngeom >= scene.maxgeom:
        return None
    g = scene.geoms[scene.ngeom]
    mujoco.mjv_initGeom(g, kind, size, pos, _EYE, rgba)
    g.category = mujoco.mjtCatBit.mjCAT_DECOR
    g.castshadow = False  # marks, not objects (were shadows turned on)
    scene.ngeom += 1
    return g


def _polyline(scene: mujoco.MjvScene, points: np.ndarray, rgba: np.ndarray, px: float) -> None:
    """Append line segments ``px`` pixels wide joining ``points`` (N, 3) in order."""
    line = mujoco.mjtGeom.mjGEOM_LINE
    for a, b in itertools.pairwise(points):
        g = _geom(scene, line, _ZERO3, _ZERO3, rgba)
        if g is None:
            return
        mujoco.mjv_connector(g, line, px, a, b)


class FollowCamera:
    """A free camera that follows the UAM (module docstring)."""

    def __init__(
        self, traj: Trajectory, radius: float, fovy_deg: float, normal: np.ndarray | None = None
    ) -> None:
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        fit = radius / math.tan(math.radians(fovy_deg) / 2)
        self.camera.distance = FRAMING * fit
        self.camera.azimuth = side_azimuth(traj.ref)
        if normal is not None and (facing := surface_azimuth(normal)) is not None:
            self.camera.azimuth = facing
        self.camera.elevation = ELEVATION_DEG

    def aim(self, base: np.ndarray, ee: np.ndarray) -> mujoco.MjvCamera:
        """Point at the midpoint of the platform base and the end effector [m]."""
        self.camera.lookat[:] = 0.5 * (np.asarray(base) + np.asarray(ee))
        return self.camera


def surface_azimuth(normal: np.ndarray) -> float | None:
    """Camera azimuth [deg] for a run pressing a surface of outward ``normal``: from its
    free side, looking ``SURFACE_VIEW_DEG`` into it off its face (the force arrow, along
    the normal, seen nearly side-on); ``None`` for a horizontal surface."""
    nx, ny = float(normal[0]), float(normal[1])
    if math.hypot(nx, ny) < 0.3:
        return None
    face = math.degrees(math.atan2(-ny, -nx))  # looking straight into the surface
    return (face + 90.0 - SURFACE_VIEW_DEG) % 360.0


def side_azimuth(path: np.ndarray) -> float:
    """Camera azimuth [deg] seeing the path's main horizontal direction side-on, skewed."""
    xy = path[:, :2] - path[:, :2].mean(axis=0)
    if len(xy) < 2 or float(np.abs(xy).max()) < 1e-6:
        return DEFAULT_AZIMUTH_DEG
    _, _, vt = np.linalg.svd(xy, full_matrices=False)
    main = math.degrees(math.atan2(vt[0, 1], vt[0, 0]))
    return (main + 90.0 + SKEW_DEG) % 360.0
