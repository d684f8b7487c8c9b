"""URDF import at its edges, against the URDF specification and rotation algebra.

Truths: the URDF spec's defaults (``<axis>`` 1 0 0, ``<limit lower/upper>`` 0, ``<origin>``
and ``<inertia>`` entries 0), round trips through ``rpy_to_matrix`` (roll-pitch-yaw is not
unique at pitch +-pi/2 or beyond), and the module docstring (a single origin is kept exact;
errors name the source and the element).
"""

import math

import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.robot.urdf import arm_from_urdf, arm_from_urdf_string, matrix_to_rpy, rpy_to_matrix

LIMIT = '<limit lower="-1" upper="1" velocity="1"/>'


def chain(j1="", l1='<inertial><mass value="0.1"/></inertial>', extra=""):
    """base -> j1 (revolute) -> l1 [-> extra]."""
    return f"""<robot name="r">
  <link name="base"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>{j1}</joint>
  <link name="l1">{l1}</link>{extra}
</robot>"""


@pytest.mark.parametrize("pitch", [math.pi / 2, -math.pi / 2])
@pytest.mark.parametrize(("roll", "yaw"), [(0.3, 0.5), (-1.0, 2.0), (0.0, -0.7)])
def test_matrix_to_rpy_at_gimbal_lock_gives_roll_zero_and_the_same_rotation(pitch, roll, yaw):
    R = rpy_to_matrix((roll, pitch, yaw))
    out = matrix_to_rpy(R)
    assert out[0] == 0.0 and out[1] == pytest.approx(pitch, abs=1e-7)
    np.testing.assert_allclose(rpy_to_matrix(out), R, atol=1e-7)


def test_single_origin_is_kept_exactly_and_no_fixed_tail_means_a_zero_ee_frame():
    """rpy (0.1, 2.0, 0.3) has pitch beyond pi/2: re-extracting it would change the triple."""
    arm = arm_from_urdf_string(chain(f'<origin xyz="0 0 -0.1" rpy="0.1 2.0 0.3"/>{LIMIT}'))
    assert arm.joints[0].rpy == (0.1, 2.0, 0.3)
    assert (arm.ee_xyz, arm.ee_rpy) == ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))


def test_urdf_defaults_axis_limits_and_inertia_entries():
    j1 = '<limit velocity="2"/>'
    l1 = '<inertial><mass value="0.5"/><inertia ixx="1e-3" iyy="2e-3" izz="3e-3"/></inertial>'
    arm = arm_from_urdf_string(chain(j1, l1))
    j = arm.joints[0]
    assert (j.axis, j.lower, j.upper, j.velocity) == ((1.0, 0.0, 0.0), 0.0, 0.0, 2.0)
    assert j.link.inertia == (1e-3, 2e-3, 3e-3, 0.0, 0.0, 0.0)
    no_inertia = arm_from_urdf_string(chain(LIMIT, '<inertial><mass value="0.5"/></inertial>'))
    assert no_inertia.joints[0].link.inertia == (0.0,) * 6


def test_massless_link_and_equal_limits_are_allowed():
    arm = arm_from_urdf_string(
        chain(
            '<limit lower="0.2" upper="0.2" velocity="1"/>',
            '<inertial><mass value="0"/></inertial>',
        )
    )
    assert (arm.joints[0].lower, arm.joints[0].upper, arm.joints[0].link.mass) == (0.2, 0.2, 0.0)


def test_branched_tree_without_tip_lists_every_leaf():
    extra = """
  <joint name="fa" type="fixed"><parent link="l1"/><child link="a"/></joint><link name="a"/>
  <joint name="fa1" type="fixed"><parent link="a"/><child link="a1"/></joint><link name="a1"/>
  <joint name="fb" type="fixed"><parent link="l1"/><child link="b"/></joint><link name="b"/>
  <joint name="fb1" type="fixed"><parent link="b"/><child link="b1"/></joint><link name="b1"/>"""
    with pytest.raises(ConfigError, match=r"\['a1', 'b1'\]"):
        arm_from_urdf_string(chain(LIMIT, extra=extra))


def test_arm_from_urdf_file_passes_base_link(tmp_path):
    text = chain(
        LIMIT,
        extra='<joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>'
        f'{LIMIT}</joint><link name="l2"/>',
    )
    (tmp_path / "a.urdf").write_text(text, encoding="utf-8")
    assert [j.name for j in arm_from_urdf(tmp_path / "a.urdf", base_link="l1").joints] == ["j2"]


BAD = [  # (j1 contents, l1 contents, extra, words the error must contain)
    ('<origin xyz="1 2"/>' + LIMIT, "", "", ["src.urdf", "joint 'j1'", "<origin>", "xyz"]),
    ('<origin rpy="a b c"/>' + LIMIT, "", "", ["src.urdf", "joint 'j1'", "<origin>", "rpy"]),
    ('<limit lower="x" upper="1" velocity="1"/>', "", "", ["joint 'j1'", "lower"]),
    ('<limit lower="-1" upper="inf" velocity="1"/>', "", "", ["joint 'j1'", "upper"]),
    ('<limit lower="-1" upper="1" velocity="0"/>', "", "", ["joint 'j1'", "velocity"]),
    (LIMIT, '<inertial><mass value="abc"/></inertial>', "", ["src.urdf", "link 'l1'", "mass"]),
    (LIMIT, '<inertial><mass value="1"/><origin xyz="0 0"/></inertial>', "", ["link 'l1'"]),
    (LIMIT, '<inertial><mass value="1"/><inertia ixx="q"/></inertial>', "", ["link 'l1'", "ixx"]),
    (LIMIT, "", '<link name="l1"/>', ["duplicate"]),
    (LIMIT, "", '<joint name="orphan" type="fixed"><child link="l1"/></joint>', ["parent link"]),
]


@pytest.mark.parametrize(("j1", "l1", "extra", "words"), BAD)
def test_malformed_elements_are_config_errors_naming_source_and_element(j1, l1, extra, words):
    with pytest.raises(ConfigError) as err:
        arm_from_urdf_string(chain(j1, l1, extra), source="src.urdf")
    for w in words:
        assert w in str(err.value)


def test_malformed_origin_off_the_chain_names_its_joint():
    """Off-chain parts are merged rigidly (module doc): their joint origin is read too."""
    extra = (
        '<joint name="off" type="fixed"><parent link="l1"/><child link="o"/>'
        '<origin xyz="0 0 z"/></joint><link name="o"/>'
    )
    with pytest.raises(ConfigError, match=r"src\.urdf: joint 'off'"):
        arm_from_urdf_string(chain(LIMIT, "", extra), tip_link="l1", source="src.urdf")
