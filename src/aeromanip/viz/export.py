"""What ``aeromanip run`` writes after a run from its directory: each run's ``run.mcap``
(on by default, ``--no-mcap`` to skip) and, with ``--video``, ``DIR/replay.mp4``.

The MCAP is written after the run from the files the run streamed (``log.csv``,
``robot.urdf``), so the closed loop is not slowed. A run stopped by a signal stops at once
and writes none: ``aeromanip replay DIR --mcap`` writes it from the rows kept. Without the
``viz`` extra the MCAP is skipped with a note: it never fails a run that flew. ``--video``
checks the offscreen renderer before the run.
"""

from __future__ import annotations

import sys
from pathlib import Path

from aeromanip.errors import AeromanipError
from aeromanip.viz.dependencies import MissingExtraError, require
from aeromanip.viz.gl import make_context


def check_video() -> None:
    """Fail before a run if its ``--video`` could not be rendered (one-line error)."""
    require("imageio_ffmpeg", "imageio-ffmpeg", "--video")
    require("PIL.Image", "pillow", "--video")
    make_context(16, 16).free()


def export_run(out_dir: Path, *, mcap: bool = True, video: bool = False) -> list[Path]:
    """Write the MCAP of every run under ``out_dir`` and, with ``video``, its replay;
    returns the files written (each also printed). An MCAP that cannot be written (no
    ``viz`` extra, a run stopped before its first row) is a note on stderr, not an error."""
    from aeromanip.viz.mcap_log import write_mcap
    from aeromanip.viz.replay import print_progress, replay
    from aeromanip.viz.runs import run_dirs

    written: list[Path] = []
    try:
        dirs = run_dirs(out_dir) if mcap else []
    except AeromanipError as e:  # e.g. stopped before its first row
        print(f"aeromanip: run.mcap not written: {e}", file=sys.stderr)
        dirs = []
    for d in dirs:
        try:
            written.append(write_mcap(d))
        except MissingExtraError as e:
            print(f"aeromanip: run.mcap not written: {e}", file=sys.stderr)
            break
        except AeromanipError as e:
            print(f"aeromanip: {d}/run.mcap not written: {e}", file=sys.stderr)
    if video:
        written.append(replay(out_dir, progress=print_progress).path)
    for path in written:
        print(f"wrote {path}")
    return written
