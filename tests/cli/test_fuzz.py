"""Fuzzing the command line with malformed input (hypothesis, reproducible).

The rule under test: bad input gets ONE clear line on stderr (``aeromanip: error: <key>:
...``) and exit code 2, never a traceback and never a hang, and nothing of a previous run
is lost. Generated here:

* ``run SCENARIO --check --set KEY=VALUE``: real keys of the built-in scenarios (and
  typos, unknown and malformed keys) set to wrong or extreme TOML values;
* scenario files: a built-in scenario's table with 1-3 mutations (a key deleted, a value
  replaced, an unknown key added, ``extends`` broken), and files that are not TOML;
* robot files: ``robots/x8-3dof.toml`` with physically or structurally wrong entries,
  flown by a scenario that names it;
* ``plot DIR`` on run directories with malformed ``log.csv`` / ``meta.json``: every file
  that was in ``DIR`` (other than ``figures/``) is unchanged afterwards;
* a few scenarios still valid after plausible mutations, flown for one control period.

Every call runs in-process under a watchdog (``SIGALRM``): a call that hangs fails the
test instead of hanging it. Settings are derandomized (the same examples on every run)
and hypothesis writes no example database. Inputs once found to break the rule are pinned
with ``@example`` so that they are always tried.
"""

from __future__ import annotations

import copy
import csv
import datetime as dt
import io
import json
import math
import os
import re
import tempfile
import time
import tomllib
import warnings
from collections.abc import Callable, Iterator
from importlib import resources
from pathlib import Path
from typing import Any

import pytest
import tomli_w
from hypothesis import assume, configuration, example, given, settings
from hypothesis import strategies as st

from aeromanip.cli import main
from aeromanip.experiment.runlog import contract_columns
from aeromanip.robot.spec import reserved_names
from fuzzing import FUZZ, CallTimedOut, watchdog

SCENARIOS = ("planar", "waypoints", "flight", "flight-cog", "waypoints-unbounded")
CHECK_LIMIT_S = 10.0  # [s] one `run --check` (normally ~30 ms)
PLOT_LIMIT_S = 30.0  # [s] one `plot DIR` (normally < 2 s)
RUN_LIMIT_S = 120.0  # [s] one real run of one control period (normally < 5 s)

# the limits above bound each call (the watchdog; hypothesis' settings: fuzzing.FUZZ)

# characters for generated text: printable ASCII, control characters, a newline, a BOM,
# a line separator and non-ASCII letters (an explicit alphabet: no unicode tables needed)
ALPHABET = (
    "abcdefghijklmnopqrstuvwxyzABCXYZ0123456789 _-.,:;=+*/\\'\"[]{}()#$%&<>?!@^|~`\t\n"
    "\x00\x01\x1b\x7f\u00e9\u00df\u4e2d\u2028\ufeff"
)
NAN, INF = math.nan, math.inf


@pytest.fixture(autouse=True, scope="module")
def _hypothesis_files_in_tmp(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Hypothesis caches what it learns of the code under test in ``.hypothesis/`` of the
    working directory, whatever the settings: while these tests run it goes to a
    temporary directory (its pytest plugin still writes there when it collects)."""
    previous = configuration.storage_directory(intent_to_write=False).home_directory
    configuration.set_hypothesis_home_dir(tmp_path_factory.mktemp("hypothesis"))
    yield
    configuration.set_hypothesis_home_dir(previous)


def _builtin(package: str, name: str) -> dict[str, Any]:
    return tomllib.loads((resources.files("aeromanip") / package / f"{name}.toml").read_text())


BUILTIN_SCENARIOS = {name: _builtin("scenarios", name) for name in SCENARIOS}
X8 = _builtin("robots", "x8-3dof")


def _key_paths(table: dict[str, Any], prefix: str = "") -> Iterator[str]:
    """Every dotted key path of a TOML table, tables included (``controller``,
    ``controller.dt``, ``tasks.cog.weight``...)."""
    for key, value in table.items():
        path = f"{prefix}{key}"
        yield path
        if isinstance(value, dict):
            yield from _key_paths(value, f"{path}.")


SCENARIO_KEYS = sorted(
    {k for data in BUILTIN_SCENARIOS.values() for k in _key_paths(data)}
    | {  # optional keys the built-ins leave out, free-form solver options
        "robot",
        "max_failure_ratio",
        "controller.time_budget",
        "clearance.points",
        "clearance.margin",
        "reference.file",
        "tasks.tracking.kind",
        "tasks.tracking.tracked",
        "physics.gains",
        "physics.servo_hz",
        "controller.solver_options.max_iter",
        "controller.solver_options.qpsol_options",
        "controller.solver_options.ipopt.max_iter",
    }
)

# TOML value text for `--set KEY=VALUE`: wrong types, extremes, names that resolve to
# something else, and text that is not TOML (read as a string by `parse_override`)
EVIL_LITERALS = (
    *('""', '"x"', "true", "false", "0", "-1", "1", "0.0", "-0.0", "0x7fffffff", "1_000"),
    *("1e308", "-1e308", "1e-300", "5e-324", "nan", "-nan", "inf", "-inf"),
    *("9223372036854775807", "-9223372036854775808"),
    *("[]", "{}", "[1]", "[1, 2]", "[1, 2, 3]", "[0, 0, 0]", "[1, 2, 3, 4, 5, 6, 7, 8]"),
    *("[[]]", "[{}]", "[nan, nan]", "[inf, -inf]", "[1e308, -1e308]", '[1, "a"]'),
    *("{ a = 1 }", "{ default = -1 }", "{ default = nan }", "{ x = [1, 2] }"),
    *('"nosuch"', '"package.module:Class"', '"os:path"', '"aeromanip:nosuch"'),
    *('".relative:Class"', '"x8-3dof"', '"planar-2dof"', '"nosuch.toml"'),
    *('"/"', '"."', '".."', '"a/b"', "1979-05-27T07:32:00Z", "1979-05-27", "07:32:00"),
    *('"kinematic"', '"physics"', '"ipopt"', '"sqp"', '"sqp-rti"', '"fatrop"'),
    *('"weighted"', '"hierarchical"', '"stagewise"'),
    *("", "=", "[", "{", '"', "1e", "a\nb"),
)


def _toml_float(x: float) -> str:
    """A float as TOML text (``nan``, ``inf``, ``-inf`` included)."""
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return repr(x)


def toml_literals() -> st.SearchStrategy[str]:
    """TOML value text: curated evil literals, any float, huge integers, quoted and raw
    strings, nested arrays and inline tables of those."""
    scalars = st.one_of(
        st.sampled_from(EVIL_LITERALS),
        st.floats().map(_toml_float),
        st.integers(-(2**70), 2**70).map(str),
        st.text(ALPHABET, max_size=12).map(lambda s: json.dumps(s, ensure_ascii=False)),
        st.text(ALPHABET, max_size=12),
    )
    names = st.sampled_from(("a", "x", "q1", "default", "kind", "weight", "mode", "z"))

    def nest(inner: st.SearchStrategy[str]) -> st.SearchStrategy[str]:
        arrays = st.lists(inner, max_size=8).map(lambda xs: f"[{', '.join(xs)}]")
        tables = st.dictionaries(names, inner, max_size=4).map(
            lambda d: "{ " + ", ".join(f"{k} = {v}" for k, v in d.items()) + " }"
        )
        return arrays | tables

    return st.recursive(scalars, nest, max_leaves=10)


def override_keys() -> st.SearchStrategy[str]:
    """Dotted keys for ``--set``: real ones (mostly), typos of real ones, unknown and
    malformed ones (empty parts, spaces, a newline)."""

    @st.composite
    def typo(draw: st.DrawFn) -> str:
        key = draw(st.sampled_from(SCENARIO_KEYS))
        i = draw(st.integers(0, len(key)))
        junk = draw(st.sampled_from(("", "x", ".", "..", "_", " ", "\n", "s", "0")))
        return key[:i] + junk + key[i + 1 :]

    odd = st.sampled_from(
        (
            "nosuch",
            "nosuch.key",
            "controller.nosuch",
            "tasks.nosuch.weight",
            "variants.nosuch.duration",
            "variants",
            "extends",
            ".",
            "a..b",
            ".duration",
            "duration.",
            " ",
            "",
        )
    )
    return st.one_of(st.sampled_from(SCENARIO_KEYS), typo(), odd)


# ----------------------------------------------------------------------- the rule


# warnings a user of the command line does not see (Python's default filters)
HIDDEN_WARNINGS = (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning)


def call(
    argv: list[str], capsys: pytest.CaptureFixture[str], limit_s: float, what: str
) -> tuple[int, str, str, list[str]]:
    """``main(argv)`` in-process: (exit code, stdout, stderr, warnings a user would see).

    An exception escaping ``main`` or a call over ``limit_s`` fails the test, naming the
    input (``what``: the argv and any generated file)."""
    capsys.readouterr()
    t0 = time.monotonic()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            with watchdog(limit_s):
                rc = main(argv)
        except CallTimedOut as e:
            raise AssertionError(f"hang: {e}\n{what}") from None
        except KeyboardInterrupt:  # Ctrl-C on the tests themselves (main catches its own)
            raise
        except BaseException as e:
            raise AssertionError(f"{type(e).__name__} escaped main: {e}\n{what}") from e
    elapsed = time.monotonic() - t0
    out, err = capsys.readouterr()
    assert elapsed < limit_s, f"took {elapsed:.1f} s (limit {limit_s:g} s)\n{what}"
    shown = [
        f"{w.filename}:{w.lineno}: {w.category.__name__}: {w.message}"
        for w in caught
        if not issubclass(w.category, HIDDEN_WARNINGS)
    ]
    return rc, out, err, shown


def assert_rule(rc: int, err: str, shown: list[str], what: str, quiet_ok: bool = True) -> None:
    """Exit 0 or 2; on 2 exactly one ``aeromanip: error: <key>: ...`` line on stderr.

    ``quiet_ok``: an accepted input (0) prints nothing on stderr, warnings included (a
    warning there means a value overflowed to inf/nan while it was being checked)."""
    assert rc in (0, 2), f"exit code {rc}, stderr {err!r}\n{what}"
    if rc == 0:
        if quiet_ok:
            assert not err.strip(), f"accepted, but stderr says {err!r}\n{what}"
            assert not shown, f"accepted, with warnings {shown}\n{what}"
        return
    # lines as a terminal shows them (not str.splitlines: U+2028 breaks no line there)
    lines = re.split(r"\r\n|\r|\n", err.strip()) + shown  # a warning: one more line
    assert "Traceback" not in err, f"traceback on stderr\n{err}\n{what}"
    assert len(lines) == 1, f"{len(lines)} stderr lines, not one: {lines!r}\n{what}"
    prefix = "aeromanip: error: "
    assert lines[0].startswith(prefix), f"not an aeromanip error line: {lines[0]!r}\n{what}"
    head, sep, _ = lines[0][len(prefix) :].partition(": ")
    # "<key>: ...": a key path, a file, an option ("--set 'x=1'"); spaces only where the
    # input has them (a key "b unds" from `--set "b unds=1"`), not "bounds margin: ..."
    parts = [p for p in head.split(".") if len(p.split()) > 1]
    names_key = head.startswith("--") or all(p in what for p in parts)
    assert sep and head.strip() and names_key, f"names no key: {lines[0]!r}\n{what}"


def checked(argv: list[str], what: str, capsys: Any, out: Path) -> int:
    """``main(argv)`` for a ``run ... --check`` under the rule; ``--out`` (``out``) is
    checked, never created. The exit code."""
    rc, stdout, err, shown = call(argv, capsys, CHECK_LIMIT_S, what)
    assert_rule(rc, err, shown, what)
    if rc == 0:
        assert ": ok" in stdout, f"--check accepted without saying ok: {stdout!r}\n{what}"
    assert not out.exists(), f"--check created --out\n{what}"
    return rc


def fresh_dir(tmp_path: Path) -> Path:
    """A new empty directory of its own for one example."""
    return Path(tempfile.mkdtemp(dir=tmp_path))


def _describe(argv: list[str], files: dict[Path, bytes | str] | None = None) -> str:
    lines = [f"argv: {argv!r}"]
    for path, content in (files or {}).items():
        lines.append(f"--- {path.name} ---\n{content!r}")
    return "\n".join(lines)


# ----------------------------------------------------------------- 1. --set KEY=VALUE


@settings(FUZZ, max_examples=400)
@given(scenario=st.sampled_from(SCENARIOS), key=override_keys(), value=toml_literals())
@example(scenario="waypoints", key="controller.backend", value='".relative:Class"')
@example(scenario="waypoints", key="duration", value="[" * 1000)
@example(scenario="waypoints", key="nosuch.a\nb", value="1")
@example(scenario="waypoints", key="controller.a\nb", value="1")
@example(scenario="flight", key="bounds.joint_margin", value="2")
@example(
    scenario="planar",
    key="reference.phases",
    value="[{ duration = 30.0, amplitude = 0.08, frequency = 1e308 }]",
)
def test_set_overrides_are_checked_in_one_line(scenario, key, value, tmp_path, capsys):
    argv = ["run", scenario, "--check", "--out", str(tmp_path / "out"), "--set", f"{key}={value}"]
    checked(argv, _describe(argv), capsys, tmp_path / "out")


# ------------------------------------------------------------ 2. malformed scenario files

EVIL_VALUES: tuple[Any, ...] = (
    *("", "x", "nosuch", "a:b", ".relative:Class", "x8-3dof", "s.toml", "/", "a\nb"),
    *(True, False, 0, -1, 1, 2**63 - 1, -(2**63), 2**80),
    *(0.0, -0.0, 1e308, -1e308, 1e-300, NAN, INF, -INF),
    *([], {}, [1], [1, 2], [0.0, 0.0, 0.0], [2.0, 1.0], [1, 2, 3, 4, 5, 6, 7], [[1, 2, 3]]),
    *([NAN, 1.0], [{}], [{"duration": -1}], {"a": 1}, {"kind": "constant"}, {"kind": "csv"}),
    *({"default": -1.0}, {"q1": NAN}),
    *(dt.datetime(1979, 5, 27, 7, 32, tzinfo=dt.UTC), dt.date(1979, 5, 27), dt.time(7, 32)),
)


def toml_values() -> st.SearchStrategy[Any]:
    """Python values ``tomli_w`` can write: curated wrong ones, any scalar, and arrays and
    tables of them."""
    scalars = st.one_of(
        st.sampled_from(EVIL_VALUES),
        st.booleans(),
        st.integers(-(2**70), 2**70),
        st.floats(),
        st.text(ALPHABET, max_size=10),
    )
    names = st.sampled_from(("a", "x", "q1", "kind", "weight", "default", "duration", ""))

    def nest(inner: st.SearchStrategy[Any]) -> st.SearchStrategy[Any]:
        return st.lists(inner, max_size=6) | st.dictionaries(names, inner, max_size=4)

    # copies: a later mutation must not change EVIL_VALUES (or put a table into itself)
    return st.recursive(scalars, nest, max_leaves=8).map(copy.deepcopy)


def _paths(node: Any, prefix: tuple = ()) -> Iterator[tuple]:
    """Every path (keys and array indices) into a TOML value, the root excluded."""
    items = node.items() if isinstance(node, dict) else enumerate(node)
    for k, v in items:
        yield (*prefix, k)
        if isinstance(v, dict | list):
            yield from _paths(v, (*prefix, k))


def _parent(data: Any, path: tuple) -> Any:
    for k in path[:-1]:
        data = data[k]
    return data


def _tables(node: Any, prefix: tuple = ()) -> Iterator[tuple]:
    """Paths of every table (dict) in a TOML value, the root included."""
    if isinstance(node, dict):
        yield prefix
        children = node.items()
    elif isinstance(node, list):
        children = enumerate(node)
    else:
        return
    for k, v in children:
        yield from _tables(v, (*prefix, k))


def _at(data: Any, path: tuple) -> Any:
    for k in path:
        data = data[k]
    return data


@st.composite
def mutated_tables(draw: st.DrawFn, base: dict[str, Any]) -> dict[str, Any]:
    """``base`` after 1-3 mutations: a key or entry deleted, a value replaced by a wrong
    one (``toml_values``), an unknown or misplaced key added to some table."""
    data = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(("delete", "replace", "replace", "add")))
        paths = list(_paths(data))
        if op == "add" or not paths:
            table = _at(data, draw(st.sampled_from(list(_tables(data)))))
            key = draw(st.sampled_from(("zzz", "duraton", "kind", "weight", "dt", "name")))
            table[key] = draw(toml_values())
            continue
        path = draw(st.sampled_from(paths))
        parent = _parent(data, path)
        if op == "delete":
            del parent[path[-1]]
        else:
            parent[path[-1]] = draw(toml_values())
    return data


@st.composite
def scenario_files(draw: st.DrawFn) -> tuple[str, dict[str, Any], dict[str, str]]:
    """(built-in name, mutated table, other files beside it): the mutations of
    ``mutated_tables``, sometimes with ``extends`` broken (a missing file, the file
    itself, a cycle through a second file, a non-string, an unknown name)."""
    name = draw(st.sampled_from(SCENARIOS))
    data = draw(mutated_tables(BUILTIN_SCENARIOS[name]))
    others: dict[str, str] = {}
    broken = draw(
        st.sampled_from((None, None, "missing", "self", "cycle", "number", "unknown", "empty"))
    )
    if broken == "missing":
        data["extends"] = "missing.toml"
    elif broken == "self":
        data["extends"] = "s.toml"
    elif broken == "cycle":
        data["extends"] = "b.toml"
        others["b.toml"] = 'extends = "s.toml"\nname = "b"\n'
    elif broken == "number":
        data["extends"] = draw(st.sampled_from((1, 1.5, True, ["flight"], {"a": 1})))
    elif broken == "unknown":
        data["extends"] = "nosuch"
    elif broken == "empty":
        data["extends"] = ""
    return name, data, others


def _write(directory: Path, files: dict[str, bytes | str]) -> dict[Path, bytes | str]:
    out = {}
    for name, content in files.items():
        path = directory / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content)
        out[path] = content
    return out


def check_file(path: Path, files: dict, tmp: Path, capsys: Any) -> int:
    """``run PATH --check`` under the rule; the exit code."""
    argv = ["run", str(path), "--check", "--out", str(tmp / "out")]
    what = _describe(argv, files)
    return checked(argv, what, capsys, tmp / "out")


@settings(FUZZ, max_examples=250)
@given(case=scenario_files())
@example(case=("waypoints", {**BUILTIN_SCENARIOS["waypoints"], "a\nb": 1}, {}))
def test_mutated_scenario_files_are_checked_in_one_line(case, tmp_path, capsys):
    _, data, others = case
    d = fresh_dir(tmp_path)
    files = _write(d, {"s.toml": tomli_w.dumps(data), **others})
    check_file(d / "s.toml", files, d, capsys)


def corrupted_toml() -> st.SearchStrategy[bytes]:
    """Bytes that are not a valid scenario: random bytes, random text, a built-in file
    cut short or with junk spliced in, deep nesting, invalid UTF-8."""
    texts = [
        (resources.files("aeromanip") / "scenarios" / f"{n}.toml").read_bytes() for n in SCENARIOS
    ]

    @st.composite
    def spliced(draw: st.DrawFn) -> bytes:
        text = draw(st.sampled_from(texts))
        i = draw(st.integers(0, len(text)))
        j = draw(st.integers(i, min(len(text), i + 20)))
        junk = draw(st.binary(max_size=8) | st.sampled_from((b"[", b"=", b'"', b"\n[", b"\xff")))
        return text[:i] + junk + text[j:]

    return st.one_of(
        st.binary(max_size=300),
        st.text(ALPHABET, max_size=300).map(str.encode),
        spliced(),
        st.sampled_from((b"", b"\xef\xbb\xbf", b'name = "\xff"\n', b"a = " + b"[" * 1000)),
    )


@settings(FUZZ, max_examples=60)
@given(content=corrupted_toml())
@example(content=b'name = "\xff"\n')
@example(content=b"a = " + b"[" * 1000)
def test_garbage_scenario_files_are_one_line(content, tmp_path, capsys):
    d = fresh_dir(tmp_path)
    files = _write(d, {"s.toml": content})
    check_file(d / "s.toml", files, d, capsys)


# --------------------------------------------------------------- 3. malformed robot files

BAD_AXES = ([0, 0, 0], [1, 1, 0], [0, 0, 2], [1e-12, 0, 0], [NAN, 0, 0], [INF, 0, 0], [1, 0])
BAD_LIMITS = ([1.0, -1.0], [0.5, 0.5], [NAN, 1.0], [-INF, INF], [1.0], [], [1e308, -1e308])
BAD_MASSES = (-1.0, 0.0, -0.0, 1e3 + 1, 1e4 + 1, 1e308, NAN, INF, 1e-300, "1", True)
BAD_INERTIAS = (
    [-1e-5, 1e-5, 1e-5, 0, 0, 0],  # a negative moment
    [1.0, 1.0, 1.0, 5.0, 5.0, 5.0],  # not positive semi-definite
    [1.0, 1.0, 5.0, 0, 0, 0],  # breaks the triangle inequality
    [1e308] * 6,  # overflows while checked
    [1e200, 1e200, 1e200, 0, 0, 0],
    [0.0] * 6,
    [NAN, 1, 1, 0, 0, 0],
    [1, 1, 1],
    [1, 1, 1, 0, 0, 0, 0],
)
BAD_PLATFORM_INERTIAS = ([0, 0, 0], [-1, 1, 1], [1, 1, 5], [1e308] * 3, [NAN, 1, 1], [1, 1])
BAD_NAMES = ("", "world", "base_link", "arm_mount", *sorted(reserved_names("end_effector")), 7)


def _pick(draw: st.DrawFn, values: tuple) -> Any:
    """A copy of one of ``values`` (never the shared object: mutations change it)."""
    return copy.deepcopy(draw(st.sampled_from(values)))


def _joints(robot: dict) -> list[dict]:
    js = robot.get("joints")
    return [j for j in js if isinstance(j, dict)] if isinstance(js, list) else []


RobotMutation = Callable[[st.DrawFn, dict], None]


def _joint_axis(draw: st.DrawFn, robot: dict) -> None:
    """A joint axis zero, not a unit vector, non-finite or of the wrong length."""
    if js := _joints(robot):
        draw(st.sampled_from(js))["axis"] = _pick(draw, BAD_AXES)


def _joint_limits(draw: st.DrawFn, robot: dict) -> None:
    """Joint limits reversed, empty, NaN, infinite or of the wrong length."""
    if js := _joints(robot):
        draw(st.sampled_from(js))["limits"] = _pick(draw, BAD_LIMITS)


def _link_mass(draw: st.DrawFn, robot: dict) -> None:
    """A link mass negative, zero, too large, non-finite or not a number; or every link
    massless (an arm without mass)."""
    js = [j for j in _joints(robot) if isinstance(j.get("link"), dict)]
    if not js:
        return
    if draw(st.booleans()):
        draw(st.sampled_from(js))["link"]["mass"] = _pick(draw, BAD_MASSES)
    else:
        for j in js:
            j["link"]["mass"] = 0.0


def _link_inertia(draw: st.DrawFn, robot: dict) -> None:
    """A link inertia negative, indefinite, non-physical, huge or of the wrong length."""
    js = [j for j in _joints(robot) if isinstance(j.get("link"), dict)]
    if js:
        draw(st.sampled_from(js))["link"]["inertia"] = _pick(draw, BAD_INERTIAS)


def _platform(draw: st.DrawFn, robot: dict) -> None:
    """A wrong platform entry: mass, inertia, DoFs, rotors, fixed or velocity."""
    pf = robot.get("platform")
    if not isinstance(pf, dict):
        return
    key, values = draw(
        st.sampled_from(
            (
                ("mass", BAD_MASSES),
                ("inertia", BAD_PLATFORM_INERTIAS),
                ("dofs", ([], ["x", "x"], ["yaw", "x"], ["roll"], "xyz", [1], ["x", "y", "z", ""])),
                ("rotors", (3, 5, 0, -8, 4, 2**40, 8.0, True)),
                ("coaxial", ("yes", 1)),
                ("fixed", ({"x": 0.0}, {"roll": 0.0}, {"yaw": NAN}, [])),
                ("velocity", ({"x": 0.0}, {"x": -1.0}, {"roll": 1.0}, {"x": NAN}, {"x": INF})),
                ("arm_length", (0.0, -0.3, NAN)),
            )
        )
    )
    pf[key] = _pick(draw, values)


def _names(draw: st.DrawFn, robot: dict) -> None:
    """A joint or link named like another, empty, reserved by the URDF export, or not a
    string."""
    js = [j for j in _joints(robot) if isinstance(j.get("link"), dict)]
    if len(js) < 2:
        return
    a, b = draw(st.permutations(js))[:2]
    taken = [b.get("name"), b["link"].get("name"), a["link"].get("name")]
    new = draw(st.sampled_from([n for n in taken if n is not None] + list(BAD_NAMES)))
    if draw(st.booleans()):
        a["name"] = new
    else:
        a["link"]["name"] = new


def _structure(draw: st.DrawFn, robot: dict) -> None:
    """A table or list removed or reshaped: no platform / joints / link / name, an empty
    joint list, a joint duplicated or dropped, an [arm] table beside [[joints]]."""
    choice = draw(
        st.sampled_from(
            ("platform", "joints", "mount", "end_effector", "name", "link", "empty", "dup", "drop")
        )
    )
    js = _joints(robot)
    if choice in ("platform", "joints", "mount", "end_effector", "name"):
        robot.pop(choice, None)
    elif choice == "link" and js:
        draw(st.sampled_from(js)).pop("link", None)
    elif choice == "empty":
        robot["joints"] = []
    elif choice == "dup" and js:
        robot["joints"] = [*robot["joints"], copy.deepcopy(draw(st.sampled_from(js)))]
    elif choice == "drop" and js:
        robot["joints"] = robot["joints"][:-1]
    else:
        robot["arm"] = {"urdf": "missing.urdf"}


def _generic(draw: st.DrawFn, robot: dict) -> None:
    """Any entry deleted or replaced by a generated wrong value."""
    paths = list(_paths(robot))
    if not paths:
        return
    path = draw(st.sampled_from(paths))
    parent = _parent(robot, path)
    if draw(st.booleans()):
        del parent[path[-1]]
    else:
        parent[path[-1]] = draw(toml_values())


ROBOT_MUTATIONS: tuple[RobotMutation, ...] = (
    _joint_axis,
    _joint_limits,
    _link_mass,
    _link_inertia,
    _platform,
    _names,
    _structure,
    _generic,
)


def _x8_with(path: tuple, value: Any) -> dict[str, Any]:
    """x8-3dof with one entry replaced (for explicit examples)."""
    robot = copy.deepcopy(X8)
    _parent(robot, path)[path[-1]] = value
    return robot


@st.composite
def robot_files(draw: st.DrawFn) -> tuple[dict[str, Any], str]:
    """(mutated x8-3dof table, how the scenario names it): 1-3 mutations of
    ``ROBOT_MUTATIONS``; named by a scenario file (``extends = "waypoints"``,
    ``robot = "robot.toml"``) or by ``--set robot="/abs/robot.toml"`` on ``flight``."""
    robot = copy.deepcopy(X8)
    for _ in range(draw(st.integers(1, 3))):
        draw(st.sampled_from(ROBOT_MUTATIONS))(draw, robot)
    return robot, draw(st.sampled_from(("extends", "--set")))


@settings(FUZZ, max_examples=200)
@given(case=robot_files())
@example(case=(_x8_with(("joints", 0, "link", "inertia"), [1e308] * 6), "extends"))
@example(case=(_x8_with(("platform", "inertia"), [1e308] * 3), "extends"))
@example(case=(_x8_with(("joints", 0, "limits"), [0.5, 0.5]), "--set"))
def test_malformed_robot_files_are_checked_in_one_line(case, tmp_path, capsys):
    robot, via = case
    d = fresh_dir(tmp_path)
    files = {"robot.toml": tomli_w.dumps(robot)}
    if via == "extends":
        files["s.toml"] = 'extends = "waypoints"\nrobot = "robot.toml"\n'
        written = _write(d, files)
        check_file(d / "s.toml", written, d, capsys)
    else:
        written = _write(d, files)
        robot_path = json.dumps(str(d / "robot.toml"))
        argv = ["run", "flight", "--check", "--out", str(d / "out"), "--set", f"robot={robot_path}"]
        checked(argv, _describe(argv, written), capsys, d / "out")


def test_special_files_do_not_hang(tmp_path, capsys):
    """A FIFO named as the scenario or as its robot: an error, not a wait for a writer
    (the watchdog ends the wait; opening it for writing would too)."""
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    scenario = tmp_path / "s.toml"
    scenario.write_text('extends = "waypoints"\nrobot = "fifo.toml"\n')
    for path in (fifo, scenario):
        argv = ["run", str(path), "--check", "--out", str(tmp_path / "out")]
        checked(argv, _describe(argv), capsys, tmp_path / "out")


# ------------------------------------------------------- 4. malformed run directories

EXTRA_COLUMNS = (
    *("roll", "pitch", "arm_torque", "motor_1", "motor_2", "clear_ee", "clear_q2"),
    *("iterations", "level0_loss", "level0_cost", "message", "rotor_spread"),
)
LOG_COLUMNS = (*contract_columns(3), *EXTRA_COLUMNS)
CELLS = ("x", "1e308", "-1e308", "", "nan", "inf", "-inf", "ok", "failed", "$\\foo$", "1,2")


def csv_cells() -> st.SearchStrategy[str]:
    """One ``log.csv`` cell: text, extremes (1e308, NaN, inf), empty, math text, any
    float, a small integer, random characters."""
    return st.one_of(
        st.sampled_from(CELLS),
        st.floats().map(repr),
        st.integers(-5, 5).map(str),
        st.text(ALPHABET, max_size=5),
    )


def _log_rows(draw: st.DrawFn) -> list[list[str]]:
    """A plausible log: ``t`` and a random choice of the columns a run writes (for 0-3
    joints), 1-4 rows of small numbers ("ok" in ``status``)."""
    pool = [c for c in (*contract_columns(draw(st.integers(0, 3))), *EXTRA_COLUMNS) if c != "t"]
    header = ["t", *draw(st.lists(st.sampled_from(pool), unique=True, min_size=2, max_size=10))]
    rows = [header]
    numbers = st.floats(-2, 2).map(repr)
    for k in range(draw(st.integers(1, 4))):
        cells = ["ok" if name == "status" else draw(numbers) for name in header[1:]]
        rows.append([repr(0.5 * k), *cells])
    return rows


def _spoil(draw: st.DrawFn, rows: list[list[str]]) -> None:
    """One defect in a log (``rows[0]`` is the header): a cell replaced (text, NaN, 1e308,
    math text...), a column renamed or duplicated, a row made ragged."""
    what = draw(st.sampled_from(("cell", "cell", "cell", "rename", "duplicate", "ragged")))
    r = draw(st.integers(1, len(rows) - 1)) if what == "cell" else 0
    if what == "ragged":
        r = draw(st.integers(0, len(rows) - 1))
        rows[r] = rows[r][:-1] if draw(st.booleans()) else [*rows[r], "0.0"]
    elif rows[r]:  # a cell of a row (mostly not in `t`: then its column's figure is drawn)
        c = draw(st.integers(0, len(rows[r]) - 1)) + (what == "cell")
        c %= len(rows[r])
        if what == "cell":
            rows[r][c] = draw(csv_cells())
        else:
            names = st.sampled_from(rows[0]) if what == "duplicate" else column_names()
            rows[0][c] = draw(names)


def column_names() -> st.SearchStrategy[str]:
    """A column name: one a run writes, or junk."""
    return st.sampled_from(LOG_COLUMNS) | st.text(ALPHABET, max_size=6)


@st.composite
def log_csv(draw: st.DrawFn) -> bytes:
    """A ``log.csv``: mostly a plausible log with 1-3 defects (``_spoil``), the last
    newline sometimes missing; else a header only, random rows of random cells, or bytes
    that are not a CSV at all."""
    kind = draw(st.integers(0, 9))  # 0-6 (hypothesis favours small numbers): spoilt
    if kind == 9:
        return draw(st.binary(max_size=200))
    if kind == 8:
        return draw(st.text(ALPHABET, max_size=200)).encode()
    if kind <= 6:
        rows = _log_rows(draw)
        for _ in range(draw(st.integers(1, 3))):
            _spoil(draw, rows)
    else:
        rows = [draw(st.lists(column_names(), max_size=10))]
        for _ in range(draw(st.integers(0, 3))):
            rows.append(draw(st.lists(csv_cells(), max_size=len(rows[0]) + 1)))
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(rows)
    text = buf.getvalue()
    if draw(st.integers(0, 5)) == 5:  # (hypothesis favours 0)
        text = text.rstrip("\n")
    return text.encode()


def json_values() -> st.SearchStrategy[Any]:
    """Any JSON value (NaN and infinities included, as Python's json writes them)."""
    scalars = (
        st.none() | st.booleans() | st.floats() | st.integers() | st.text(ALPHABET, max_size=6)
    )
    return st.recursive(
        scalars,
        lambda v: (
            st.lists(v, max_size=4) | st.dictionaries(st.text(ALPHABET, max_size=4), v, max_size=4)
        ),
        max_leaves=8,
    )


@st.composite
def meta_json(draw: st.DrawFn) -> bytes | None:
    """A ``meta.json``: absent, the keys the plots read with wrong values, any JSON, or
    bytes that are not JSON."""
    kind = draw(st.sampled_from(("absent", "known", "known", "known", "json", "junk")))
    if kind == "absent":
        return None
    if kind == "junk":
        return draw(st.binary(max_size=60))
    if kind == "json":
        return json.dumps(draw(json_values())).encode()
    columns = st.sampled_from(("q1", "x", "u_x", "u_q1", "z", "ee_x", "t"))
    pairs = st.lists(st.none() | st.floats() | st.text(ALPHABET, max_size=3), max_size=3)
    meta = draw(
        st.fixed_dictionaries(
            {},
            optional={
                "bounds": st.dictionaries(columns, pairs | json_values(), max_size=3)
                | json_values(),
                "state_names": st.lists(columns | json_values(), max_size=4) | json_values(),
                "waypoints": st.lists(st.lists(st.floats(), max_size=4), max_size=3)
                | json_values(),
                "scenario": st.text(ALPHABET, max_size=12) | json_values(),
                "clearance_min": st.floats() | json_values(),
                "clearance_planned": st.floats() | json_values(),
            },
        )
    )
    return json.dumps(meta).encode()


@st.composite
def run_directories(draw: st.DrawFn) -> dict[str, bytes]:
    """The files of a run directory (relative path -> bytes): one run at the top, or 1-2
    variant runs below it with a ``summary.json``; sometimes a stray file, a stale
    ``figures/`` or a file named ``figures``."""
    files: dict[str, bytes] = {}
    runs = [""] if draw(st.booleans()) else draw(st.sampled_from((["a/"], ["a/", "b/"])))
    for prefix in runs:
        files[f"{prefix}log.csv"] = draw(log_csv())
        meta = draw(meta_json())
        if meta is not None:
            files[f"{prefix}meta.json"] = meta
    if runs != [""] and draw(st.booleans()):
        files["summary.json"] = json.dumps(draw(json_values())).encode()
    extra = draw(st.sampled_from((None, None, "notes", "stale", "figures-file")))
    if extra == "notes":
        files["notes.txt"] = b"keep me\n"
    elif extra == "stale":
        files[f"{runs[0]}figures/old.png"] = b"not a png"
    elif extra == "figures-file":
        files[f"{runs[0]}figures"] = b"a file where figures/ would go\n"
    return files


def _snapshot(root: Path) -> dict[str, bytes]:
    """Every file below ``root`` outside any ``figures`` entry: relative path -> bytes."""
    return {
        str(p.relative_to(root)): p.read_bytes()
        for p in sorted(root.rglob("*"))
        if p.is_file() and "figures" not in p.relative_to(root).parts
    }


@settings(FUZZ, max_examples=150)
@given(files=run_directories())
@example(files={"log.csv": b"t,ee_x,ee_y,ee_z,ref_x,ref_y,ref_z\n0,0,0,x,0,0,0\n"})
@example(files={"log.csv": b"t,solve_ms\n0,x\n"})
@example(files={"log.csv": b"t,roll,pitch\n0,x,1\n"})
@example(files={"log.csv": b"t,cog_bx,cog_by\n0,x,1\n"})
@example(files={"log.csv": b"t,q1\n0,1e308\n"})
@example(files={"log.csv": b"t,u_x\n0,1\n", "meta.json": b'{"state_names": 5}'})
@example(files={"log.csv": b"t,clear_a\n0,1\n", "meta.json": b'{"clearance_min": "abc"}'})
@example(files={"log.csv": b"t,q1\n0,1\n", "meta.json": b'{"bounds": {"q1": [-1e308, 1e308]}}'})
@example(files={"log.csv": b"t,x\n0,1\n", "meta.json": b'{"scenario": "$\\\\foo$"}'})
@example(files={"log.csv": b"t,q1\n0,1\n", "figures": b"a file\n"})
@example(
    files={
        "a/log.csv": b"t,ee_x,ee_y,ee_z\n0,0,0,1\n",
        "b/log.csv": b"t,ee_x,ee_y,ee_z\n0,0,0,1\n",
        "b/meta.json": b'{"waypoints": [[1, 2]]}',
    }
)
@example(files={"a/log.csv": b"t,cond\n0,x\n", "b/log.csv": b"t,cond\n0,1\n"})
def test_plot_of_malformed_run_directories_is_one_line_and_loses_nothing(files, tmp_path, capsys):
    d = fresh_dir(tmp_path)
    written = _write(d, files)
    before = _snapshot(d)
    argv = ["plot", str(d)]
    what = _describe(argv, written)
    rc, _, err, shown = call(argv, capsys, PLOT_LIMIT_S, what)
    assert_rule(rc, err, shown, what, quiet_ok=False)
    after = _snapshot(d)
    lost = [p for p, content in before.items() if after.get(p) != content]
    assert not lost, f"changed or removed by plot: {lost}\n{what}"


# ------------------------------------------- 5. plausible mutations, flown for one step

ALTERNATIVES = {
    "strategy": ("weighted", "hierarchical"),
    "backend": ("ipopt", "sqp"),
    "sim": ("kinematic", "physics"),
    "mode": ("stagewise", "strict", "total"),
}


@st.composite
def plausible_scenarios(draw: st.DrawFn) -> tuple[str, dict[str, Any]]:
    """(built-in name, table) after 1-2 mutations a user might make: a number scaled, a
    flag flipped, a choice switched to another valid one, an entry deleted."""
    name = draw(st.sampled_from(SCENARIOS))
    data = copy.deepcopy(BUILTIN_SCENARIOS[name])
    for _ in range(draw(st.integers(1, 2))):
        path = draw(st.sampled_from(list(_paths(data))))
        parent = _parent(data, path)
        value = parent[path[-1]]
        if isinstance(value, bool):
            parent[path[-1]] = not value
        elif isinstance(value, int | float):
            factor = draw(st.sampled_from((0, 0.5, 0.9, 1.1, 2)))
            parent[path[-1]] = type(value)(value * factor)
        elif isinstance(value, str) and path[-1] in ALTERNATIVES:
            parent[path[-1]] = draw(st.sampled_from(ALTERNATIVES[path[-1]]))
        else:
            del parent[path[-1]]
    return name, data


@settings(FUZZ, max_examples=6)
@given(case=plausible_scenarios())
def test_scenarios_that_pass_check_fly(case, tmp_path, capsys, monkeypatch):
    from aeromanip.experiment.scenario import load_scenarios

    monkeypatch.setenv("AEROMANIP_CACHE", str(tmp_path / "cache"))
    _, data = case
    d = fresh_dir(tmp_path)
    files = _write(d, {"s.toml": tomli_w.dumps(data)})
    assume(check_file(d / "s.toml", files, d, capsys) == 0)
    period = max(sc.problem.dt for sc in load_scenarios(d / "s.toml").values())
    out = d / "run"
    argv = ["run", str(d / "s.toml"), "--out", str(out), "--quiet", "--set", f"duration={period!r}"]
    what = _describe(argv, files)
    rc, _, err, _ = call(argv, capsys, RUN_LIMIT_S, what)
    assert rc in (0, 3), f"exit code {rc} after --check said ok: {err!r}\n{what}"
    assert (out / "summary.json").is_file(), f"no summary.json in {out}\n{what}"
