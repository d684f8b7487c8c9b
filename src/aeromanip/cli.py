"""Command line: ``aeromanip list | bench``.

Errors a user can cause (unknown names, bad values, malformed files) print one line and
exit with code 2, without a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from aeromanip.errors import AeromanipError


def _cmd_list(args: argparse.Namespace) -> int:
    from aeromanip.robot.loader import builtin_robots

    print("robots:")
    for name, text in builtin_robots().items():
        print(f"  {name:<16} {text}")
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from aeromanip.bench.kinematics import bench_kinematics, format_kinematics

    results = {}
    if args.what in ("kinematics", "all"):
        for robot in ("planar-2dof", "x8-3dof"):
            r = bench_kinematics(robot)
            results[f"kinematics/{robot}"] = r
            print(format_kinematics(r))
            print()
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2))
        print(f"wrote {args.json}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The ``aeromanip`` argument parser."""
    parser = argparse.ArgumentParser(
        prog="aeromanip", description="NMPC for aerial manipulators (Lunni et al., ICUAS 2017)"
    )
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("list", help="built-in robots and scenarios, one line each")
    p.set_defaults(func=_cmd_list)
    p = sub.add_parser("bench", help="measure evaluation and controller step times")
    p.add_argument("what", nargs="?", default="all", choices=["all", "kinematics"])
    p.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    p.set_defaults(func=_cmd_bench)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``aeromanip`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except AeromanipError as e:
        print(f"aeromanip: error: {e}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # e.g. piped into `head`
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print("aeromanip: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
