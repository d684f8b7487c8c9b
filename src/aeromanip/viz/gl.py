"""Headless OpenGL for MuJoCo's offscreen renderer, whatever the import order.

``mujoco.Renderer`` takes its GL backend from ``MUJOCO_GL`` as it was when ``mujoco`` was
first imported (GLFW, which needs a display, when unset). The replay makes its own context
instead, with the backend ``MUJOCO_GL`` names if set, else the first of ``AUTO`` whose
library is installed: EGL (a GPU driver, or Mesa's software ``llvmpipe`` on a plain
machine: no display, no X server), then OSMesa. PyOpenGL serves one platform per process,
so the choice is made once, before OpenGL is loaded. When neither works the error names
the fix (``FIX``).
"""

from __future__ import annotations

import ctypes.util
import os
from types import ModuleType
from typing import Any, Protocol

from aeromanip.viz.dependencies import RenderBackendError

BACKENDS = ("egl", "osmesa", "glfw")
AUTO = (("egl", "EGL"), ("osmesa", "OSMesa"))  # (backend, library) tried without MUJOCO_GL
FIX = (
    "set MUJOCO_GL=egl (Debian/Ubuntu: apt install libegl1 libgl1-mesa-dri) "
    "or MUJOCO_GL=osmesa (apt install libosmesa6)"
)


class GLContext(Protocol):
    """What MuJoCo's GL context classes (``mujoco.egl``, ``.osmesa``, ``.glfw``) offer."""

    def make_current(self) -> None: ...

    def free(self) -> None: ...


def backend_name() -> str:
    """The backend: ``MUJOCO_GL`` if set (``RenderBackendError`` if it names none of
    ``BACKENDS``), else the first of ``AUTO`` whose library is found (``egl`` if none is:
    its error then names the fix)."""
    name = os.environ.get("MUJOCO_GL", "").strip().lower()
    if name in ("", "1", "true", "on", "enable", "enabled"):
        found = [b for b, lib in AUTO if ctypes.util.find_library(lib)]
        return found[0] if found else AUTO[0][0]
    if name == "glx":
        return "glfw"
    if name not in BACKENDS:
        raise RenderBackendError(
            f"MUJOCO_GL={name!r}: not an offscreen backend (allowed: egl, osmesa, glfw); {FIX}"
        )
    return name


def import_mujoco() -> ModuleType:
    """``mujoco``, or a ``RenderBackendError`` naming the fix: its import fails outright
    (not only its renderer) when ``MUJOCO_GL`` names a backend this machine lacks."""
    try:
        import mujoco
    except ImportError:
        raise  # mujoco itself is missing: a dependency of aeromanip, not of the viz extra
    except Exception as e:  # PyOpenGL's AttributeError, mujoco's RuntimeError
        reason = " ".join(str(e).split())[:160] or type(e).__name__
        name = os.environ.get("MUJOCO_GL", "")
        raise RenderBackendError(
            f"cannot load MuJoCo with MUJOCO_GL={name} ({reason}); {FIX}"
        ) from None
    return mujoco


def _context_class(name: str) -> Any:
    if name == "egl":
        from mujoco.egl import GLContext as Egl

        return Egl
    if name == "osmesa":
        from mujoco.osmesa import GLContext as OSMesa

        return OSMesa
    from mujoco.glfw import GLContext as Glfw

    return Glfw


def make_context(width: int, height: int) -> GLContext:
    """A GL context of at least ``width`` x ``height`` pixels, made current.

    Raises ``RenderBackendError`` naming ``MUJOCO_GL`` and the packages to install when
    the backend cannot be loaded or started.
    """
    name = backend_name()
    import_mujoco()
    try:
        ctx = _context_class(name)(width, height)
        ctx.make_current()
    except Exception as e:  # ImportError, OSError, RuntimeError, PyOpenGL's own errors
        reason = " ".join(str(e).split())[:160] or type(e).__name__
        raise RenderBackendError(
            f"no offscreen OpenGL with MUJOCO_GL={name} ({reason}); {FIX}"
        ) from None
    return ctx
