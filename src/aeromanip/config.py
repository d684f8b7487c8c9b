"""Typed access to TOML tables with errors that name the key path.

Every configuration reader in aeromanip (robots, scenarios) goes through ``Table`` so
that an unknown key, a missing key or a wrong type is reported the same way.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any

from aeromanip.errors import ConfigError

_MISSING = object()


MAX_FILE_BYTES = 10_000_000  # a configuration file larger than this is not one


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file; a missing, special (FIFO, device), huge or malformed file is a
    ``ConfigError``."""
    p = Path(path)
    if not p.exists():
        raise ConfigError(f"{p}: file not found")
    if not p.is_file():  # a FIFO or a device would block or never end
        raise ConfigError(f"{p}: not a regular file")
    if p.stat().st_size > MAX_FILE_BYTES:
        raise ConfigError(f"{p}: {p.stat().st_size} bytes, too large for a configuration file")
    try:
        return tomllib.loads(p.read_bytes().decode("utf-8"))
    except OSError as e:
        raise ConfigError(f"{p}: cannot read: {e.strerror}") from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"{p}: not UTF-8 text (byte {e.start})") from None
    except (tomllib.TOMLDecodeError, RecursionError) as e:
        raise ConfigError(f"{p}: malformed TOML: {_one_line(e)}") from None


def _one_line(e: BaseException) -> str:
    text = str(e) if not isinstance(e, RecursionError) else "nested too deeply"
    return text.replace("\n", " ")


def builtin_descriptions(package: str) -> dict[str, str]:
    """Built-in TOML files of ``package`` (e.g. ``"aeromanip.robots"``): name -> description."""
    out = {}
    for item in sorted(resources.files(package).iterdir(), key=lambda p: p.name):
        if item.name.endswith(".toml"):
            data = load_toml(Path(str(item)))
            out[item.name.removesuffix(".toml")] = str(data.get("description", ""))
    return out


def resolve_toml(name_or_path: str | Path, package: str, what: str) -> Path:
    """A TOML file given by path, or by the name of a built-in of ``package``.

    ``what`` ("robot", "scenario") names the kind in the error for an unknown name.
    """
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.is_file():
        return p.resolve()
    item = resources.files(package) / f"{name_or_path}.toml"
    if not item.is_file():
        known = ", ".join(builtin_descriptions(package))
        raise ConfigError(f"{what}: unknown {what} {str(name_or_path)!r} (built-in: {known})")
    return Path(str(item))


class Table:
    """A read-only view of one TOML table that knows its key path and tracks used keys.

    ``resolved`` collects every value read, defaults included (sub-tables nested): written
    back as TOML it is the fully resolved configuration.
    """

    def __init__(self, data: Mapping[str, Any], path: str = "") -> None:
        if not isinstance(data, Mapping):
            raise ConfigError(f"{path or '<root>'}: must be a table, got {type(data).__name__}")
        self.data = data
        self.path = path
        self._used: set[str] = set()
        self.resolved: dict[str, Any] = {}

    def key(self, name: str) -> str:
        """The full key path of ``name`` in this table (an odd name quoted)."""
        shown = name if name and name.isprintable() and "." not in name else repr(name)
        return f"{self.path}.{shown}" if self.path else shown

    def has(self, name: str) -> bool:
        """Whether the table holds ``name``."""
        return name in self.data

    def raw(self, name: str, default: Any = _MISSING) -> Any:
        """The value as stored; a missing key without default is an error."""
        self._used.add(name)
        if name not in self.data:
            if default is _MISSING:
                unread = [str(k) for k in self.data if k not in self._used]
                close = difflib.get_close_matches(name, unread, n=1)
                hint = f" (is {self.key(close[0])!r} a typo?)" if close else ""
                raise ConfigError(f"{self.key(name)}: missing required key{hint}")
            value = default
        else:
            value = self.data[name]
        if value is not None and not isinstance(value, Mapping):
            self.resolved[name] = list(value) if isinstance(value, tuple) else value
        return value

    def float(
        self,
        name: str,
        default: Any = _MISSING,
        *,
        finite: bool = True,
        minimum: float | None = None,
        maximum: float | None = None,
        positive: bool = False,
    ) -> float:
        """A number (int or float); ``finite`` rejects inf/nan; optionally within
        ``[minimum, maximum]`` or ``> 0`` (``positive``)."""
        v = to_float(self.raw(name, default), self.key(name), finite=finite)
        check_range(v, self.key(name), minimum, maximum, positive)
        return v

    def int(
        self,
        name: str,
        default: Any = _MISSING,
        *,
        minimum: int | None = None,
        maximum: int | None = None,
    ) -> int:
        """An integer, optionally within ``[minimum, maximum]``."""
        v = self.raw(name, default)
        if isinstance(v, bool) or not isinstance(v, int):
            raise ConfigError(f"{self.key(name)}: expected an integer, got {v!r}")
        check_range(v, self.key(name), minimum, maximum)
        return v

    def str(self, name: str, default: Any = _MISSING, *, choices: tuple[str, ...] = ()) -> str:
        """A string, optionally one of ``choices``."""
        v = self.raw(name, default)
        if not isinstance(v, str):
            raise ConfigError(f"{self.key(name)}: expected a string, got {v!r}")
        if choices and v not in choices:
            raise ConfigError(f"{self.key(name)}: {v!r} is not one of {list(choices)}")
        return v

    def bool(self, name: str, default: Any = _MISSING) -> bool:
        """A boolean."""
        v = self.raw(name, default)
        if not isinstance(v, bool):
            raise ConfigError(f"{self.key(name)}: expected true or false, got {v!r}")
        return v

    def floats(
        self, name: str, default: Any = _MISSING, *, size: int | None = None, finite: bool = True
    ) -> tuple[float, ...]:
        """A list of numbers, optionally of a given ``size``."""
        v = self.raw(name, default)
        return to_floats(v, self.key(name), size=size, finite=finite)

    def table(self, name: str, default: Any = _MISSING) -> Table:
        """A sub-table."""
        v = self.raw(name, default)
        child = Table(v, self.key(name))
        self.resolved[name] = child.resolved
        return child

    def sub(self, name: str, data: Mapping[str, Any]) -> Table:
        """A sub-table read from ``data`` in place of the value stored under ``name``.

        Used where a string names a table kept elsewhere (e.g. a built-in robot).
        """
        self._used.add(name)
        child = Table(data, self.key(name))
        self.resolved[name] = child.resolved
        return child

    def tables(self, name: str, default: Any = _MISSING) -> list[Table]:
        """An array of tables."""
        v = self.raw(name, default)
        if not isinstance(v, list):
            raise ConfigError(f"{self.key(name)}: expected an array of tables, got {v!r}")
        children = [Table(item, f"{self.key(name)}[{i}]") for i, item in enumerate(v)]
        self.resolved[name] = [c.resolved for c in children]
        return children

    def unread(self) -> list[str]:
        """The keys of the table not read so far, in table order."""
        return [str(k) for k in self.data if k not in self._used]

    def read_keys(self) -> frozenset[str]:
        """The keys read so far (present or not)."""
        return frozenset(self._used)

    def done(self) -> None:
        """Raise on any key that was never read (a typo would otherwise pass silently)."""
        unknown = sorted(set(self.data) - self._used)
        if unknown:
            close = difflib.get_close_matches(unknown[0], sorted(self._used), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ConfigError(f"{self.key(unknown[0])}: unknown key{hint}")


def check_range(
    v: float,
    path: str,
    minimum: float | None = None,
    maximum: float | None = None,
    positive: bool = False,
) -> None:
    """A ``ConfigError`` naming ``path``, the value and the allowed range if ``v`` is
    outside ``[minimum, maximum]`` (or not > 0 with ``positive``)."""
    if positive and not v > (minimum or 0.0):
        raise ConfigError(f"{path}: must be > {minimum or 0:g}, got {v!r}")
    if minimum is not None and maximum is not None and not minimum <= v <= maximum:
        raise ConfigError(f"{path}: must be in [{minimum:g}, {maximum:g}], got {v!r}")
    if minimum is not None and v < minimum:
        raise ConfigError(f"{path}: must be >= {minimum:g}, got {v!r}")
    if maximum is not None and v > maximum:
        raise ConfigError(f"{path}: must be <= {maximum:g}, got {v!r}")


def to_float(v: Any, path: str, *, finite: bool = True) -> float:
    """Convert a TOML number to float or raise naming ``path``."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise ConfigError(f"{path}: expected a number, got {v!r}")
    f = float(v)
    if math.isnan(f) or (finite and math.isinf(f)):
        raise ConfigError(f"{path}: must be a finite number, got {v!r}")
    return f


def to_floats(
    v: Any, path: str, *, size: int | None = None, finite: bool = True
) -> tuple[float, ...]:
    """Convert a TOML array of numbers or raise naming ``path``."""
    if not isinstance(v, list | tuple):
        raise ConfigError(f"{path}: expected an array of numbers, got {v!r}")
    if size is not None and len(v) != size:
        raise ConfigError(f"{path}: expected {size} numbers, got {len(v)}")
    return tuple(to_float(x, f"{path}[{i}]", finite=finite) for i, x in enumerate(v))


def parse_override(text: str) -> tuple[list[str], Any]:
    """``"a.b.c=VALUE"`` -> (["a", "b", "c"], value); VALUE is read as TOML, else a string."""
    key, sep, value = text.partition("=")
    key = key.strip()
    if not sep or not key or any(not part for part in key.split(".")):
        raise ConfigError(f"--set {text!r}: expected KEY=VALUE with a dotted KEY")
    try:
        parsed = tomllib.loads(f"v = {value.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value.strip()
    except RecursionError:
        raise ConfigError(f"--set {key}: the value is nested too deeply") from None
    return key.split("."), parsed


def apply_override(
    data: dict[str, Any],
    path: list[str],
    value: Any,
    where: str,
    free_form: tuple[str, ...] = (),
) -> None:
    """Set ``data[path...] = value`` in place; every table on the path must exist, but
    below a ``free_form`` table (a dotted key path) missing tables are created."""
    node: Any = data
    for i, part in enumerate(path[:-1]):
        free = any(".".join(path[:i]).startswith(f) for f in free_form if i)
        if free and isinstance(node, dict) and part not in node:
            node[part] = {}
        if not isinstance(node, dict) or part not in node or not isinstance(node[part], dict):
            raise ConfigError(f"{where}: unknown key {'.'.join(path[: i + 1])!r}")
        node = node[part]
    node[path[-1]] = value
