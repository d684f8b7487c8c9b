"""Where scenarios come from: built-in names or TOML files, ``extends``, variants, ``--set``.

A scenario file may start from another (``extends = "flight"`` or ``"other.toml"``,
relative to it) and override it key by key (a table whose ``kind`` changes is replaced
whole); relative file names of the parent stay anchored where the parent names them.
``expand_variants`` applies ``--set KEY=VALUE`` overrides and splits a scenario into its
``[variants.NAME]``.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

from aeromanip.config import (
    apply_override,
    builtin_descriptions,
    load_toml,
    parse_override,
    resolve_toml,
)
from aeromanip.errors import ConfigError

FREE_FORM = ("controller.solver_options",)  # tables whose keys the backend, not we, knows


def builtin_scenarios() -> dict[str, str]:
    """Built-in scenario names mapped to their one-line description."""
    return builtin_descriptions("aeromanip.scenarios")


def scenario_source(
    name_or_path: str | Path, _seen: tuple[Path, ...] = ()
) -> tuple[dict[str, Any], Path]:
    """The raw TOML table of a built-in scenario name or a file, and its directory.

    A scenario may start from another: ``extends = "flight"`` (a built-in name or a file,
    relative to this one) takes that scenario's table and overrides it key by key.
    """
    path = resolve_toml(name_or_path, "aeromanip.scenarios", "scenario")
    data = load_toml(path)
    base = data.pop("extends", None)
    if base is None:
        return data, path.parent
    if not isinstance(base, str):
        raise ConfigError(f"{path}: extends: expected a scenario name or file, got {base!r}")
    if path in _seen:
        raise ConfigError(f"{path}: extends: a cycle ({' -> '.join(map(str, _seen))})")
    target = path.parent / base if base.endswith(".toml") else base
    try:
        parent, parent_dir = scenario_source(target, (*_seen, path))
    except ConfigError as e:
        if str(e).startswith(f"{path}:"):  # already names this file (a cycle)
            raise
        raise ConfigError(f"{path}: extends: {e}") from None
    parent.pop("variants", None)  # variants are a scenario's own
    _anchor_paths(parent, parent_dir)  # its files stay where it names them
    return _merge(parent, data), path.parent


def _anchor_paths(data: dict[str, Any], base_dir: Path) -> None:
    """Make the relative file names of a scenario table absolute against ``base_dir``:
    ``robot`` (a TOML file), ``robot.arm.urdf`` and ``reference.file``."""

    def anchor(table: Any, key: str, suffixes: tuple[str, ...] = ()) -> None:
        v = table.get(key) if isinstance(table, dict) else None
        if isinstance(v, str) and (not suffixes or v.endswith(suffixes)):
            p = Path(v)
            if not p.is_absolute():
                table[key] = str(base_dir / p)

    anchor(data, "robot", (".toml",))
    robot = data.get("robot")
    if isinstance(robot, dict):
        anchor(robot.get("arm"), "urdf")
    anchor(data.get("reference"), "file")


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """``base`` overridden key by key by ``over``; a table whose ``kind`` changes (a
    reference, a task) is replaced whole: the old kind's keys mean nothing to the new."""
    out = copy.deepcopy(base)
    for k, v in over.items():
        old = out.get(k)
        if (
            isinstance(v, dict)
            and isinstance(old, dict)
            and v.get("kind", old.get("kind")) == old.get("kind")
        ):
            out[k] = _merge(old, v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def expand_variants(
    data: dict[str, Any], overrides: list[str] = (), only: str | None = None
) -> dict[str, dict[str, Any]]:
    """Apply ``--set`` overrides, then split into variants: {variant name or "": data};
    an override also wins over a variant's value for the same key."""
    data = copy.deepcopy(data)
    controller = data.get("controller")
    if isinstance(controller, dict):  # free-form: --set controller.solver_options.KEY=...
        controller.setdefault("solver_options", {})
    for text in overrides:
        path, value = parse_override(text)
        apply_override(data, path, value, f"--set {text}", FREE_FORM)
    variants = data.pop("variants", {})
    if not isinstance(variants, dict):
        raise ConfigError("variants: must be a table of named variants")
    if not variants:
        if only:
            raise ConfigError(f"--variant {only}: the scenario has no variants")
        return {"": data}
    if only is not None:
        if only not in variants:
            raise ConfigError(f"--variant {only}: unknown variant (have: {', '.join(variants)})")
        variants = {only: variants[only]}
    out = {}
    for name, over in variants.items():
        if not isinstance(over, dict):
            raise ConfigError(f"variants.{name}: must be a table of overrides")
        out[name] = _merge(data, over)
        for text in overrides:  # --set wins over the variant's own values too
            path, value = parse_override(text)
            if path[0] != "variants":
                apply_override(out[name], path, value, f"--set {text}", FREE_FORM)
    return out
