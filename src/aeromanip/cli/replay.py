"""``aeromanip replay RUN_DIR``: a 3D video (or a still) of a saved run, rendered headless.

A directory of variants renders them side by side. ``--out`` picks the format by its
suffix: ``.mp4`` (default ``RUN_DIR/replay.mp4``), ``.gif`` or ``.png`` (one still at
``--at``). ``--mcap`` also (re)writes each run's ``run.mcap`` for Foxglove. A damaged run
(its log cut short, no ``meta.json``) is rendered from what is whole, and the command
says what is wrong and exits 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from aeromanip.errors import ExitCode


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command."""
    p = sub.add_parser("replay", help="render a saved run to a 3D video (MP4, GIF) or a still")
    p.add_argument("dir", help="a run directory (or a directory of variant runs)")
    p.add_argument(
        "--out", metavar="FILE", help="FILE.mp4 | FILE.gif | FILE.png (default DIR/replay.mp4)"
    )
    p.add_argument(
        "--speed",
        type=float,
        metavar="X",
        help="run seconds per video second "
        "(default: 1, or more to keep the video within 90 s; 10 for the flight)",
    )
    p.add_argument(
        "--size", default="640x480", metavar="WxH", help="size of each panel (default 640x480)"
    )
    p.add_argument("--fps", type=float, help="frames per second (default 30 MP4, 10 GIF)")
    p.add_argument(
        "--at",
        type=float,
        metavar="T",
        help="time of a .png still [s] (default: the middle of the run)",
    )
    p.add_argument(
        "--quality",
        choices=("fast", "high"),
        help="fast (default for videos) or high: smooth edges, rendered at twice the size "
        "(default for a still), about 4x slower",
    )
    p.add_argument("--mcap", action="store_true", help="also write each run's run.mcap")
    p.add_argument("--quiet", action="store_true", help="no progress counter")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Render (and write the MCAPs); print what was written."""
    from aeromanip.viz.mcap_log import write_mcaps
    from aeromanip.viz.replay import print_progress, replay
    from aeromanip.viz.video import parse_size

    size = parse_size(args.size)
    result = replay(
        Path(args.dir),
        args.out,
        speed=args.speed,
        size=size,
        fps=args.fps,
        at=args.at,
        quality=args.quality,
        progress=None if args.quiet else print_progress,
    )
    w, h = result.size
    if result.path.suffix.lower() == ".png":
        what = f"a still {w}x{h} at t = {result.start_s:g} s"
    else:
        what = (
            f"{result.frames} frames {w}x{h}, {result.video_s:.1f} s at {result.fps:g} fps, "
            f"speed {result.speed:g}x; {result.render_fps:.1f} frames/s"
        )
    print(f"wrote {result.path}: {what} (rendered in {result.wall_s:.1f} s)")
    if args.mcap:
        for path in write_mcaps(Path(args.dir)):
            print(f"wrote {path}")
    if result.problems:  # rendered what is whole, but the run is damaged: not a clean 0
        print(f"aeromanip: error: {'; '.join(result.problems)}", file=sys.stderr)
        return ExitCode.BAD_INPUT
    return 0
