"""The examples run as their docstrings say."""

import subprocess
import sys
from pathlib import Path

import numpy as np

from aeromanip.experiment.runlog import read_summary
from aeromanip.experiment.runner import run_scenarios
from aeromanip.experiment.scenario import load_scenarios

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def test_user_task_example_holds_the_point_and_the_height():
    proc = subprocess.run(
        [sys.executable, str(EXAMPLES / "user_task.py")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    last = proc.stdout.strip().splitlines()[-1].split()
    err_mm, z, status = float(last[1]), float(last[2]), last[-1]
    assert status == "ok" and err_mm < 0.5 and abs(z - 1.15) < 2e-3


def test_extending_scenario_flies_the_urdf_arm(tmp_path):
    scenarios = load_scenarios(EXAMPLES / "scenarios" / "flight-urdf-arm.toml", ["duration=10"])
    sc = scenarios[""]
    assert sc.robot.name == "urdf-arm" and sc.strategy == "hierarchical"
    run_scenarios(scenarios, tmp_path, progress=False, figures=False)
    s = read_summary(tmp_path / "summary.json")
    assert s["solver_failures"] == 0 and s["max_bound_violation"] <= 1e-6
    assert s["min_clearance_m"] >= 0.1 - 1e-6 and np.isfinite(s["ee_rmse_m"])
