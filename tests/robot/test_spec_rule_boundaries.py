"""Each rule of ``spec.validate`` at its boundary: the last valid value passes, the first
invalid one fails with the key path of the robot TOML format.

Truths: physics (principal moments of any mass distribution are >= 0 and obey
``I1 + I2 >= I3``; masses, lengths and speed limits are > 0; a point mass has zero
inertia), the documented bounds (``MAX_*``, ``INERTIA_SLACK``, a unit axis within 1e-6),
the multirotor layouts the physics supports (an even number of rotors >= 4; coaxial pairs
on >= 4 arms) and the names the URDF export adds (its docstring).
"""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from aeromanip.errors import ConfigError
from aeromanip.robot import spec as sp
from aeromanip.robot.loader import load_robot

X8 = load_robot("x8-3dof")


def with_platform(**over):
    return replace(X8, platform=replace(X8.platform, **over))


def with_joint(i=0, link=None, **over):
    j = X8.joints[i]
    if link is not None:
        j = replace(j, link=replace(j.link, **link))
    j = replace(j, **over)
    return replace(X8, joints=(*X8.joints[:i], j, *X8.joints[i + 1 :]))


def ok(make):
    assert isinstance(make(), sp.RobotSpec)


def bad(make, key):
    with pytest.raises(ConfigError, match=key):
        make()


# --- the platform ----------------------------------------------------------------------------


def test_platform_dofs_known_unique_and_in_state_order():
    ok(lambda: with_platform(dofs=("y", "z"), fixed={"x": 0.5}))
    ok(lambda: with_platform(dofs=(), fixed={}))
    bad(lambda: with_platform(dofs=("x", "roll")), r"^platform\.dofs\[1\]: unknown")
    bad(lambda: with_platform(dofs=("z", "x")), r"^platform\.dofs: must be unique and in")
    bad(lambda: with_platform(dofs=("x", "x")), r"^platform\.dofs: must be unique")


def test_platform_fixed_values_are_for_inactive_known_dofs_and_finite():
    ok(lambda: with_platform(dofs=("x", "y", "z"), fixed={"yaw": -1.2}))
    bad(lambda: with_platform(fixed={"roll": 0.0}), r"^platform\.fixed\.roll: unknown")
    bad(lambda: with_platform(fixed={"x": 0.0}), r"^platform\.fixed\.x: DoF is active")
    bad(lambda: with_platform(dofs=("x",), fixed={"z": math.inf}), r"^platform\.fixed\.z: must")


def test_platform_speed_limits_are_positive_finite_and_for_known_dofs():
    ok(lambda: with_platform(velocity={"x": 1e-3, "yaw": 0.5}))
    assert with_platform(velocity={"x": 2.5}).platform.velocity_limit("z") == 1.0
    for v in (0.0, -1.0, math.inf, math.nan):
        bad(lambda v=v: with_platform(velocity={"x": v}), r"^platform\.velocity\.x: must be")
    bad(lambda: with_platform(velocity={"w": 1.0}), r"^platform\.velocity\.w: unknown")


def test_platform_mass_in_its_range():
    for m in (1e-3, 0.5, sp.MAX_PLATFORM_MASS):
        ok(lambda m=m: with_platform(mass=m))
    for m in (0.0, -1.0, sp.MAX_PLATFORM_MASS * (1 + 1e-12)):
        bad(lambda m=m: with_platform(mass=m), r"^platform\.mass: must be in")


def test_platform_inertia_three_positive_principal_moments():
    ok(lambda: with_platform(inertia=(0.5, 0.5, 0.9)))  # below 1 kg m^2 is fine
    bad(lambda: with_platform(inertia=(0.1, 0.1)), r"^platform\.inertia: must have 3 entries")
    bad(lambda: with_platform(inertia=(0.1, 0.0, 0.1)), r"^platform\.inertia: every entry")
    bad(lambda: with_platform(inertia=(0.1, 0.1, 0.3)), r"^platform\.inertia: principal")


def test_platform_arm_length_positive():
    ok(lambda: with_platform(arm_length=0.05))
    for v in (0.0, -0.1):
        bad(lambda v=v: with_platform(arm_length=v), r"^platform\.arm_length: must be > 0")


def test_rotor_counts_the_physics_supports():
    for n in (4, 6, 8, 12):
        ok(lambda n=n: with_platform(rotors=n, coaxial=False))
    for n in (8, 12, 16):
        ok(lambda n=n: with_platform(rotors=n, coaxial=True))
    for n in (2, 3, 5, 7, 4.0, True):
        bad(lambda n=n: with_platform(rotors=n, coaxial=False), r"^platform\.rotors: must be")
    for n in (4, 6, 10):
        bad(lambda n=n: with_platform(rotors=n, coaxial=True), r"^platform\.rotors: coaxial")


# --- the joints ------------------------------------------------------------------------------


def test_joint_frames_have_three_finite_entries():
    bad(lambda: with_joint(1, xyz=(0.0, 0.0)), r"^joints\[1\]\.xyz: must have 3 entries")
    bad(lambda: with_joint(1, rpy=(0.0, 0.0, math.nan)), r"^joints\[1\]\.rpy\[2\]: must be")
    bad(lambda: with_joint(2, axis=(math.inf, 0.0, 0.0)), r"^joints\[2\]\.axis\[0\]: must be")


def test_joint_axis_is_a_unit_vector_within_1e_6():
    ok(lambda: with_joint(1, axis=(0.0, 1.0 + 9e-7, 0.0)))
    ok(lambda: with_joint(1, axis=(0.0, 0.6, 0.8)))
    bad(lambda: with_joint(1, axis=(0.0, 0.0, 0.0)), r"^joints\[1\]\.axis: must be non-zero")
    bad(lambda: with_joint(1, axis=(1e-9, 0.0, 0.0)), r"^joints\[1\]\.axis: must be a unit")
    bad(lambda: with_joint(1, axis=(0.0, 1.1, 0.0)), r"^joints\[1\]\.axis: must be a unit")
    bad(lambda: with_joint(1, axis=(0.0, 1.0 + 2e-6, 0.0)), r"^joints\[1\]\.axis: must be a unit")


def test_joint_limits_are_ordered_numbers():
    ok(lambda: with_joint(0, lower=0.2, upper=0.2))  # a locked joint
    ok(lambda: with_joint(0, lower=-math.inf, upper=math.inf))  # continuous
    bad(lambda: with_joint(0, lower=0.0, upper=math.nan), r"^joints\[0\]\.limits: must be numb")
    bad(lambda: with_joint(0, lower=math.nan, upper=0.0), r"^joints\[0\]\.limits: must be numb")
    bad(lambda: with_joint(0, lower=0.3, upper=0.2), r"^joints\[0\]\.limits: lower 0\.3 is above")


def test_joint_speed_limit_positive_and_finite():
    ok(lambda: with_joint(0, velocity=1e-3))
    for v in (0.0, -1.0, math.inf, math.nan):
        bad(lambda v=v: with_joint(0, velocity=v), r"^joints\[0\]\.velocity: must be a finite")


def test_link_mass_in_its_range_and_the_arm_heavier_than_nothing():
    for m in (0.0, 0.5, sp.MAX_LINK_MASS):  # a massless link is fine if the arm has mass
        ok(lambda m=m: with_joint(1, link={"mass": m}))
    for m in (-1e-9, sp.MAX_LINK_MASS * (1 + 1e-12)):
        bad(lambda m=m: with_joint(1, link={"mass": m}), r"^joints\[1\]\.link\.mass: must be in")
    light = tuple(replace(j, link=replace(j.link, mass=0.0)) for j in X8.joints)
    bad(lambda: replace(X8, joints=light), r"^joints\[\*\]\.link\.mass: the arm must have")
    ok(lambda: replace(X8, joints=(*light[:2], replace(light[2], link=X8.joints[2].link))))


def test_link_com_and_inertia_shapes():
    bad(lambda: with_joint(0, link={"com": (0.0, 0.0)}), r"^joints\[0\]\.link\.com: must have 3")
    bad(
        lambda: with_joint(0, link={"inertia": (1e-5,) * 5}),
        r"^joints\[0\]\.link\.inertia: must be \[",
    )


# --- inertia: a physical mass distribution ------------------------------------------------------


def link_inertia(i6):
    return lambda: with_joint(2, link={"inertia": i6})


def test_a_point_mass_a_thin_rod_and_negative_products_are_physical():
    ok(link_inertia((0.0,) * 6))  # point mass
    ok(link_inertia((1e-4, 1e-4, 0.0, 0.0, 0.0, 0.0)))  # thin rod along z
    ok(link_inertia((2e-4, 2e-4, 2e-4, -5e-5, -5e-5, -5e-5)))  # PSD with negative products
    ok(link_inertia((sp.MAX_INERTIA,) * 3 + (0.0,) * 3))


def test_negative_diagonal_entries_are_refused_first():
    bad(link_inertia((-1e-9, 1e-4, 1e-4, 0, 0, 0)), r"^joints\[2\]\.link\.inertia: diagonal")


def test_entries_bounded_and_finite():
    too_big = sp.MAX_INERTIA * (1 + 1e-12)
    bad(
        link_inertia((1.0, 1.0, 1.0, too_big, 0, 0)),
        r"^joints\[2\]\.link\.inertia\[3\]: must be within",
    )
    bad(
        link_inertia((1.0, 1.0, 1.0, 0, 0, math.nan)),
        r"^joints\[2\]\.link\.inertia\[5\]: must be a finite",
    )


def test_not_positive_semidefinite_is_refused_to_relative_1e_9():
    # eigenvalues (1e-4 + 1e-4 - 1e-4 ..): the smallest one is -1e-11, 1e-7 of the largest
    a, e = 1e-4, 1e-11
    # [[a, b], [b, a]] has eigenvalues a - b and a + b
    bad(link_inertia((a, a, a, a + e, 0.0, 0.0)), r"^joints\[2\]\.link\.inertia: not positive semi")
    bad(link_inertia((1.0, 1.0, 1.0, 1.5, 0.0, 0.0)), r"^joints\[2\]\.link\.inertia: not positive")


def test_triangle_inequality_with_its_documented_slack():
    slack = sp.INERTIA_SLACK
    ok(link_inertia((1e-4, 1e-4, 2e-4 * (1 + slack / 2), 0, 0, 0)))  # within the slack
    ok(link_inertia((1e-4, 1e-4, 2e-4, 0, 0, 0)))  # a flat plate: I1 + I2 = I3
    bad(link_inertia((1e-4, 1e-4, 2e-4 * (1 + 2 * slack), 0, 0, 0)), r"break the triangle")
    bad(link_inertia((1e-5, 5e-5, 1e-4, 0, 0, 0)), r"^joints\[2\]\.link\.inertia: principal")
    bad(lambda: with_platform(inertia=(0.01, 0.05, 0.1)), r"^platform\.inertia: principal")


# --- the fixed frames and names -------------------------------------------------------------------


def test_fixed_frames_name_their_toml_keys():
    bad(lambda: replace(X8, mount_xyz=(0.0, 0.0)), r"^mount\.xyz: must have 3")
    bad(lambda: replace(X8, mount_rpy=(0.0, math.inf, 0.0)), r"^mount\.rpy\[1\]: must be")
    bad(lambda: replace(X8, ee_xyz=(0.0, 0.0, 0.0, 0.0)), r"^end_effector\.xyz: must have 3")
    bad(lambda: replace(X8, ee_rpy=(math.nan, 0.0, 0.0)), r"^end_effector\.rpy\[0\]: must be")


def test_an_arm_needs_a_joint():
    bad(lambda: replace(X8, joints=()), r"^joints: the arm needs at least one joint")


def test_names_non_empty_and_unique_across_links_and_joints():
    bad(lambda: replace(X8, base_link=""), r"^base_link: must be a non-empty")
    bad(lambda: replace(X8, ee_link=""), r"^end_effector\.name: must be a non-empty")
    bad(lambda: replace(X8, ee_link=X8.base_link), r"^end_effector\.name: name 'base_link' is used")
    bad(lambda: with_joint(1, name="pan"), r"^joints\[1\]\.name: name 'pan' is used twice")
    bad(lambda: with_joint(0, name=X8.ee_link), r"^joints\[0\]\.name: name 'end_effector' is used")
    bad(lambda: with_joint(1, link_name="pan"), r"^joints\[1\]\.link\.name: name 'pan' is used")
    bad(lambda: with_joint(2, link_name=""), r"^joints\[2\]\.link\.name: must be a non-empty")


EXPORT_NAMES = [
    "world",
    "arm_mount",
    sp.MOUNT_LINK,
    "platform_fixed",
    "end_effector_joint",
    *(f"platform_{d}" for d in sp.PLATFORM_DOFS),
    *(f"platform_{d}_link" for d in sp.PLATFORM_DOFS),
]


def test_reserved_names_are_exactly_the_ones_the_urdf_export_adds():
    assert sp.reserved_names("end_effector") == set(EXPORT_NAMES)
    assert "tip_joint" in sp.reserved_names(
        "tip"
    ) and "end_effector_joint" not in sp.reserved_names("tip")


@pytest.mark.parametrize("name", EXPORT_NAMES)
def test_a_name_the_export_adds_is_refused_for_any_link_or_joint(name):
    bad(lambda: with_joint(1, name=name), rf"^joints\[1\]\.name: name '{name}' is reserved")
    bad(lambda: with_joint(2, link_name=name), rf"^joints\[2\]\.link\.name: name '{name}' is res")
    bad(lambda: replace(X8, base_link=name), rf"^base_link: name '{name}' is reserved")


def test_look_alikes_of_reserved_names_are_fine():
    ok(lambda: with_joint(1, name="World"))
    ok(lambda: with_joint(1, name="platform_x_joint"))
    ok(lambda: replace(X8, ee_link="tip", base_link="end_effector_joint"))
