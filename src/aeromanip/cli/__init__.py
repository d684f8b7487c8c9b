"""Command line: ``aeromanip run | list | plot | bench | fly | sitl ...`` (one module per
command).

Every way a command can end is one line on stderr and an exit code of
``aeromanip.errors.ExitCode`` (``docs/exit-codes.md``): 2 bad input (argparse's errors
included), 3 did not fly, 4 link, 5 I/O, 130 / 143 SIGINT / SIGTERM, which are handled
from the first line of ``main`` to the last file written.
"""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Sequence
from typing import NoReturn

from aeromanip.cli import bench, export, fly, identify, listing, plot, replay, sitl, sweep
from aeromanip.cli import run as run_command
from aeromanip.errors import AeromanipError, ConfigError, ExitCode, describe_os_error
from aeromanip.interrupts import RunInterrupted, interrupted, stop_on_signals


def one_line(text: str) -> str:
    """``text`` on one line: line breaks (e.g. inside a quoted key) shown as ``\\n``."""
    return text.replace("\r", "\\r").replace("\n", "\\n")


class UsageError(ConfigError):
    """A command line argparse refused (exit 2, one line)."""


class OneLineParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are one line naming the option (no usage)."""

    def error(self, message: str) -> NoReturn:
        for prefix in ("argument ", "the following arguments are required: "):
            if message.startswith(prefix):
                rest = message[len(prefix) :]
                message = rest if prefix == "argument " else f"{rest}: required"
        if message.startswith("unrecognized arguments: "):
            message = f"{message.split(': ', 1)[1]}: not an option of this command"
        raise UsageError(f"{message} (see {self.prog} --help)")


def build_parser() -> argparse.ArgumentParser:
    """The ``aeromanip`` argument parser."""
    parser = OneLineParser(
        prog="aeromanip", description="NMPC for aerial manipulators (Lunni et al., ICUAS 2017)"
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for command in (run_command, plot, replay, listing, bench, identify, sweep, fly, sitl, export):
        command.add_parser(sub)
    return parser


def _fail(message: str, code: int) -> int:
    print(f"aeromanip: {one_line(message)}", file=sys.stderr)
    return int(code)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``aeromanip`` console script (``argv`` None: ``sys.argv``, and
    a signal after the last file is written no longer kills the ending process)."""
    try:
        with stop_on_signals(keep=argv is None):
            args = build_parser().parse_args(argv)
            _check_environment()
            return int(args.func(args))
    except SystemExit:  # --help
        raise
    except BaseException as e:
        return _ending(e)


def _check_environment() -> None:
    """Refuse a bad ``$AEROMANIP_CODEGEN_OPT`` in one line before any work."""
    from aeromanip.nmpc.backends.codegen import cflags

    cflags()


def _ending(e: BaseException) -> int:
    """The one line and the exit code of a command stopped by ``e`` (re-raised if it is
    a bug: no signal, not an error of aeromanip or of the operating system)."""
    if (signum := interrupted()) is not None or isinstance(e, RunInterrupted):
        # a signal, or what it broke (an extension's import fails with an ImportError)
        if isinstance(e, RunInterrupted):
            return _fail(f"interrupted ({e})", e.exit_code)
        return _fail(f"interrupted ({signal.Signals(signum).name})", 128 + int(signum))
    if isinstance(e, AeromanipError):  # one line, whatever user text the message quotes
        text = describe_os_error(e) if isinstance(e, OSError) else str(e)
        return _fail(f"error: {text}", e.exit_code)
    if isinstance(e, BrokenPipeError):  # e.g. piped into `head`
        sys.stderr.close()
        return 0
    if isinstance(e, OSError):  # a file the command reads or writes
        return _fail(f"error: {describe_os_error(e)}", ExitCode.IO)
    if isinstance(e, KeyboardInterrupt):
        return _fail("interrupted", ExitCode.SIGINT)
    raise e


if __name__ == "__main__":
    sys.exit(main())
