"""The one exception root of aeromanip, its few children, and the command's exit codes.

Every error carries the exit code the command line ends with when it stops a command
(``ExitCode``; the table is in ``docs/exit-codes.md``).
"""

import errno
from enum import IntEnum


class ExitCode(IntEnum):
    """The exit codes of the ``aeromanip`` command (one definition)."""

    OK = 0
    BAD_INPUT = 2  # an option, file or name is wrong: nothing was built or flown
    DID_NOT_FLY = 3  # it ran, but did not really fly (or runs of a sweep failed)
    LINK = 4  # a link could not be opened or was lost; the vehicle or a cluster refused
    IO = 5  # reading or writing a file failed (disk full, permission, read-only, I/O)
    SIGINT = 130  # 128 + SIGINT (2): stopped by Ctrl-C
    SIGTERM = 143  # 128 + SIGTERM (15)


class AeromanipError(Exception):
    """Root of every error raised on purpose by aeromanip."""

    exit_code = ExitCode.BAD_INPUT


class ConfigError(AeromanipError, ValueError):
    """An invalid robot description, scenario or option; the message names the key path."""


class InfeasibleProblemError(AeromanipError):
    """A problem whose constraints cannot all hold, detected before solving."""


class StateError(AeromanipError, ValueError):
    """A state given to the controller or simulator is malformed (NaN, wrong length)."""


class OutputError(AeromanipError, OSError):
    """Writing a run's files failed (the disk is full, a permission or a read-only file
    system refused it, the device failed); the message names the file and the fix."""

    exit_code = ExitCode.IO


FIXES = {  # errno name -> what the user can do
    "ENOSPC": "free some space or write elsewhere (--out)",
    "EDQUOT": "free some space or write elsewhere (--out)",
    "EACCES": "check its permissions or write elsewhere (--out)",
    "EPERM": "check its permissions and attributes (chattr) or write elsewhere (--out)",
    "EROFS": "the file system is read-only: write elsewhere (--out)",
    "EIO": "the device failed: check it (dmesg) and write elsewhere (--out)",
    "ENOENT": "check the path",
    "ENOTDIR": "a part of the path is a file, not a directory: check the path",
    "EISDIR": "the path is a directory: name a file",
}


def describe_os_error(e: OSError, root: str | None = None) -> str:
    """One line of an ``OSError``: the file (relative to ``root`` if below it), what
    failed (with the errno name), the fix."""
    if e.errno is None:
        return str(e)
    name = errno.errorcode.get(e.errno, str(e.errno))
    where = "" if e.filename is None else f"{e.filename}: "
    if root is not None and str(e.filename).startswith(f"{root}/"):
        where = f"{str(e.filename)[len(str(root)) + 1 :]}: "
    fix = FIXES.get(name)
    return f"{where}{e.strerror or name} ({name})" + (f"; {fix}" if fix else "")
