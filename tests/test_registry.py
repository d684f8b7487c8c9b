"""Registries: built-ins by name, and a user's own task, reference, backend and simulator
loaded from a scenario TOML as ``kind = "package.module:Class"`` (one file each, no edit
of aeromanip)."""

import sys
import textwrap

import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.experiment.closed_loop import simulate
from aeromanip.experiment.scenario import load_scenarios
from aeromanip.nmpc.backends import BACKENDS, make_backend
from aeromanip.nmpc.backends.nlpsol import IpoptBackend
from aeromanip.nmpc.constraints import Bounds
from aeromanip.nmpc.problem import Problem
from aeromanip.nmpc.transcription import Transcription
from aeromanip.references import REFERENCES, Constant
from aeromanip.robot.loader import load_robot
from aeromanip.sim.base import SIMULATORS
from aeromanip.tasks import TASKS, EndEffectorTracking

USER_FILES = {
    "lift_task.py": '''
        """A user task: keep the platform at a height given in the scenario."""
        from aeromanip.tasks import Task

        class HoldHeight(Task):
            name = "hold_height"

            def __init__(self, height):
                self.height = height

            def residual(self, stage):
                return stage.x[2] - self.height

            @classmethod
            def from_table(cls, table, reference):
                return cls(table.float("height"))
        ''',
    "circle_ref.py": '''
        """A user reference: a horizontal circle."""
        import numpy as np
        from aeromanip.references import Reference

        class Circle(Reference):
            def __init__(self, center, radius, period):
                self.center, self.radius, self.period = np.array(center), radius, period
                self.duration = period

            def sample(self, times):
                a = 2 * np.pi * np.atleast_1d(np.asarray(times, float)) / self.period
                ring = np.stack([np.cos(a), np.sin(a), 0 * a], axis=1)
                return self.center + self.radius * ring

            @classmethod
            def from_table(cls, table, base_dir=None):
                return cls(table.floats("center", size=3), table.float("radius"),
                           table.float("period"))
        ''',
    "counting_backend.py": '''
        """A user backend: IPOPT, counting its solves."""
        from aeromanip.nmpc.backends.nlpsol import IpoptBackend

        class CountingIpopt(IpoptBackend):
            solves = 0

            def solve(self, request):
                type(self).solves += 1
                return super().solve(request)
        ''',
    "record_sim.py": '''
        """A user simulator: the ideal loop, recording the commands it flies; its options
        (a label) in a table of its own."""
        from aeromanip.errors import ConfigError
        from aeromanip.sim.kinematic import KinematicSimulator

        class RecordingSim(KinematicSimulator):
            commands = []
            options_table = "recorder"
            built_with = None

            @classmethod
            def check_options(cls, options):
                if set(options) - {"label"}:
                    raise ConfigError(f"recorder: only 'label', got {sorted(options)}")
                return dict(options)

            @classmethod
            def from_options(cls, spec, options):
                cls.built_with = dict(cls.check_options(options))
                return cls(spec)

            def advance(self, u, plan_x, dt):
                type(self).commands.append(u.copy())
                super().advance(u, plan_x, dt)
        ''',
    "not_a_task.py": """
        class Plain:
            pass
        """,
}

SCENARIO = """
extends = "waypoints"
name = "user-classes"
duration = 3.0
sim = "record_sim:RecordingSim"

[controller]
strategy = "weighted"
backend = "counting_backend:CountingIpopt"
horizon = 4

[reference]
kind = "circle_ref:Circle"
center = [0.0, 0.0, 0.6]
radius = 0.05
period = 10.0

[tasks.lift]
kind = "lift_task:HoldHeight"
height = 1.05
weight = 0.5

[recorder]
label = "mine"

[variants.only]
"""


@pytest.fixture
def user_package(tmp_path, monkeypatch):
    for name, text in USER_FILES.items():
        (tmp_path / name).write_text(textwrap.dedent(text))
        # a fresh module each time (class-level counters start at zero)
        monkeypatch.delitem(sys.modules, name.removesuffix(".py"), raising=False)
    monkeypatch.syspath_prepend(str(tmp_path))
    return tmp_path


def test_builtins_are_found_by_name():
    assert {
        "tracking",
        "cog",
        "cog_velocity",
        "manipulability",
        "condition",
        "control_rate",
    } <= set(TASKS.names())
    assert set(REFERENCES.names()) >= {"constant", "sinusoids", "waypoints", "csv", "lissajous"}
    assert set(BACKENDS.names()) >= {"ipopt", "fatrop", "sqp", "sqp-rti"}
    assert set(SIMULATORS.names()) >= {"kinematic", "physics"}
    assert TASKS.get("cog").kind == "cog"


def test_make_backend_defaults_to_ipopt_and_names_the_key_of_an_unknown_backend():
    """The API's own check (a scenario's is made when it loads): ``controller.backend``."""
    robot = load_robot("x8-3dof")
    pb = Problem(robot, 4, 0.1, Bounds.from_robot(robot))
    pb.add_task(EndEffectorTracking(Constant([0.4, 0.3, 0.5])), weight=1.0)
    tr = Transcription(pb, pb.entries)
    backend = make_backend(tr)
    assert type(backend) is IpoptBackend and backend.name == "ipopt"
    with pytest.raises(ConfigError, match=r"^controller\.backend: 'ipoptt' is not one of \["):
        make_backend(tr, "ipoptt")


def test_user_classes_from_a_scenario_toml_fly_a_run(user_package):
    path = user_package / "user.toml"
    path.write_text(SCENARIO)
    sc = load_scenarios(path, only="only")["only"]
    assert type(sc.reference).__name__ == "Circle"
    assert [e.name for e in sc.problem.entries] == ["tracking", "cog", "control_rate", "lift"]
    log = simulate(sc, progress=False)
    steps = len(log)
    # the user's reference is the one tracked and logged
    t = log.column("t")
    ring = sc.reference.sample(t)
    np.testing.assert_allclose(np.stack([log.column(f"ref_{c}") for c in "xyz"], 1), ring)
    # the user's task is in the cost, the user's backend solved, the user's simulator flew
    assert np.all(np.isfinite(log.column("cost_lift")))
    from counting_backend import CountingIpopt
    from record_sim import RecordingSim

    assert CountingIpopt.solves >= steps
    assert len(RecordingSim.commands) == steps
    assert RecordingSim.built_with == {"label": "mine"}  # its own table, not [physics]
    assert sc.resolved["recorder"] == {"label": "mine"}
    np.testing.assert_allclose(
        RecordingSim.commands[0],
        [log.column(f"u_{n}")[0] for n in ("x", "y", "z", "yaw", "q1", "q2", "q3")],
    )


@pytest.mark.parametrize(
    ("override", "message"),
    [
        (
            'tasks.lift.kind="no_such_module:X"',
            "tasks.lift.kind: 'no_such_module:X': cannot import",
        ),
        (
            'tasks.lift.kind="lift_task:Nope"',
            "tasks.lift.kind: 'lift_task:Nope': 'lift_task' has no",
        ),
        ('tasks.lift.kind="not_a_task:Plain"', "tasks.lift.kind: 'not_a_task:Plain' is not a Task"),
        ('tasks.lift.kind="lift_task:"', "expected 'package.module:Class'"),
        ('tasks.lift.kind="lifter"', "tasks.lift.kind: 'lifter' is not one of"),
        ('reference.kind="circle_ref:Nope"', "reference.kind: 'circle_ref:Nope'"),
        (
            'controller.backend="not_a_task:Plain"',
            "controller.backend: 'not_a_task:Plain' is not a",
        ),
        ('controller.backend="ipoptt"', "controller.backend: 'ipoptt' is not one of"),
        ('sim="not_a_task:Plain"', "sim: 'not_a_task:Plain' is not a Simulator"),
        ('sim="mujoco"', "sim: 'mujoco' is not one of"),
    ],
)
def test_a_bad_kind_is_one_clear_line_naming_the_key(user_package, override, message):
    path = user_package / "user.toml"
    path.write_text(SCENARIO)
    with pytest.raises(ConfigError) as err:
        load_scenarios(path, [override], only="only")
    text = str(err.value)
    assert message in text and "\n" not in text, text
