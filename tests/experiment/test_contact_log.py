"""A physics run with surfaces logs the end effector's contact every step; one without
logs exactly the columns it did before."""

from pathlib import Path

import numpy as np
import pytest

from aeromanip.experiment.closed_loop import log_columns, make_simulator
from aeromanip.experiment.runlog import RunLog, read_summary
from aeromanip.experiment.runner import run_scenarios
from aeromanip.experiment.scenario import load_scenarios
from aeromanip.sim.contact_sensor import CONTACT_COLUMNS

# the flight's end effector starts at z = 0.6 m: its 1 cm probe 3 mm into this floor
TOUCH = """
extends = "flight"
name = "flight-touch"
duration = 1.5

[[physics.surfaces]]
kind = "wall"
point = [0.0, 0.0, 0.593]
normal = [0.0, 0.0, 1.0]
size = [0.4, 0.4]
friction = 0.3
"""


@pytest.fixture(scope="module")
def touch_run(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("touch")
    (d / "touch.toml").write_text(TOUCH)
    run_scenarios(load_scenarios(d / "touch.toml"), d / "out", progress=False, figures=False)
    return d / "out"


def test_contact_columns_are_logged_every_step(touch_run):
    log = RunLog.load(touch_run)
    assert log.names[-len(CONTACT_COLUMNS) :] == list(CONTACT_COLUMNS)
    contact, fn, ft = (log.column(c) for c in ("contact", "f_n", "f_t"))
    f = np.stack([log.column(c) for c in ("f_x", "f_y", "f_z")], axis=1)
    assert len(log) == 3 and set(contact.tolist()) <= {0.0, 1.0}
    # at t = 0 the probe presses into the floor: pushed up, the force along the normal
    assert contact[0] == 1.0 and fn[0] > 0.0 and f[0, 2] == pytest.approx(fn[0])
    assert np.all(fn >= 0.0) and np.all(ft >= 0.0)
    free = contact == 0.0
    assert np.all(fn[free] == 0.0) and np.all(f[free] == 0.0)
    s = read_summary(touch_run / "summary.json")
    assert s["contact_share"] == pytest.approx(contact.mean())
    assert s["f_n_max_n"] == pytest.approx(fn.max())


def test_the_resolved_config_keeps_the_surfaces(touch_run):
    (sc,) = load_scenarios(touch_run / "config.toml").values()
    assert sc.physics["surfaces"][0]["point"] == [0.0, 0.0, 0.593]
    assert 'name="surface_1"' in (touch_run / "robot.xml").read_text()


def test_no_surfaces_no_contact_columns():
    (sc,) = load_scenarios("flight", ["duration=1"]).values()
    columns = log_columns(sc, make_simulator(sc))
    assert not set(CONTACT_COLUMNS) & set(columns)
