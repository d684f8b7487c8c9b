"""The errors of the viz layer (all ``AeromanipError``: one line, exit code 2 on the CLI)."""

from __future__ import annotations

import importlib
from types import ModuleType

from aeromanip.errors import AeromanipError

EXTRA_HINT = "pip install 'aeromanip[viz]'"


class RenderBackendError(AeromanipError):
    """No offscreen OpenGL context could be made (the message names the fix)."""


class MissingExtraError(AeromanipError):
    """A package of the ``viz`` extra is not installed."""


def require(module: str, package: str, what: str) -> ModuleType:
    """Import ``module`` (from PyPI ``package``) for ``what``, or say how to install it."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise MissingExtraError(
            f"{what} needs the package {package!r}, not installed: {EXTRA_HINT}"
        ) from None
