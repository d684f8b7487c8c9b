"""``mujoco``, imported once for the simulator's modules: its import fails on a
``MUJOCO_GL`` it does not know (its renderer's check), which becomes one ``ConfigError``
line naming the variable and the fix."""

import os

from aeromanip.errors import ConfigError

try:
    import mujoco
except ImportError:
    raise
except RuntimeError as _e:
    raise ConfigError(
        f"MUJOCO_GL={os.environ.get('MUJOCO_GL', '')!r}: MuJoCo will not load with it "
        f"({' '.join(str(_e).split())[:120]}); unset it, or set egl or osmesa (offscreen) "
        "or glfw (a display)"
    ) from None

__all__ = ["mujoco"]
