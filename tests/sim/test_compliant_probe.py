"""The spring-loaded probe (``physics.probe``): Hooke's law through its slide, the wrist
sensor reading the contact through the spring, and the NMPC's series spring against
MuJoCo's static contact force at several pushes (the UAM hovering, its probe on a wall)."""

import math

import numpy as np
import pytest

from aeromanip.errors import ConfigError
from aeromanip.robot.loader import load_robot
from aeromanip.sim.contact import PROBE_SLIDE, read_probe
from aeromanip.sim.physics import PhysicsSimulator
from aeromanip.tasks.contact import ContactSpring

SPEC = load_robot("x8-3dof")
X0 = np.array([0.011292851, 0.0, 1.020614110, 0.0, 0.0, 0.6, -1.2])  # contact-wall's start
AXIS = [math.cos(0.6), 0.0, -math.sin(0.6)]  # EE frame: world +x in this posture
PROBE = dict(stiffness=150.0, damping=3.0, travel=0.04, axis=AXIS)
SERIES = 138.0  # [N/m] the NMPC's spring: probe and wall in series (the contact-wall's)
PUSHES = (0.02, 0.1, 0.3)  # [m] the position setpoint moved into the wall


@pytest.fixture(scope="module")
def pressed() -> list[dict]:
    """Per push, the last 0.3 s of 3 s (10 Hz samples): EE, forces, slide, probe axis."""
    free = PhysicsSimulator(SPEC)
    free.reset(X0)
    ee0 = free.ee_position()
    point = (ee0 + np.array([0.01, 0.0, 0.0])).tolist()  # the probe touching it
    wall = dict(kind="wall", point=point, normal=[-1.0, 0, 0], size=[1, 1], friction=0.3)
    rows = []
    for push in PUSHES:
        sim = PhysicsSimulator(SPEC, surfaces=[wall], probe=PROBE)
        sim.reset(X0)
        plan = np.tile(sim.true_state(), (11, 1))
        plan[:, 0] += push
        slide = sim.model.joint(PROBE_SLIDE).qposadr[0]
        for k in range(30):
            sim.advance(np.zeros(SPEC.nx), plan, 0.1)
            if k >= 27:
                rot = sim.data.site_xmat[sim._ee].reshape(3, 3)
                rows.append(
                    dict(
                        ee=sim.ee_position(),
                        f_n=sim.extras()["f_n"],
                        wrench=sim.measured_wrench(),
                        slide=float(sim.data.qpos[slide]),
                        axis=rot @ np.array(AXIS),
                        point=wall["point"],
                    )
                )
    return rows


def test_the_spring_carries_the_contact_force_along_its_axis(pressed):
    """Hooke's law: ``k delta`` is the contact force's part along the probe's axis (the
    tip's 10 g and its damper moving slowly take < 1 %)."""
    for r in pressed:
        along = float(-r["wrench"][:3] @ r["axis"])  # the push back along the axis
        assert r["slide"] > 0 and r["slide"] < PROBE["travel"]
        assert PROBE["stiffness"] * r["slide"] == pytest.approx(along, rel=0.01, abs=0.005)
        # the sensor reads it through the spring (the tip's inertia: < 1e-3 N)
        assert float(r["wrench"][:3] @ [-1.0, 0, 0]) == pytest.approx(r["f_n"], abs=1e-3)
    assert min(r["f_n"] for r in pressed) < 0.4 and max(r["f_n"] for r in pressed) > 4.0


def test_the_series_spring_matches_mujocos_static_force(pressed):
    """138 N/m from the touching point: within 0.05 N (1 % of the largest) over
    0.3-4.9 N, at the true EE (the platform pitched up to 9.5 deg to push)."""
    spring = ContactSpring(tuple(pressed[0]["point"]), (-1.0, 0.0, 0.0), SERIES, 0.01, 0.0, 1e-4)
    for r in pressed:
        assert spring.normal_force(r["ee"]) == pytest.approx(r["f_n"], abs=0.05)


def test_no_probe_option_changes_nothing_without_surfaces_and_bad_ones_are_one_line():
    assert "slide" not in PhysicsSimulator(SPEC, probe=PROBE).to_xml()  # no surface: no probe
    with pytest.raises(ConfigError, match=r"^physics\.probe\.travel: missing"):
        read_probe({"stiffness": 100.0})
    with pytest.raises(ConfigError, match=r"^physics\.probe\.stifness: unknown key"):
        read_probe({"stifness": 100.0, "travel": 0.01})
    with pytest.raises(ConfigError, match=r"^physics\.probe\.axis: must not be zero"):
        read_probe({"stiffness": 100.0, "travel": 0.01, "axis": [0, 0, 0]})
    with pytest.raises(ConfigError, match=r"^physics\.probe\.stiffness: "):
        PhysicsSimulator.check_options({"probe": {"stiffness": -1.0, "travel": 0.01}})
