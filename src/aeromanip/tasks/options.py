"""A task's options from its constructor: a scenario's ``[tasks.NAME]`` keys matched
against the keyword parameters of the task class's ``__init__``.

``Task.from_table`` uses it by default, so a task of your own whose constructor takes
options (``def __init__(self, z_ref: float, axis: str = "z")``) is configured from a
scenario TOML without a hand-written ``from_table``. Each value is checked against the
parameter's annotation (``float``, ``int``, ``bool``, ``str``, ``Literal[...]``, lists,
tuples and ``Sequence`` of these, ``dict``, ``np.ndarray``, ``X | Y``) and a key the
constructor does not take, a missing required option or a value of the wrong type is one
``ConfigError`` naming the key, the value and what is allowed, before anything is built.
A parameter annotated ``Reference`` (or named ``reference`` without annotation) receives
the scenario's end-effector reference.
"""

from __future__ import annotations

import difflib
import inspect
import types
import typing
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from aeromanip.config import Table, to_float
from aeromanip.errors import ConfigError
from aeromanip.references import Reference

_SCALARS = (bool, int, float, str)


def constructor_options(cls: type, table: Table, reference: Reference | None) -> dict[str, Any]:
    """The keyword arguments for ``cls(...)`` read from ``table`` (module docstring)."""
    params = _parameters(cls)
    options = {name: p for name, p in params.items() if not _is_reference(p)}
    allowed = ", ".join(f"{name} ({_describe(p.annotation)})" for name, p in options.items())
    for key in table.unread():
        if key not in options:
            close = difflib.get_close_matches(key, [*options, *table.read_keys()], n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            takes = f"takes {allowed}" if allowed else "takes no option"
            raise ConfigError(f"{table.key(key)}: unknown key ({cls.__name__} {takes}{hint})")
    kwargs: dict[str, Any] = {}
    for name, p in params.items():
        if _is_reference(p):
            kwargs[name] = reference
        elif table.has(name):
            kwargs[name] = _checked(table.raw(name), p.annotation, table.key(name))
        elif p.default is inspect.Parameter.empty:
            raise ConfigError(
                f"{table.key(name)}: missing required key ({cls.__name__} needs "
                f"{_describe(p.annotation)})"
            )
        elif _toml_value(p.default):
            table.raw(name, p.default)  # recorded: the resolved scenario states it
    return kwargs


def _parameters(cls: type) -> dict[str, inspect.Parameter]:
    """The constructor's keyword parameters, annotations evaluated where they can be."""
    init = cls.__init__  # type: ignore[misc]
    if init is object.__init__:
        return {}
    try:
        sig = inspect.signature(init, eval_str=True)
    except (NameError, TypeError, SyntaxError):  # an annotation that cannot be evaluated
        sig = inspect.signature(init)
    kinds = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    params = list(sig.parameters.values())[1:]  # without self
    return {p.name: p for p in params if p.kind in kinds}


def _is_reference(p: inspect.Parameter) -> bool:
    ann = p.annotation
    if ann is inspect.Parameter.empty:
        return p.name == "reference"
    options = typing.get_args(ann) if _is_union(ann) else (ann,)
    return any(isinstance(a, type) and issubclass(a, Reference) for a in options)


def _is_union(ann: Any) -> bool:
    return typing.get_origin(ann) in (typing.Union, types.UnionType)


def _toml_value(v: Any) -> bool:
    if isinstance(v, _SCALARS):
        return True
    return isinstance(v, list | tuple) and all(isinstance(x, _SCALARS) for x in v)


def _describe(ann: Any) -> str:
    """``ann`` in words, for messages."""
    origin, args = typing.get_origin(ann), typing.get_args(ann)
    if ann is inspect.Parameter.empty or ann is Any or isinstance(ann, str):
        return "any value"
    if ann is float:
        return "a number"
    if ann is int:
        return "an integer"
    if ann is bool:
        return "true or false"
    if ann is str:
        return "a string"
    if ann is np.ndarray:
        return "an array of numbers"
    if origin is typing.Literal:
        return f"one of {list(args)}"
    if _is_union(ann):
        return " or ".join(_describe(a) for a in args if a is not type(None))
    if origin is tuple and args and args[-1] is not Ellipsis:
        if len(set(args)) == 1:
            return f"an array of {len(args)} {_plural(args[0])}"
        return f"an array of {len(args)} ({', '.join(_describe(a) for a in args)})"
    if origin in (list, tuple, Sequence) or ann in (list, tuple):
        return f"an array of {_plural(args[0])}" if args else "an array"
    if origin in (dict, Mapping) or ann is dict:
        return "a table"
    return getattr(ann, "__name__", str(ann))


def _plural(ann: Any) -> str:
    words = {float: "numbers", int: "integers", str: "strings", bool: "booleans"}
    return words.get(ann, f"({_describe(ann)})")


def _checked(value: Any, ann: Any, key: str) -> Any:
    """``value`` converted to ``ann``, or a ``ConfigError`` naming ``key``."""
    try:
        return _convert(value, ann, key)
    except _MismatchError:
        raise ConfigError(f"{key}: expected {_describe(ann)}, got {value!r}") from None


class _MismatchError(ConfigError):
    """A value that does not fit an annotation (turned into one ``ConfigError``)."""


def _convert(value: Any, ann: Any, key: str) -> Any:
    origin, args = typing.get_origin(ann), typing.get_args(ann)
    if ann is inspect.Parameter.empty or ann is Any or isinstance(ann, str):
        return value
    if _is_union(ann):
        for option in args:
            try:
                return _convert(value, option, key)
            except ConfigError:
                continue
        raise _MismatchError
    if ann in (float, int, bool, str):
        return _scalar(value, ann, key)
    if origin is typing.Literal:
        if value in args and type(value) in {type(a) for a in args}:
            return value
        raise _MismatchError
    if ann is np.ndarray:
        return _array(value, key)
    if origin in (list, tuple, Sequence) or ann in (list, tuple):
        return _sequence(value, origin or ann, args, key)
    if origin in (dict, Mapping) or ann is dict:
        if not isinstance(value, dict):
            raise _MismatchError
        inner = args[1] if len(args) == 2 else Any
        return {k: _convert(v, inner, f"{key}.{k}") for k, v in value.items()}
    if isinstance(ann, type) and isinstance(value, ann):
        return value
    raise _MismatchError


def _scalar(value: Any, ann: type, key: str) -> Any:
    if ann is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise _MismatchError
        return to_float(value, key)  # a non-finite number: its own message
    if ann is int and (isinstance(value, bool) or not isinstance(value, int)):
        raise _MismatchError
    if not isinstance(value, ann):
        raise _MismatchError
    return value


def _array(value: Any, key: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise _MismatchError from None
    if not isinstance(value, list) or a.dtype == object or not np.all(np.isfinite(a)):
        raise _MismatchError
    return a


def _sequence(value: Any, origin: Any, args: tuple[Any, ...], key: str) -> Any:
    if not isinstance(value, list):
        raise _MismatchError
    if origin is tuple and args and args[-1] is not Ellipsis:
        if len(value) != len(args):
            raise _MismatchError
        return tuple(
            _convert(v, a, f"{key}[{i}]") for i, (v, a) in enumerate(zip(value, args, strict=True))
        )
    inner = args[0] if args else Any
    items = [_convert(v, inner, f"{key}[{i}]") for i, v in enumerate(value)]
    return tuple(items) if origin is tuple else items
