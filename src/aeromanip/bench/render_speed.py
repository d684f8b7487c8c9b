"""How fast a replay renders: frames per second of one panel (``aeromanip replay``).

A synthetic 10-min run of the ``x8-3dof`` UAM (a Lissajous EE reference, the platform
drifting along it, the arm swinging, rows every 0.5 s, z bounded) is written to a
temporary run directory and rendered through the same ``Panel`` a replay uses, one frame
every 1/3 s of the run (10x at 30 frames/s): pose, scene, overlays, render, caption. Video
encoding (a separate ffmpeg process) is not included.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from aeromanip.experiment.runlog import RunLog
from aeromanip.robot.loader import load_robot
from aeromanip.robot.urdf_export import robot_to_urdf
from aeromanip.sim.mjcf import robot_to_mjcf
from aeromanip.viz.gl import backend_name
from aeromanip.viz.render import Panel
from aeromanip.viz.runs import Trajectory, load_run
from aeromanip.viz.transforms import FrameTree

ROBOT = "x8-3dof"
DURATION_S = 600.0  # [s] of the synthetic run
DT = 0.5  # [s] between its rows
FRAME_DT = 1.0 / 3.0  # [s] of run between frames (10x at 30 frames/s)


def synthetic_run(out_dir: Path, robot: str = ROBOT) -> Path:
    """Write a run directory (``log.csv``, ``meta.json``, ``robot.xml``, ``robot.urdf``)
    of ``robot`` flying a Lissajous for ``DURATION_S``; returns it."""
    spec = load_robot(robot)
    t = np.arange(0.0, DURATION_S + 1e-9, DT)
    w = 2 * np.pi / 60.0
    cols = {"t": t, "x": 1.5 * np.sin(w * t), "y": np.sin(2 * w * t)}
    cols |= {"z": 1.2 + 0.2 * np.sin(3 * w * t), "yaw": 0.3 * np.sin(w * t)}
    for i in range(spec.n_joints):
        cols[f"q{i + 1}"] = 0.5 * np.sin((i + 1) * 1.7 * w * t) + (0.6 if i == 1 else 0.0)
    n = len(t)
    zeros = np.zeros(n)
    urdf = robot_to_urdf(spec)
    fake = cols | {c: zeros for c in ("ee_x", "ee_y", "ee_z", "ref_x", "ref_y", "ref_z")}
    ee = FrameTree(urdf).positions(Trajectory.from_log(RunLog(fake)))
    ref = ee + 0.003 * np.sin(np.outer(t, [1.0, 1.3, 0.7]))
    cols.update(ee_x=ee[:, 0], ee_y=ee[:, 1], ee_z=ee[:, 2])
    cols.update(ref_x=ref[:, 0], ref_y=ref[:, 1], ref_z=ref[:, 2], status=np.full(n, "ok"))
    meta = {"scenario": f"bench/{robot}", "bounds": {"z": [0.6, 2.0]}}
    RunLog(cols, meta).save(out_dir)
    (out_dir / "robot.urdf").write_text(urdf)
    (out_dir / "robot.xml").write_text(robot_to_mjcf(spec))
    return out_dir


def bench_render(
    frames: int = 300, size: tuple[int, int] = (640, 480), quality: str = "fast"
) -> dict:
    """Per-frame render times of one ``size`` panel: median and p95 [ms], frames/s at
    the median (``fps``) and over the whole sequence (``fps_mean``)."""
    with tempfile.TemporaryDirectory(prefix="aeromanip-bench-render-") as tmp:
        run = load_run(synthetic_run(Path(tmp)))
        panel = Panel(run, size[0], size[1], quality=quality)
        try:
            for k in range(10):  # warm-up: first frames upload textures, compile shaders
                panel.frame(k * FRAME_DT)
            ms = np.empty(frames)
            start = time.perf_counter()
            for k in range(frames):
                t0 = time.perf_counter()
                panel.frame((k % int(DURATION_S / FRAME_DT)) * FRAME_DT)
                ms[k] = 1e3 * (time.perf_counter() - t0)
            total = time.perf_counter() - start
        finally:
            panel.close()
    median = float(np.median(ms))
    return {
        "size": f"{size[0]}x{size[1]}",
        "quality": quality,
        "backend": backend_name(),
        "frames": frames,
        "median_ms": median,
        "p95_ms": float(np.percentile(ms, 95)),
        "fps": 1e3 / median,
        "fps_mean": frames / total,
    }


def format_render(result: dict) -> str:
    """One line per ``bench_render`` result."""
    return (
        f"replay rendering ({result['backend']}, {result['quality']}), {result['size']}: "
        f"{result['fps']:.1f} frames/s (median {result['median_ms']:.1f} ms, "
        f"p95 {result['p95_ms']:.1f} ms, {result['frames']} frames; "
        f"{result['fps_mean']:.1f} frames/s overall)"
    )
