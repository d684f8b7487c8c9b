"""Registries by name: tasks, references, backends, simulators.

A registry maps a name (``"tracking"``, ``"waypoints"``, ``"sqp"``, ``"physics"``) to a
class. Built-in classes register themselves with ``@REGISTRY.register("name")`` in their
own module, and the registry imports every module of its package (sub-packages included)
the first time it is asked for a name, so that adding a built-in is one new file. A
user's class needs no registration at all: ``"package.module:Class"`` (in a scenario TOML
or any call that takes a kind) is imported with ``importlib`` and checked to be a subclass
of the registry's base class.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable
from typing import Generic, TypeVar

from aeromanip.errors import ConfigError

T = TypeVar("T")


class Registry(Generic[T]):
    """Classes of one kind by name, with ``package.module:Class`` for user classes.

    Args:
        what: what the registry holds, for messages (``"task"``, ``"backend"``...).
        package: the package whose modules hold the built-ins (imported on first lookup).
        base: the class every entry must derive from.
    """

    def __init__(self, what: str, package: str, base: type[T]) -> None:
        self.what = what
        self.package = package
        self.base = base
        self._items: dict[str, type[T]] = {}
        self._discovered = False

    def register(self, name: str) -> Callable[[type[T]], type[T]]:
        """Class decorator: register the class under ``name`` (and set its ``kind``)."""

        def add(cls: type[T]) -> type[T]:
            if name in self._items and self._items[name] is not cls:
                raise ConfigError(f"{self.what} {name!r}: registered twice")
            self._items[name] = cls
            cls.kind = name  # type: ignore[attr-defined]
            return cls

        return add

    def _discover(self) -> None:
        """Import every module of ``package`` and its sub-packages once (their decorators
        fill the registry)."""
        if self._discovered:
            return
        self._discovered = True
        pkg = importlib.import_module(self.package)
        # a package's modules (sub-packages included); a module holds its own built-ins
        for info in pkgutil.walk_packages(getattr(pkg, "__path__", []), f"{self.package}."):
            importlib.import_module(info.name)

    def names(self) -> tuple[str, ...]:
        """The built-in names, sorted."""
        self._discover()
        return tuple(sorted(self._items))

    def __contains__(self, name: object) -> bool:
        self._discover()
        return name in self._items

    def get(self, kind: str, key: str | None = None) -> type[T]:
        """The class registered as ``kind``, or loaded from ``"package.module:Class"``.

        ``key`` names the configuration key in errors (default: the registry's ``what``).
        """
        key = key or self.what
        if not isinstance(kind, str) or not kind:
            raise ConfigError(f"{key}: expected a {self.what} name, got {kind!r}")
        if ":" in kind:
            return self._load(kind, key)
        self._discover()
        if kind not in self._items:
            raise ConfigError(
                f"{key}: {kind!r} is not one of {list(self.names())} "
                f"(or 'package.module:Class' for a {self.what} of your own)"
            )
        return self._items[kind]

    def _load(self, kind: str, key: str) -> type[T]:
        module_name, _, attr = kind.partition(":")
        if not module_name or not attr:
            raise ConfigError(f"{key}: {kind!r}: expected 'package.module:Class'")
        try:
            module = importlib.import_module(module_name)
        except (ImportError, TypeError, ValueError) as e:  # relative or malformed names too
            raise ConfigError(f"{key}: {kind!r}: cannot import {module_name!r} ({e})") from None
        obj = module
        for part in attr.split("."):
            if not hasattr(obj, part):
                raise ConfigError(f"{key}: {kind!r}: {module_name!r} has no {attr!r}")
            obj = getattr(obj, part)
        if not (isinstance(obj, type) and issubclass(obj, self.base)):
            raise ConfigError(
                f"{key}: {kind!r} is not a {self.base.__name__} subclass "
                f"(a {self.what} must derive from {self.base.__module__}.{self.base.__name__})"
            )
        return obj


def lazy_exports(
    package: str, table: dict[str, str], namespace: dict[str, object]
) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """A package's ``__getattr__`` and ``__dir__`` for exports imported on first use.

    Args:
        package: the package's ``__name__`` (for the error of an unknown name).
        table: export name -> the module that defines it.
        namespace: the package's ``globals()`` (what ``dir()`` lists besides the exports).
    """

    def getattr_(name: str) -> object:
        if name in table:
            return getattr(importlib.import_module(table[name]), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def dir_() -> list[str]:
        return sorted({*namespace, *table})

    return getattr_, dir_
