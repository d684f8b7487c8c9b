"""The public API: every name a package exports in ``__all__`` imports and is documented.

Documented means: named in its package's docstring (the list of exports a user reads with
``help(aeromanip.nmpc)``), and a class or function of its own carries a docstring.
Exports that need a heavy or optional package are imported on first use, so that
``import aeromanip`` stays light: checked in a fresh interpreter.
"""

import importlib
import inspect
import subprocess
import sys

import pytest

PACKAGES = [
    "aeromanip",
    "aeromanip.nmpc",
    "aeromanip.sim",
    "aeromanip.experiment",
    "aeromanip.references",
    "aeromanip.tasks",
    "aeromanip.sweep",
    "aeromanip.viz",
    "aeromanip.runtime",
    "aeromanip.mavlink",
    "aeromanip.robot",
]
# what the top-level package documents by its own docstring and the sub-packages'
TOP_LEVEL_SEE_ALSO = ("aeromanip.nmpc", "aeromanip.robot", "aeromanip.tasks", "aeromanip.errors")


def exported(package: str) -> list[tuple[str, object]]:
    mod = importlib.import_module(package)
    return [(name, getattr(mod, name)) for name in mod.__all__]


@pytest.mark.parametrize("package", PACKAGES)
def test_every_export_imports_and_is_documented(package):
    mod = importlib.import_module(package)
    assert mod.__all__ and len(set(mod.__all__)) == len(mod.__all__)
    doc = mod.__doc__ or ""
    for name, obj in exported(package):
        home = getattr(obj, "__module__", package) or package
        assert home.startswith("aeromanip"), f"{package}.{name} comes from {home}"
        if package != "aeromanip":
            assert f"``{name}``" in doc, f"{package}: {name} is not named in its docstring"
        if inspect.isclass(obj) or inspect.isfunction(obj):
            assert (obj.__doc__ or "").strip(), f"{package}.{name} has no docstring"


def test_the_top_level_exports_are_documented_in_their_sub_packages():
    import aeromanip

    documented = {
        n for p in TOP_LEVEL_SEE_ALSO for n in getattr(importlib.import_module(p), "__all__", [])
    }
    documented |= {"AeromanipError", "ConfigError", "InfeasibleProblemError", "StateError"}
    assert set(aeromanip.__all__) <= documented, set(aeromanip.__all__) - documented


def test_star_free_imports_from_packages_give_the_defining_objects():
    from aeromanip.nmpc import IpoptBackend, SqpRtiBackend
    from aeromanip.nmpc.backends import BACKENDS
    from aeromanip.sim import SIMULATORS, PhysicsSimulator

    assert BACKENDS.get("ipopt") is IpoptBackend and BACKENDS.get("sqp-rti") is SqpRtiBackend
    assert SIMULATORS.get("physics") is PhysicsSimulator
    with pytest.raises(AttributeError, match="no attribute 'Nope'"):
        importlib.import_module("aeromanip.experiment").Nope  # noqa: B018


def test_import_aeromanip_loads_no_optional_or_heavy_package():
    code = (
        "import sys, aeromanip, aeromanip.sim, aeromanip.experiment, aeromanip.runtime, "
        "aeromanip.mavlink, aeromanip.sweep\n"
        "heavy = ('ray', 'pymavlink', 'mcap', 'mujoco', 'matplotlib', 'foxglove')\n"
        "print(' '.join(m for m in heavy if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""
