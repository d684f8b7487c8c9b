"""Command line: ``aeromanip run | list | plot | bench | fly | sitl ...`` (one module per
command).

Errors a user can cause (unknown names, bad values, malformed files) print one line and
exit with code 2, without a traceback. A run that did not fly exits 3; a run stopped by
SIGINT / SIGTERM exits 130 / 143 (see ``cli.run``).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from aeromanip.cli import bench, fly, identify, listing, plot, replay, sitl, sweep
from aeromanip.cli import run as run_command
from aeromanip.errors import AeromanipError
from aeromanip.interrupts import RunInterrupted, stop_on_signals

EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130


def one_line(text: str) -> str:
    """``text`` on one line: line breaks (e.g. inside a quoted key) shown as ``\\n``."""
    return text.replace("\r", "\\r").replace("\n", "\\n")


def build_parser() -> argparse.ArgumentParser:
    """The ``aeromanip`` argument parser."""
    parser = argparse.ArgumentParser(
        prog="aeromanip", description="NMPC for aerial manipulators (Lunni et al., ICUAS 2017)"
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for command in (run_command, plot, replay, listing, bench, identify, sweep, fly, sitl):
        command.add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``aeromanip`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        with stop_on_signals():
            return int(args.func(args))
    except AeromanipError as e:  # one line, whatever user text the message quotes
        print(f"aeromanip: error: {one_line(str(e))}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BrokenPipeError:  # e.g. piped into `head`
        sys.stderr.close()
        return 0
    except RunInterrupted as e:
        print(f"aeromanip: interrupted ({e})", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("aeromanip: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
