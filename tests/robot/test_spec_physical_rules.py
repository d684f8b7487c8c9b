"""Robot spec validation: each physical rule rejects what breaks it, names the key, and
accepts its boundary case.

Truths: physics (masses, lengths, principal moments and speed limits are > 0; products of
inertia may be negative; a zero-width joint range is a locked joint, not an error), the
``Platform`` docstring (an unnamed DoF's speed limit is 1) and the key paths of the
robot TOML format.
"""

import dataclasses
import math

import pytest

from aeromanip.errors import ConfigError
from aeromanip.robot.loader import robot_from_table


def joint(name="q1", **over):
    j = {
        "name": name,
        "axis": [0.0, 1.0, 0.0],
        "limits": [-1.0, 1.0],
        "velocity": 1.0,
        "link": {"mass": 0.1, "name": f"{name}_l"},
    }
    j.update(over)
    return j


def build(platform=None, joints=None, **over):
    t = {
        "name": "t",
        "platform": {"dofs": ["x", "y", "z", "yaw"], **(platform or {})},
        "joints": joints or [joint()],
    }
    t.update(over)
    return robot_from_table(t)


def test_velocity_limit_of_an_unnamed_dof_is_one():
    pf = build(platform={"velocity": {"x": 2.5}}).platform
    assert (pf.velocity_limit("x"), pf.velocity_limit("yaw")) == (2.5, 1.0)


NAN = math.nan
BAD = [
    ({"mount": {"xyz": [0.0, NAN, 0.0]}}, r"mount\.xyz\[1\]"),
    ({"platform": {"dofs": ["x"], "fixed": {"yaw": NAN}}}, r"platform\.fixed\.yaw"),
    ({"platform": {"inertia": [0.1, NAN, 0.1]}}, r"platform\.inertia\[1\]"),
    ({"platform": {"inertia": [0.1, 0.0, 0.1]}}, r"platform\.inertia"),
    ({"platform": {"velocity": {"x": 0.0}}}, r"platform\.velocity"),
    ({"platform": {"mass": 0.0}}, r"platform\.mass"),
    ({"platform": {"arm_length": 0.0}}, r"platform\.arm_length"),
    ({"platform": {"rotors": 2}}, r"platform\.rotors"),
    ({"joints": [joint(xyz=[0.0, NAN, 0.0])]}, r"joints\[0\]\.xyz\[1\]"),
    ({"joints": [joint(link={"mass": 0.1, "com": [NAN, 0.0, 0.0]})]}, r"link\.com\[0\]"),
    ({"joints": [joint(limits=[NAN, 1.0])]}, r"joints\[0\]\.limits"),
    ({"joints": [joint(link={"mass": 0.0})]}, r"arm"),
    ({"joints": [joint("a"), joint("a")]}, r"joints\[1\]\.name"),
    (
        {
            "joints": [
                joint("a", link={"mass": 0.1, "name": "l"}),
                joint("b", link={"mass": 0.1, "name": "l"}),
            ]
        },
        r"joints\[1\]\.link\.name",
    ),
]


@pytest.mark.parametrize(("over", "key"), BAD)
def test_invalid_values_are_rejected_naming_the_key(over, key):
    over = dict(over)  # the parameters are shared between runs: do not consume them
    platform = over.pop("platform", None)
    joints = over.pop("joints", None)
    with pytest.raises(ConfigError, match=key):
        build(platform, joints, **over)


def test_rotor_count_must_be_an_int_not_a_float():
    """``replace`` re-runs the spec's validation (``__post_init__``)."""
    spec = build()
    with pytest.raises(ConfigError, match="rotors"):
        dataclasses.replace(spec, platform=dataclasses.replace(spec.platform, rotors=4.0))


def test_boundary_cases_that_are_physical_are_accepted():
    spec = build(
        platform={"mass": 0.5},
        joints=[
            joint(
                limits=[0.3, 0.3],  # a locked joint
                link={"mass": 0.1, "inertia": [1e-4, 1e-4, 1e-4, -1e-6, -1e-6, -1e-6]},
            )
        ],
    )
    assert spec.platform.mass == 0.5 and spec.joints[0].link.inertia[3] == -1e-6
