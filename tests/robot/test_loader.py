"""Robot TOML loading: every key reaches the spec, omitted keys take the spec's defaults,
malformed ones fail with a ``ConfigError``.

Truths: the ``Platform``/``Inertial``/``RobotSpec`` dataclass defaults (a key left out means
the spec's own default), the module docstring's format (sizes of xyz/rpy/axis/com/inertia,
``limits = [lower, upper]``), TOML files read with ``tomllib``, URDF chains written here.
"""

import dataclasses
import math
import tomllib
from importlib import resources

import pytest

from aeromanip.errors import ConfigError
from aeromanip.robot.loader import builtin_robots, load_robot, robot_from_table
from aeromanip.robot.spec import Inertial, Platform, RobotSpec


def joint(**over):
    j = {
        "name": "q1",
        "axis": [0.0, 1.0, 0.0],
        "limits": [-1.0, 1.0],
        "velocity": 1.0,
        "link": {"mass": 0.1},
    }
    j.update(over)
    return j


def table(**over):
    t = {"name": "t", "platform": {"dofs": ["x", "y", "z", "yaw"]}, "joints": [joint()]}
    t.update(over)
    return t


def default(cls, name):
    f = {f.name: f for f in dataclasses.fields(cls)}[name]
    return f.default if f.default is not dataclasses.MISSING else f.default_factory()


def test_builtin_robots_lists_every_packaged_toml_with_its_description():
    expected = {}
    for item in resources.files("aeromanip.robots").iterdir():
        if item.name.endswith(".toml"):
            data = tomllib.loads(item.read_text(encoding="utf-8"))
            expected[item.name.removesuffix(".toml")] = data.get("description", "")
    assert builtin_robots() == expected and "x8-3dof" in expected


def test_unknown_robot_name_says_robot():
    with pytest.raises(ConfigError, match=r"robot: unknown robot 'no-such-uam'"):
        load_robot("no-such-uam")


def test_omitted_keys_take_the_spec_defaults():
    spec = robot_from_table(table())
    pf = spec.platform
    for name in ("fixed", "mass", "inertia", "arm_length", "velocity", "rotors", "coaxial"):
        assert getattr(pf, name) == pytest.approx(default(Platform, name)), name
    for name in ("mount_xyz", "mount_rpy", "ee_xyz", "ee_rpy", "ee_link"):
        assert getattr(spec, name) == default(RobotSpec, name), name
    j = spec.joints[0]
    assert (j.xyz, j.rpy) == ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert (j.link.com, j.link.inertia) == (default(Inertial, "com"), default(Inertial, "inertia"))
    assert j.link_name == "q1_link"  # an unnamed link is named after its joint


def test_every_given_key_reaches_the_spec():
    data = table(
        platform={"dofs": ["x", "y", "z"], "fixed": {"yaw": 0.25}},
        mount={"xyz": [0.1, 0.2, -0.3], "rpy": [0.4, -0.5, 0.6]},
        end_effector={"xyz": [0.0, 0.01, -0.2], "rpy": [0.3, 0.2, 0.1], "name": "gripper"},
        joints=[
            joint(
                xyz=[0.0, 0.0, -0.04],
                rpy=[0.1, 0.2, 0.3],
                link={"name": "arm", "mass": 0.2, "com": [0.0, 0.0, -0.1]},
            )
        ],
    )
    spec = robot_from_table(data)
    assert dict(spec.platform.fixed) == {"yaw": 0.25}
    assert (spec.mount_xyz, spec.mount_rpy) == ((0.1, 0.2, -0.3), (0.4, -0.5, 0.6))
    assert (spec.ee_xyz, spec.ee_rpy, spec.ee_link) == (
        (0.0, 0.01, -0.2),
        (0.3, 0.2, 0.1),
        "gripper",
    )
    j = spec.joints[0]
    assert (j.xyz, j.rpy, j.link_name, j.link.com) == (
        (0.0, 0.0, -0.04),
        (0.1, 0.2, 0.3),
        "arm",
        (0.0, 0.0, -0.1),
    )


def test_continuous_joint_limits_may_be_infinite():
    spec = robot_from_table(table(joints=[joint(limits=[-math.inf, math.inf])]))
    assert (spec.joints[0].lower, spec.joints[0].upper) == (-math.inf, math.inf)


@pytest.mark.parametrize(
    ("over", "key"),
    [
        ({"mount": {"xyz": [0.0, 0.0]}}, "mount.xyz"),
        ({"mount": {"rpy": [0.0, 0.0, 0.0, 0.0]}}, "mount.rpy"),
        ({"end_effector": {"xyz": [0.0]}}, "end_effector.xyz"),
        ({"end_effector": {"rpy": [0.0, 0.0]}}, "end_effector.rpy"),
        ({"platform": {"dofs": ["x"], "inertia": [0.1, 0.1]}}, "platform.inertia"),
        ({"joints": [joint(xyz=[0.0, 0.0])]}, "xyz"),
        ({"joints": [joint(rpy=[0.0, 0.0])]}, "rpy"),
        ({"joints": [joint(axis=[0.0, 1.0])]}, "axis"),
        ({"joints": [joint(limits=[-1.0, 0.0, 1.0])]}, "limits"),
        ({"joints": [joint(link={"mass": 0.1, "com": [0.0, 0.0]})]}, "com"),
        ({"joints": [joint(link={"mass": 0.1, "inertia": [1e-5] * 5})]}, "inertia"),
        ({"platform": {"dofs": "xyz"}}, "platform.dofs"),
    ],
)
def test_wrong_sizes_and_types_are_config_errors_naming_the_key(over, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        robot_from_table(table(**over))


URDF = """<robot name="r">
  <link name="root"/>
  <joint name="j0" type="revolute"><parent link="root"/><child link="arm_base"/>
    <axis xyz="0 0 1"/><limit lower="-1" upper="1" velocity="1"/></joint>
  <link name="arm_base"><inertial><mass value="0.1"/></inertial></link>
  <joint name="j1" type="revolute"><parent link="arm_base"/><child link="l1"/>
    <origin xyz="0 0 -0.1"/><axis xyz="0 1 0"/><limit lower="-1" upper="1" velocity="1"/></joint>
  <link name="l1"><inertial><mass value="0.2"/></inertial></link>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0 0 -0.2"/><axis xyz="0 1 0"/><limit lower="-1" upper="1" velocity="1"/></joint>
  <link name="l2"><inertial><mass value="0.3"/></inertial></link>
  <joint name="tool" type="fixed"><parent link="l2"/><child link="tip"/>
    <origin xyz="0 0 -0.05"/></joint>
  <link name="tip"/>
</robot>
"""


def urdf_table(file, **arm):
    return {"name": "u", "platform": {"dofs": ["x", "y", "z"]}, "arm": {"urdf": str(file), **arm}}


def test_urdf_arm_defaults_to_root_and_single_leaf(tmp_path, monkeypatch):
    """No base/tip: root to the only leaf; a relative path with no base dir is cwd-relative."""
    (tmp_path / "arm.urdf").write_text(URDF, encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    spec = robot_from_table(urdf_table("arm.urdf"))
    assert [j.name for j in spec.joints] == ["j0", "j1", "j2"]
    assert spec.ee_xyz == (0.0, 0.0, -0.05)


def test_urdf_arm_base_and_tip_links_select_the_chain(tmp_path):
    (tmp_path / "arm.urdf").write_text(URDF, encoding="utf-8")
    data = urdf_table("arm.urdf", base_link="arm_base", tip_link="l2")
    spec = robot_from_table(data, base_dir=tmp_path)
    assert [j.name for j in spec.joints] == ["j1", "j2"]
    assert spec.ee_xyz == (0.0, 0.0, 0.0)  # the tip is the last moving link itself


def test_explicit_end_effector_overrides_the_urdf_tip(tmp_path):
    (tmp_path / "arm.urdf").write_text(URDF, encoding="utf-8")
    data = urdf_table("arm.urdf")
    data["end_effector"] = {"xyz": [0.0, 0.0, -0.3], "rpy": [0.0, 0.1, 0.0]}
    spec = robot_from_table(data, base_dir=tmp_path)
    assert (spec.ee_xyz, spec.ee_rpy) == ((0.0, 0.0, -0.3), (0.0, 0.1, 0.0))
