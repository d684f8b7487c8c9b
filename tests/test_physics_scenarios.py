"""The NMPC flying the full-dynamics UAM (MuJoCo): the paper's claim behind the CoG task."""

import mujoco
import numpy as np
import pytest

from aeromanip.runlog import RunLog, read_summary
from aeromanip.runner import run_scenarios
from aeromanip.scenario import load_scenarios


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    """The built-in flight-cog comparison (the flight with and without the CoG level)."""
    d = tmp_path_factory.mktemp("flight-cog")
    run_scenarios(load_scenarios("flight-cog", ["duration=60"]), d, progress=False,
                  figures=False)
    return {name: d / name for name in ("hierarchical", "tracking-only")}


def test_physics_log_has_tilt_motors_and_arm_torque(flights):
    log = RunLog.load(flights["hierarchical"])
    for col in ("roll", "pitch", "arm_torque", "thrust_total", "motor_1", "motor_4"):
        assert col in log, col
    s = read_summary(flights["hierarchical"] / "summary.json")
    assert s["roll_pitch_mean_deg"] >= 0.0 and s["arm_torque_mean_nm"] >= 0.0
    # roll and pitch are the attitude at each row's time, like the state: level at t = 0
    # (reset to hover); motor thrusts and arm torque are means over the row's period
    assert log.column("roll")[0] == 0.0 and log.column("pitch")[0] == 0.0
    assert np.abs(log.column("roll")[1:]).max() > 0.0
    # the model flown is in the run directory, loadable by MuJoCo (and its viewer)
    model = mujoco.MjModel.from_xml_path(str(flights["hierarchical"] / "robot.xml"))
    assert model.nu == 8 + 3  # the X8's rotors (4 coaxial pairs) + arm servos


def test_cog_alignment_lowers_tilt_and_arm_torque_at_equal_tracking(flights):
    hier = read_summary(flights["hierarchical"] / "summary.json")
    only = read_summary(flights["tracking-only"] / "summary.json")
    assert hier["arm_torque_mean_nm"] < 0.2 * only["arm_torque_mean_nm"]
    assert hier["roll_pitch_mean_deg"] < only["roll_pitch_mean_deg"]
    # equal tracking: within 1 mm RMS of each other (both physical, tilt included)
    assert abs(hier["ee_rmse_m"] - only["ee_rmse_m"]) < 1e-3
    # the rotors do less differential work to hold the arm's moment
    assert hier["rotor_spread_mean_n"] < 0.5 * only["rotor_spread_mean_n"]
    # the instantaneous spread, averaged, is at least that of the period-mean thrusts
    log = RunLog.load(flights["tracking-only"])
    m = np.column_stack([log.column(f"motor_{i}") for i in range(1, 5)])
    assert np.all(log.column("rotor_spread") >= m.max(1) - m.min(1) - 1e-9)
    assert only["rotor_spread_mean_n"] == pytest.approx(np.mean(log.column("rotor_spread")))
    # both variants' summaries side by side in the scenario's directory
    both = read_summary(flights["hierarchical"].parent / "summary.json")
    for key in ("ee_rmse_m", "roll_pitch_mean_deg", "arm_torque_mean_nm", "rotor_spread_mean_n"):
        assert both["hierarchical"][key] == hier[key] and both["tracking-only"][key] == only[key]


def test_flight_in_physics_keeps_joints_clearance_and_box(flights):
    log = RunLog.load(flights["hierarchical"])
    s = read_summary(flights["hierarchical"] / "summary.json")
    assert s["solver_failures"] == 0
    assert s["max_bound_violation"] <= 1e-6, log.bound_violation()
    assert s["min_clearance_m"] >= 0.1 - 1e-6
    for dof, (lo, hi) in {"x": (-0.6, 0.6), "y": (-0.6, 0.6), "z": (0.8, 1.5)}.items():
        assert lo <= log.column(dof).min() and log.column(dof).max() <= hi
