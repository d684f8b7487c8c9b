"""Robot TOML errors: one line naming the file, the full key path and the problem."""

import copy
import tomllib
from importlib import resources
from pathlib import Path

import pytest
import tomli_w

from aeromanip.cli import main
from aeromanip.config import Table
from aeromanip.errors import AeromanipError, ConfigError
from aeromanip.robot.loader import load_robot, robot_from_table

BUILTIN = Path(str(resources.files("aeromanip.robots") / "x8-3dof.toml"))


@pytest.fixture(scope="module")
def x8_table():
    return tomllib.loads(BUILTIN.read_text())


def write_robot(tmp_path, data, name="robot.toml"):
    path = tmp_path / name
    path.write_text(tomli_w.dumps(data))
    return path


def _set(data, keys, value):
    node = data
    for k in keys[:-1]:
        node = node[k]
    node[keys[-1]] = value


def _del(data, keys):
    node = data
    for k in keys[:-1]:
        node = node[k]
    del node[keys[-1]]


# (edit: keys into the table, value or DELETE), expected key path, expected problem
DELETE = object()
CASES = {
    "odd rotor count": (["platform", "rotors"], 7, "platform.rotors", "even integer >= 4"),
    "coaxial quad": (["platform", "rotors"], 4, "platform.rotors", "coaxial pairs need"),
    "zero axis": (["joints", 1, "axis"], [0.0, 0.0, 0.0], "joints[1].axis", "must be non-zero"),
    "non-unit axis": (["joints", 1, "axis"], [0.0, 2.0, 0.0], "joints[1].axis", "unit vector"),
    "negative link mass": (
        ["joints", 2, "link", "mass"],
        -0.08,
        "joints[2].link.mass",
        "must be in [0, 1000] kg, got -0.08",
    ),
    "lower limit above upper": (
        ["joints", 0, "limits"],
        [1.0, -1.0],
        "joints[0].limits",
        "lower 1.0 is above upper -1.0",
    ),
    "unknown platform dof": (
        ["platform", "dofs"],
        ["x", "y", "z", "roll"],
        "platform.dofs[3]",
        "unknown platform DoF 'roll'",
    ),
    "zero joint velocity": (
        ["joints", 1, "velocity"],
        0.0,
        "joints[1].velocity",
        "must be a finite number > 0",
    ),
    "negative joint velocity": (
        ["joints", 2, "velocity"],
        -1.0,
        "joints[2].velocity",
        "must be a finite number > 0",
    ),
    "negative platform velocity": (
        ["platform", "velocity", "z"],
        -0.7,
        "platform.velocity.z",
        "must be a finite number > 0",
    ),
    "missing link mass": (
        ["joints", 1, "link", "mass"],
        DELETE,
        "joints[1].link.mass",
        "missing required key",
    ),
    "missing name": (["name"], DELETE, "name", "missing required key"),
    "wrong type mass": (
        ["joints", 1, "link", "mass"],
        "heavy",
        "joints[1].link.mass",
        "expected a number, got 'heavy'",
    ),
    "wrong type limits": (
        ["joints", 0, "limits"],
        "wide",
        "joints[0].limits",
        "expected an array of numbers",
    ),
    "unknown key": (["joints", 0, "lenght"], 0.1, "joints[0].lenght", "unknown key"),
}


def broken(x8_table, case):
    keys, value, _, _ = CASES[case]
    data = copy.deepcopy(x8_table)
    if value is DELETE:
        _del(data, keys)
    else:
        _set(data, keys, value)
    return data


def test_unmodified_copy_loads(tmp_path, x8_table):
    """The baseline every case below edits is valid: each error comes from its edit."""
    spec = load_robot(write_robot(tmp_path, x8_table))
    assert spec == load_robot("x8-3dof")


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_robot_file_names_file_key_path_and_problem(tmp_path, x8_table, case):
    _, _, key, problem = CASES[case]
    path = write_robot(tmp_path, broken(x8_table, case))
    with pytest.raises(AeromanipError) as info:
        load_robot(path)
    assert type(info.value) is ConfigError
    message = str(info.value)
    assert message.startswith(f"{path.resolve()}: {key}: "), message
    assert problem in message
    assert "\n" not in message


@pytest.mark.parametrize("case", ["zero axis", "negative link mass", "wrong type mass"])
def test_nested_robot_table_errors_carry_the_table_prefix(x8_table, case):
    """As in a scenario's ``[robot]``: spec checks and type checks share one key path."""
    _, _, key, problem = CASES[case]
    for data in (broken(x8_table, case), Table(broken(x8_table, case), "robot")):
        with pytest.raises(ConfigError) as info:
            robot_from_table(data, path="robot")
        assert str(info.value).startswith(f"robot.{key}: "), str(info.value)
        assert problem in str(info.value)


def test_robot_table_without_file_or_prefix_keeps_plain_key_path(x8_table):
    with pytest.raises(ConfigError, match=r"^joints\[1\]\.axis: must be non-zero"):
        robot_from_table(broken(x8_table, "zero axis"))


def test_source_names_the_file(x8_table):
    with pytest.raises(
        ConfigError, match=r"^my/arm\.toml: joints\[2\]\.link\.mass: must be in \[0, 1000\] kg"
    ):
        robot_from_table(broken(x8_table, "negative link mass"), source="my/arm.toml")


@pytest.mark.parametrize("quote", ["'", ""])
def test_cli_bad_robot_file_is_exit_2_and_one_line(tmp_path, x8_table, capsys, quote):
    path = write_robot(tmp_path, broken(x8_table, "zero axis"))
    code = main(
        [
            "run",
            "flight",
            "--set",
            f"robot={quote}{path}{quote}",
            "--set",
            "duration=1",
            "--out",
            str(tmp_path / "out"),
        ]
    )
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert err.startswith("aeromanip: error: ")
    assert "robot.joints[1].axis: must be non-zero, got [0.0, 0.0, 0.0]" in err
    assert not (tmp_path / "out").exists()
