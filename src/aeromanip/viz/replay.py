"""``replay``: render a saved run (or its variants side by side) to MP4, GIF or a PNG still.

Frame ``i`` shows time ``t0 + i * speed / fps`` of the run (poses interpolated linearly
between logged rows), up to its last row. The default speed keeps the video at most
``MAX_AUTO_VIDEO_S`` long: 1x for the paper's short scenarios, 10x for the 13-min flight
(``auto_speed``). Variants are rendered in panels of ``size`` each, left to right in their
run order; a variant that ends sooner holds its last pose.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from aeromanip.errors import ConfigError
from aeromanip.experiment.rundir import check_file_writable
from aeromanip.viz.render import Panel
from aeromanip.viz.runs import SavedRun, find_runs
from aeromanip.viz.video import FrameWriter, check_gif, check_size, output_kind

DEFAULT_SIZE = (640, 480)  # [px] of a panel
DEFAULT_FPS = {"mp4": 30.0, "gif": 10.0, "png": 30.0}
MAX_AUTO_VIDEO_S = 90.0  # [s] longest video the default speed gives
NICE_SPEEDS = (1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0)
MAX_SPEED = 1e4
MAX_FPS = 120.0
MAX_FRAMES = 216_000  # two hours at 30 frames/s
VIDEO_FILE = "replay.mp4"


@dataclass(frozen=True)
class ReplayResult:
    """What ``replay`` wrote: the file, its frames, rate [1/s], speed, size [px], video
    length, run time of the first frame and wall time [s]."""

    path: Path
    frames: int
    fps: float
    speed: float
    size: tuple[int, int]
    video_s: float
    start_s: float
    wall_s: float
    problems: tuple[str, ...] = ()  # what is damaged in the runs rendered (one line each)

    @property
    def render_fps(self) -> float:
        """Frames rendered and written per wall-clock second."""
        return self.frames / self.wall_s if self.wall_s > 0 else math.inf


def auto_speed(duration_s: float) -> float:
    """The smallest of ``NICE_SPEEDS`` giving a video of at most ``MAX_AUTO_VIDEO_S``."""
    for s in NICE_SPEEDS:
        if duration_s / s <= MAX_AUTO_VIDEO_S:
            return s
    return NICE_SPEEDS[-1]


def frame_times(t0: float, t1: float, fps: float, speed: float) -> np.ndarray:
    """Run times [s] of the frames: ``t0 + i speed / fps`` for every one up to ``t1``."""
    n = math.floor((t1 - t0) * fps / speed + 1e-9) + 1
    return t0 + np.arange(max(n, 1)) * (speed / fps)


def _check(speed: float | None, fps: float | None) -> None:
    if speed is not None and not (0 < speed <= MAX_SPEED and math.isfinite(speed)):
        raise ConfigError(f"--speed: must be in (0, {MAX_SPEED:g}], got {speed}")
    if fps is not None and not (0 < fps <= MAX_FPS and math.isfinite(fps)):
        raise ConfigError(f"--fps: must be in (0, {MAX_FPS:g}], got {fps}")


def replay(
    run_dir: str | Path,
    out: str | Path | None = None,
    *,
    speed: float | None = None,
    size: tuple[int, int] = DEFAULT_SIZE,
    fps: float | None = None,
    at: float | None = None,
    quality: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> ReplayResult:
    """Render ``run_dir`` to ``out`` (default ``run_dir/replay.mp4``).

    Args:
        run_dir: a run directory, or a directory of variant runs (side by side).
        out: ``.mp4``, ``.gif`` or ``.png`` (one still, at time ``at``).
        speed: run seconds per video second (default ``auto_speed``).
        size: (width, height) of each panel [px].
        fps: video frame rate [1/s] (default 30 for MP4, 10 for GIF).
        at: time of the PNG still [s] (default: the middle of the run).
        quality: ``fast`` (default for videos) or ``high`` (smooth edges, about 4x slower;
            default for a still); see ``viz.render.QUALITY``.
        progress: called with (frames done, frames) after each frame.
    """
    _check(speed, fps)
    size = check_size(size)
    out = Path(out) if out is not None else Path(run_dir) / VIDEO_FILE
    kind = output_kind(out)
    if at is not None and kind != "png":
        raise ConfigError(f"--at: picks the time of a .png still; --out is {out}")
    check_file_writable(out)
    runs = find_runs(Path(run_dir))
    t0 = min(float(r.traj.t[0]) for r in runs)
    t1 = max(float(r.traj.t[-1]) for r in runs)
    speed = speed or auto_speed(t1 - t0)
    fps = fps or DEFAULT_FPS[kind]
    if kind == "png":
        times = np.array([_still_time(at, t0, t1)])
    else:
        if (t1 - t0) * fps / speed > MAX_FRAMES:
            raise ConfigError(
                f"--speed: {speed:g} gives more than {MAX_FRAMES} frames for {t1 - t0:g} s of "
                f"run at {fps:g} fps; use --speed {(t1 - t0) * fps / MAX_FRAMES:.3g} or more"
            )
        times = frame_times(t0, t1, fps, speed)
        if kind == "gif":
            check_gif(len(times), size[0] * len(runs), size[1])
    quality = quality or ("high" if kind == "png" else "fast")
    return _render(runs, out, times, (size, quality), fps, speed, progress)


def _still_time(at: float | None, t0: float, t1: float) -> float:
    if at is None:
        return 0.5 * (t0 + t1)
    if not (t0 <= at <= t1):
        raise ConfigError(f"--at: must be a time of the run, in [{t0:g}, {t1:g}] s, got {at}")
    return float(at)


def _render(
    runs: list[SavedRun],
    out: Path,
    times: np.ndarray,
    look: tuple[tuple[int, int], str],
    fps: float,
    speed: float,
    progress: Callable[[int, int], None] | None,
) -> ReplayResult:
    """Render every frame of every panel and write them; the renderers are freed after."""
    (w, h), quality = look
    panels: list[Panel] = []
    start = time.perf_counter()
    try:
        for r in runs:
            panels.append(Panel(r, w, h, label=_label(r, len(runs)), quality=quality))
        with FrameWriter(out, w * len(panels), h, fps) as writer:
            for i, t in enumerate(times):
                frames = [p.frame(float(t)) for p in panels]
                writer.write(frames[0] if len(frames) == 1 else np.hstack(frames))
                if progress is not None:
                    progress(i + 1, len(times))
    finally:
        for p in panels:
            p.close()
    return ReplayResult(
        out,
        len(times),
        fps,
        speed,
        (w * len(panels), h),
        len(times) / fps,
        float(times[0]),
        time.perf_counter() - start,
        tuple(p for r in runs for p in r.problems),
    )


def _label(run: SavedRun, n: int) -> str:
    """The caption's title: the scenario (with its variant when side by side)."""
    return run.name if n == 1 or "/" in run.name else f"{run.name} ({run.path.name})"


def print_progress(done: int, total: int) -> None:
    """A progress counter on stderr (one line rewritten on a terminal, else the end only)."""
    if sys.stderr.isatty() and (done == total or done % 25 == 0):
        end = "\n" if done == total else ""
        print(f"\rrendering frame {done}/{total}", end=end, file=sys.stderr, flush=True)
    elif done == total:
        print(f"rendered {total} frames", file=sys.stderr, flush=True)
