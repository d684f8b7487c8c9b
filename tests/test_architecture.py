"""The package's layers: who may import whom (docs/architecture.md), and no import cycle.

Every ``import aeromanip...`` in the source, at module level or inside a function, is
read with ``ast`` (nothing is imported), so a cycle hidden by a function-level import
is found too.
"""

import ast
import functools
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "aeromanip"
DOC = ROOT / "docs" / "architecture.md"
BASE = {"errors", "config", "registry", "interrupts", "realtime"}
# each top-level part of the package and the parts it may import (besides itself)
ALLOWED: dict[str, set[str]] = {
    "errors": set(),
    "config": {"errors"},
    "registry": {"errors"},
    "interrupts": set(),
    "realtime": set(),
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
    # a controller as a C library: only the command line imports it
    "export": BASE | {"references", "robot", "tasks", "nmpc", "experiment"},
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


def documented_layers(table: str) -> dict[str, set[str] | None]:
    """The "part | may import" table of docs/architecture.md: part -> the parts it may
    import (``None``: anything). A part's own description, in parentheses, is skipped;
    "the base" stands for ``BASE``."""
    rows = re.findall(r"^\| (.+?) \| (.+?) \|$", table, flags=re.M)
    out: dict[str, set[str] | None] = {}
    for parts, allowed in rows[1:]:  # the first row is the header
        names = re.findall(r"`([\w_]+)`", re.sub(r"\(.*\)", "", parts))
        if allowed == "anything":
            may = None
        elif allowed == "nothing":
            may = set()
        else:
            may = set(re.findall(r"`(\w+)`", allowed)) | (BASE if "the base" in allowed else set())
        out |= dict.fromkeys(names, may)
    return out


def test_the_documented_layers_are_the_checked_ones():
    text = DOC.read_text()
    table = text[text.index("| part | may import |") :].split("\n\n", 1)[0]
    doc = documented_layers(table)
    assert {p for p, may in doc.items() if may is None} == TOP
    assert {p: may for p, may in doc.items() if may is not None} == ALLOWED


def test_the_checker_sees_function_level_imports(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("def f():\n    from aeromanip.nmpc import problem\n    import aeromanip.sim\n")
    assert imports_of(f) == {"aeromanip.nmpc", "aeromanip.nmpc.problem", "aeromanip.sim"}
