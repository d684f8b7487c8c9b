"""``run.mcap``: a run as an MCAP log with Foxglove's well-known schemas (docs/foxglove.md).

Written after the run from its directory alone (``log.csv``, ``meta.json``,
``robot.urdf``), through ``foxglove-sdk``'s MCAP writer (zstd chunks). Every message is
stamped with simulation time (``t`` of its row, nanoseconds from 0). Topics:

* ``/tf`` (``foxglove.FrameTransforms``, per row): ``world`` -> base link (the logged
  platform pose, roll and pitch included in physics runs) and every URDF joint's
  ``parent`` -> ``child`` (``viz.transforms``);
* ``/joint_states`` (``foxglove.JointStates``, per row): the arm joints by URDF name;
* ``/log`` (JSON, schema ``aeromanip.LogRow``, per row): every column of ``log.csv``
  (non-finite numbers as ``null``);
* ``/robot_description`` (``std_msgs/String`` as JSON ``{"data": URDF}``, once): what the
  3D panel's URDF layer reads from a topic;
* ``/scene`` (``foxglove.SceneUpdate``, once): the EE reference path, the flown EE path,
  the waypoints, the platform's box bounds and the surfaces, in ``world``;
* with surfaces, ``/contact`` (the measured and set forces, per row) and
  ``/contact/arrow`` (the force arrow at the probe, per row): ``viz.mcap_contact``.

``robot.urdf``, ``robot.xml``, ``config.toml`` and ``meta.json`` are attached; the run's
metadata (scenario, strategy, backend, simulator, dt) is an MCAP metadata record.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.experiment.runlog import META_FILE, RunLog
from aeromanip.viz.contact import ForceArrows
from aeromanip.viz.dependencies import require
from aeromanip.viz.layout import LAYOUT_FILE, foxglove_layout
from aeromanip.viz.mcap_contact import (
    CONTACT_SCHEMA,
    CONTACT_SCHEMA_NAME,
    arrow_update,
    contact_messages,
    surface_entity,
)
from aeromanip.viz.runs import URDF_FILE, SavedRun, box_bounds, load_run, run_dirs
from aeromanip.viz.transforms import WORLD, FrameTree

MCAP_FILE = "run.mcap"
ATTACHED = {
    "robot.urdf": "application/xml",
    "robot.xml": "application/xml",
    "config.toml": "application/toml",
    META_FILE: "application/json",
}
LOG_SCHEMA_NAME = "aeromanip.LogRow"
STRING_SCHEMA = {"type": "object", "properties": {"data": {"type": "string"}}}
LINE_WIDTH_PX = 3.0
WAYPOINT_DIAMETER = 0.05  # [m]


def stamp_ns(t: float) -> int:
    """Simulation time ``t`` [s] as MCAP log time [ns] (``ConfigError`` if negative)."""
    if not (t >= 0 and math.isfinite(t)):
        raise ConfigError(f"log: t = {t} cannot be an MCAP time (finite and >= 0)")
    return round(t * 1e9)


def write_mcap(run_dir: str | Path, out: str | Path | None = None) -> Path:
    """Write the MCAP of one run directory (default ``run_dir/run.mcap``) and a Foxglove
    layout for it beside it (``foxglove-layout.json``, ``viz.layout``); returns the MCAP's
    path. The file is written beside its destination and moved into place when complete.
    """
    run = load_run(Path(run_dir))
    if run.urdf is None:
        raise ConfigError(f"{run.path}: no {URDF_FILE}: the MCAP's frames come from it")
    out = Path(out) if out is not None else run.path / MCAP_FILE
    tmp = out.with_name(f".{out.name}.partial-{os.getpid()}")
    try:
        base = _write(run, tmp)
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)
    out.with_name(LAYOUT_FILE).write_text(foxglove_layout(run.log, base))
    return out


def write_mcaps(root: str | Path) -> list[Path]:
    """``write_mcap`` for every run under ``root`` (itself, or each variant)."""
    return [write_mcap(d) for d in run_dirs(Path(root))]


def _write(run: SavedRun, path: Path) -> str:
    """Every topic of the module docstring, into a new MCAP at ``path``; returns the
    platform's base link."""
    fg = require("foxglove", "foxglove-sdk", "an MCAP log")
    channels = require("foxglove.channels", "foxglove-sdk", "an MCAP log")
    tree = FrameTree(run.urdf or "", str(run.path / URDF_FILE))
    transforms = tree.transforms(run.traj)  # checks the joints before anything is written
    ctx = fg.Context()
    times = [stamp_ns(float(t)) for t in run.traj.t]
    with fg.open_mcap(path, allow_overwrite=True, context=ctx) as writer:
        _static(run, fg, channels, ctx, times[0])
        tf = channels.FrameTransformsChannel("/tf", context=ctx)
        joints = channels.JointStatesChannel("/joint_states", context=ctx)
        log = fg.Channel(
            "/log",
            schema=_json_schema(fg, LOG_SCHEMA_NAME, _log_schema(run.log)),
            message_encoding="json",
            context=ctx,
        )
        rows = _log_rows(run.log)
        names = tree.joint_names
        for k, ns in enumerate(times):
            tf.log(_frame_transforms(transforms, k, ns), log_time=ns)
            joints.log(_joint_states(names, run.traj.q[k], ns), log_time=ns)
            log.log(rows[k], log_time=ns)
        _contact(run.log, fg, channels, ctx, times)
        _attach(writer, run.path, times[0])
        meta = {k: str(v) for k, v in run.log.meta.items() if isinstance(v, str | int | float)}
        writer.write_metadata("aeromanip", meta)
    return tree.base


def _contact(log: RunLog, fg: Any, channels: Any, ctx: Any, times: list[int]) -> None:
    """``/contact`` and ``/contact/arrow``, per row, for a run with surfaces."""
    arrows = ForceArrows.of_run(log)
    if arrows is None:
        return
    schema = _json_schema(fg, CONTACT_SCHEMA_NAME, CONTACT_SCHEMA)
    forces = fg.Channel("/contact", schema=schema, message_encoding="json", context=ctx)
    arrow = channels.SceneUpdateChannel("/contact/arrow", context=ctx)
    for k, msg in enumerate(contact_messages(log, arrows)):
        forces.log(json.dumps(msg, allow_nan=False).encode(), log_time=times[k])
        arrow.log(arrow_update(arrows, k, _timestamp(times[k])), log_time=times[k])


def _static(run: SavedRun, fg: Any, channels: Any, ctx: Any, ns: int) -> None:
    """The robot description and the scene, once, at the first row's time."""
    schema = _json_schema(fg, "std_msgs/String", STRING_SCHEMA)
    desc = fg.Channel("/robot_description", schema=schema, message_encoding="json", context=ctx)
    desc.log({"data": run.urdf}, log_time=ns)
    channels.SceneUpdateChannel("/scene", context=ctx).log(_scene(run, ns), log_time=ns)


def _json_schema(fg: Any, name: str, schema: dict[str, Any]) -> Any:
    return fg.Schema(name=name, encoding="jsonschema", data=json.dumps(schema).encode())


def _timestamp(ns: int) -> Any:
    from foxglove.messages import Timestamp

    return Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


def _frame_transforms(transforms: list, k: int, ns: int) -> Any:
    """The ``FrameTransforms`` of row ``k``."""
    from foxglove.messages import FrameTransform, FrameTransforms, Quaternion, Vector3

    stamp = _timestamp(ns)
    out = []
    for tf in transforms:
        (x, y, z), (qw, qx, qy, qz) = tf.translation[k].tolist(), tf.rotation[k].tolist()
        out.append(
            FrameTransform(
                timestamp=stamp,
                parent_frame_id=tf.parent,
                child_frame_id=tf.child,
                translation=Vector3(x=x, y=y, z=z),
                rotation=Quaternion(x=qx, y=qy, z=qz, w=qw),
            )
        )
    return FrameTransforms(transforms=out)


def _joint_states(names: list[str], q: np.ndarray, ns: int) -> Any:
    from foxglove.messages import JointState, JointStates

    joints = [JointState(name=n, position=float(v)) for n, v in zip(names, q, strict=True)]
    return JointStates(timestamp=_timestamp(ns), joints=joints)


def _log_schema(log: RunLog) -> dict[str, Any]:
    """JSON schema of a ``/log`` message: one number (or null) or string per column."""
    props = {
        name: {"type": "string"} if col.dtype.kind == "U" else {"type": ["number", "null"]}
        for name, col in log.columns.items()
    }
    return {"type": "object", "properties": props}


def _log_rows(log: RunLog) -> list[bytes]:
    """Each row of the log as a JSON object (strict JSON: NaN and inf as ``null``)."""
    cols = {n: c.tolist() for n, c in log.columns.items()}
    rows = []
    for k in range(len(log)):
        row = {n: _finite(c[k]) for n, c in cols.items()}
        rows.append(json.dumps(row, allow_nan=False).encode())
    return rows


def _finite(v: Any) -> Any:
    return None if isinstance(v, float) and not math.isfinite(v) else v


def _attach(writer: Any, run_dir: Path, ns: int) -> None:
    for name, media in ATTACHED.items():
        f = run_dir / name
        if f.is_file():
            writer.attach(
                log_time=ns, create_time=ns, name=name, media_type=media, data=f.read_bytes()
            )


def _scene(run: SavedRun, ns: int) -> Any:
    """The ``SceneUpdate`` with the run's static entities, in ``world``."""
    from foxglove.messages import SceneEntity, SceneUpdate

    traj = run.traj
    stamp = _timestamp(ns)
    entities = [
        SceneEntity(
            timestamp=stamp,
            frame_id=WORLD,
            id="reference",
            lines=[_line(traj.ref, (0.1, 0.85, 0.3, 1.0))],
        ),
        SceneEntity(
            timestamp=stamp,
            frame_id=WORLD,
            id="ee_path",
            lines=[_line(traj.ee, (0.95, 0.2, 0.15, 1.0))],
        ),
    ]
    points = run.log.meta.get("waypoints")
    if points:
        entities.append(
            SceneEntity(
                timestamp=stamp,
                frame_id=WORLD,
                id="waypoints",
                spheres=[_sphere(p) for p in points],
            )
        )
    box = box_bounds(run.log, traj)
    if box is not None:
        entities.append(
            SceneEntity(timestamp=stamp, frame_id=WORLD, id="box_bounds", lines=[_box_edges(*box)])
        )
    surfaces = surface_entity(run.log, stamp)
    if surfaces is not None:
        entities.append(surfaces)
    return SceneUpdate(entities=entities)


def _line(points: np.ndarray, rgba: tuple[float, ...], kind: str = "LineStrip") -> Any:
    from foxglove.messages import Color, LinePrimitive, LinePrimitiveLineType, Point3

    return LinePrimitive(
        type=getattr(LinePrimitiveLineType, kind),
        thickness=LINE_WIDTH_PX,
        scale_invariant=True,
        points=[Point3(x=x, y=y, z=z) for x, y, z in np.asarray(points).tolist()],
        color=Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]),
    )


def _sphere(p: list[float]) -> Any:
    from foxglove.messages import Color, Pose, Quaternion, SpherePrimitive, Vector3

    pose = Pose(position=Vector3(x=p[0], y=p[1], z=p[2]), orientation=Quaternion(w=1.0))
    d = WAYPOINT_DIAMETER
    return SpherePrimitive(
        pose=pose, size=Vector3(x=d, y=d, z=d), color=Color(r=1.0, g=0.85, b=0.1, a=1.0)
    )


def _box_edges(center: np.ndarray, half: np.ndarray) -> Any:
    """The 12 edges of an axis-aligned box as a line list."""
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    pts = center + corners * half
    edges = [
        (a, b)
        for a in range(8)
        for b in range(a + 1, 8)
        if np.count_nonzero(corners[a] != corners[b]) == 1
    ]
    return _line(np.array([pts[i] for e in edges for i in e]), (0.3, 0.6, 1.0, 0.6), "LineList")
