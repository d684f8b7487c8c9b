"""The contact topics of ``run.mcap`` (runs with surfaces; ``viz.contact`` has the geometry).

* ``/contact`` (JSON, schema ``aeromanip.Contact``, per row): the wrist sensor's force
  ``force`` {x, y, z} [N] (world, with its noise), ``normal_force`` (its component along
  the surface's outward normal: what the arrow shows), the true ``f_n`` and ``f_t``, the
  set force ``f_ref`` (``null`` without a force task) and ``contact`` (1 or 0), as in
  ``log.csv``: a plot panel reads ``/contact.normal_force`` against ``/contact.f_ref``;
* ``/contact/arrow`` (``foxglove.SceneUpdate``, per row): entity ``contact_force`` with
  the force arrow (an ``ArrowPrimitive``, no arrow out of contact), in ``world``;
* the surfaces as ``CubePrimitive`` slabs in ``/scene`` (entity ``surfaces``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from aeromanip.experiment.runlog import RunLog
from aeromanip.viz.contact import ARROW_M_PER_N, ForceArrows, surfaces_of
from aeromanip.viz.transforms import WORLD

CONTACT_SCHEMA_NAME = "aeromanip.Contact"
_NUMBER = {"type": ["number", "null"]}
CONTACT_SCHEMA = {
    "type": "object",
    "properties": {
        "force": {"type": "object", "properties": {c: _NUMBER for c in "xyz"}},
        **{k: _NUMBER for k in ("normal_force", "f_n", "f_t", "f_ref", "contact")},
    },
}
ARROW_HEAD_SHARE = 0.25  # of the arrow's length
ARROW_SHAFT_DIAMETER = 0.01  # [m]
ARROW_HEAD_DIAMETER = 0.025  # [m]
ARROW_RGBA = (1.0, 0.45, 0.0, 1.0)
SURFACE_RGBA = (0.55, 0.5, 0.45, 0.6)  # as the MJCF's slabs


def contact_messages(log: RunLog, arrows: ForceArrows) -> list[dict[str, Any]]:
    """The ``/contact`` message of every row (module docstring)."""
    col = log.columns
    f_ref = col["f_ref"].tolist() if "f_ref" in log else [None] * len(log)
    out = []
    for k in range(len(log)):
        force = {c: _number(col[f"f_{c}"][k]) for c in "xyz"}
        out.append(
            {
                "force": force,
                "normal_force": _number(arrows.along[k]),
                "f_n": _number(col["f_n"][k]),
                "f_t": _number(col["f_t"][k]),
                "f_ref": _number(f_ref[k]),
                "contact": _number(col["contact"][k]),
            }
        )
    return out


def _number(v: Any) -> float | None:
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def arrow_update(arrows: ForceArrows, k: int, stamp: Any) -> Any:
    """Row ``k``'s ``SceneUpdate``: the entity ``contact_force`` with its arrow (or none)."""
    from foxglove.messages import SceneEntity, SceneUpdate

    seg = arrows.segment(k)
    prims = [] if seg is None else [_arrow(seg[0], arrows.direction[k], arrows.force[k])]
    entity = SceneEntity(timestamp=stamp, frame_id=WORLD, id="contact_force", arrows=prims)
    return SceneUpdate(entities=[entity])


def _arrow(tail: np.ndarray, direction: np.ndarray, force: float) -> Any:
    from foxglove.messages import ArrowPrimitive, Color, Pose, Vector3

    length = ARROW_M_PER_N * force
    x, y, z = tail.tolist()
    return ArrowPrimitive(
        pose=Pose(position=Vector3(x=x, y=y, z=z), orientation=_quat_x_to(direction)),
        shaft_length=(1.0 - ARROW_HEAD_SHARE) * length,
        shaft_diameter=ARROW_SHAFT_DIAMETER,
        head_length=ARROW_HEAD_SHARE * length,
        head_diameter=ARROW_HEAD_DIAMETER,
        color=Color(r=ARROW_RGBA[0], g=ARROW_RGBA[1], b=ARROW_RGBA[2], a=ARROW_RGBA[3]),
    )


def _quat_x_to(d: np.ndarray) -> Any:
    """The shortest rotation taking +x to the unit vector ``d``."""
    from foxglove.messages import Quaternion

    c = float(np.clip(d[0], -1.0, 1.0))
    axis = np.array([0.0, -d[2], d[1]])  # x cross d
    norm = float(np.linalg.norm(axis))
    if norm < 1e-12:  # along x: none, or half a turn about z
        return Quaternion(w=1.0) if c > 0 else Quaternion(z=1.0, w=0.0)
    half = 0.5 * math.atan2(norm, c)
    ax = axis / norm * math.sin(half)
    return Quaternion(x=float(ax[0]), y=float(ax[1]), z=float(ax[2]), w=math.cos(half))


def surface_entity(log: RunLog, stamp: Any) -> Any | None:
    """The surfaces as slabs (``None`` for a run without)."""
    from foxglove.messages import Color, CubePrimitive, Pose, Quaternion, SceneEntity, Vector3

    cubes = []
    for s in surfaces_of(log):
        w, x, y, z = _quat_of(s.rotation)
        cx, cy, cz = s.centre.tolist()
        cubes.append(
            CubePrimitive(
                pose=Pose(position=Vector3(x=cx, y=cy, z=cz), orientation=Quaternion(
                    x=x, y=y, z=z, w=w)),
                size=Vector3(x=float(s.size[0]), y=float(s.size[1]), z=s.thickness),
                color=Color(r=SURFACE_RGBA[0], g=SURFACE_RGBA[1], b=SURFACE_RGBA[2],
                            a=SURFACE_RGBA[3]),
            )
        )  # fmt: skip
    if not cubes:
        return None
    return SceneEntity(timestamp=stamp, frame_id=WORLD, id="surfaces", cubes=cubes)


def _quat_of(r: np.ndarray) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a rotation matrix (Shepperd's method)."""
    t = float(np.trace(r))
    i = int(np.argmax([t, r[0, 0], r[1, 1], r[2, 2]]))
    if i == 0:
        s = 2.0 * math.sqrt(1.0 + t)
        q = (0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s)
    elif i == 1:
        s = 2.0 * math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = ((r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s)
    elif i == 2:
        s = 2.0 * math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = ((r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = ((r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s)
    return tuple(float(v) for v in q)  # type: ignore[return-value]
