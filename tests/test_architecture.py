"""The package's layers: who may import whom (docs/architecture.md), and no import cycle.

Every ``import aeromanip...`` in the source, at module level or inside a function, is
read with ``ast`` (nothing is imported), so a cycle hidden by a function-level import
is found too.
"""

import ast
import functools
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "aeromanip"
BASE = {"errors", "config", "registry", "interrupts"}
# each top-level part of the package and the parts it may import (besides itself)
ALLOWED: dict[str, set[str]] = {
    "errors": set(),
    "config": {"errors"},
    "registry": {"errors"},
    "interrupts": set(),
    "references": BASE,
    "robot": BASE,
    "tasks": BASE | {"references", "robot"},
    "nmpc": BASE | {"references", "robot", "tasks"},
    "sim": BASE | {"robot"},
    "experiment": BASE | {"references", "robot", "tasks", "nmpc", "sim"},
    # replays and MCAP logs of saved runs; only bench (render speed) and the CLI import it
    "viz": BASE | {"robot", "experiment"},
    "bench": BASE | {"references", "robot", "tasks", "nmpc", "sim", "experiment", "viz"},
    "sweep": BASE | {"experiment"},  # campaigns on Ray; only the command line imports it
    # the real-time loop (wall clock, transports' interface): beside bench, above experiment
    "runtime": BASE | {"references", "robot", "tasks", "nmpc", "sim", "experiment"},
    # MAVLink: the runtime's transport and the SITL autopilot; only the command line imports it
    "mavlink": BASE | {"references", "robot", "tasks", "nmpc", "sim", "experiment", "runtime"},
    "robots": set(),  # built-in TOML files
    "scenarios": set(),
}
TOP = {"__init__", "__main__", "cli"}  # the public API and the command line: anything


def module_name(path: Path) -> str:
    """``src/aeromanip/nmpc/backends/sqp/solver.py`` -> ``aeromanip.nmpc.backends.sqp.solver``."""
    parts = path.relative_to(SRC.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path) -> set[str]:
    """The aeromanip modules ``path`` imports (wherever the import statement is); ``from
    package import name`` counts as importing ``package.name`` too (it may be a module)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith("aeromanip")}
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("aeromanip"):
            out |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
    return out


@functools.cache
def graph() -> dict[str, set[str]]:
    """Module -> the aeromanip modules it imports (packages resolved to their modules)."""
    files = {module_name(p): p for p in SRC.rglob("*.py")}
    return {m: {i for i in imports_of(p) if i in files} - {m} for m, p in files.items()}


def part(module: str) -> str:
    """The top-level part of the package a module belongs to."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def test_every_part_is_known():
    parts = {part(m) for m in graph()}
    assert parts <= set(ALLOWED) | TOP, parts - set(ALLOWED) - TOP


@pytest.mark.parametrize("module", sorted(graph()))
def test_imports_go_down_the_layers(module):
    src = part(module)
    if src in TOP:
        return
    bad = sorted(i for i in graph()[module] if part(i) not in ALLOWED[src] | {src})
    assert not bad, f"{module} ({src}) may not import {bad}: allowed {sorted(ALLOWED[src])}"


def test_no_import_cycle():
    """Depth-first search over the module graph; a back edge is a cycle."""
    g = graph()
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for n in sorted(g[m]):
            assert state.get(n) != 1, "import cycle: " + " -> ".join([*path, m, n])
            if n not in state:
                visit(n, [*path, m])
        state[m] = 2

    for m in sorted(g):
        if m not in state:
            visit(m, [])


def test_the_checker_sees_function_level_imports(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("def f():\n    from aeromanip.nmpc import problem\n    import aeromanip.sim\n")
    assert imports_of(f) == {"aeromanip.nmpc", "aeromanip.nmpc.problem", "aeromanip.sim"}
