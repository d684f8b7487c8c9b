"""A task of one's own takes its scenario options from its constructor (``Task.from_table``
by default, ``aeromanip.tasks.options``): keys matched against the keyword parameters,
values checked against their annotations, one line naming the key otherwise."""

from typing import Literal

import casadi as ca
import numpy as np
import pytest

from aeromanip import ConfigError, Stage, Task
from aeromanip.experiment import load_scenarios, simulate
from aeromanip.references import Reference

SCENARIO = """
name = "own-task"
robot = "x8-3dof"
duration = 6.0
initial_state = [0.0, 0.0, 1.0, 0.0, 0.0, 0.6, -1.2]
sim = "kinematic"
[controller]
strategy = "weighted"
backend = "ipopt"
horizon = 8
dt = 0.1
[reference]
kind = "constant"
point = [0.3, 0.2, 0.7]
[tasks.tracking]
weight = 10.0
[tasks.own]
kind = "test_task_options:Height"
weight = 1.0
{own}
[tasks.control_rate]
regularizer = true
weight = 0.05
"""


class Height(Task):
    """``r = gain * (coordinate - target)``: a platform coordinate toward a target [m]."""

    name = "height"

    def __init__(
        self,
        target: float,
        axis: Literal["x", "y", "z"] = "z",
        gain: float = 1.0,
        reference: Reference | None = None,
    ) -> None:
        self.target, self.axis, self.gain, self.reference = target, axis, gain, reference

    def residual(self, stage: Stage) -> ca.SX:
        """The gained coordinate error."""
        return self.gain * (stage.x["xyz".index(self.axis)] - self.target)


def scenario(tmp_path, own: str):
    path = tmp_path / "own.toml"
    path.write_text(SCENARIO.format(own=own))
    (sc,) = load_scenarios(path).values()
    return sc


def test_constructor_options_from_the_toml_reach_the_task_and_the_flight(tmp_path):
    sc = scenario(tmp_path, "target = 1.1\ngain = 2")
    task = next(e.task for e in sc.problem.entries if e.name == "own")
    assert (task.target, task.axis, task.gain) == (1.1, "z", 2.0)
    assert task.reference is sc.reference  # a Reference parameter gets the scenario's
    resolved = sc.resolved["tasks"]["own"]
    assert resolved["target"] == 1.1 and resolved["axis"] == "z"  # defaults recorded too
    log = simulate(sc)
    assert abs(log.column("z")[-1] - 1.1) < 5e-3  # the platform went to the option's height


@pytest.mark.parametrize(
    ("own", "message"),
    [
        ("target = 1.2\ntarget_z = 1", "tasks.own.target_z: unknown key (Height takes target "
         "(a number), axis (one of ['x', 'y', 'z']), gain (a number); did you mean 'target'?)"),
        ('target = "high"', "tasks.own.target: expected a number, got 'high'"),
        ("target = true", "tasks.own.target: expected a number, got True"),
        ("target = 1\naxis = 'w'", "tasks.own.axis: expected one of ['x', 'y', 'z'], got 'w'"),
        ("gain = 2", "tasks.own.target: missing required key (Height needs a number)"),
        ("target = nan", "tasks.own.target: must be a finite number, got nan"),
        ("target = 1\nreference = 2", "tasks.own.reference: unknown key"),
    ],
)  # fmt: skip
def test_a_wrong_option_is_one_line_naming_key_value_and_what_is_allowed(tmp_path, own, message):
    with pytest.raises(ConfigError) as e:
        scenario(tmp_path, own)
    assert str(e.value).startswith(message) and "\n" not in str(e.value)


def test_annotations_of_containers_are_checked_and_converted():
    from aeromanip.config import Table

    class Shaped(Task):
        def __init__(
            self,
            pair: tuple[float, float] = (0.0, 0.0),
            names: list[str] | None = None,
            matrix: np.ndarray | None = None,
            count: int = 1,
        ) -> None:
            self.pair, self.names, self.matrix, self.count = pair, names, matrix, count

        def residual(self, stage: Stage) -> ca.SX:
            return stage.x[0]

    t = Shaped.from_table(
        Table({"pair": [1, 2], "names": ["q1"], "matrix": [[1, 0], [0, 1]]}), None
    )
    assert t.pair == (1.0, 2.0) and t.names == ["q1"] and t.count == 1
    np.testing.assert_array_equal(t.matrix, np.eye(2))
    for table, message in [
        ({"pair": [1, 2, 3]}, "pair: expected an array of 2 numbers, got [1, 2, 3]"),
        ({"names": ["q1", 2]}, "names: expected an array of strings, got ['q1', 2]"),
        ({"count": 1.5}, "count: expected an integer, got 1.5"),
        ({"matrix": "eye"}, "matrix: expected an array of numbers, got 'eye'"),
    ]:
        with pytest.raises(
            ConfigError, match=f"^{message}".replace("[", r"\[").replace("(", r"\(")
        ):
            Shaped.from_table(Table(table), None)
