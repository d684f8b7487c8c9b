"""The examples run as their docstrings say, and what they print holds against a second
measurement: the CLI on the same scenario, a run flown in-process, the vehicle's truth
log, IPOPT against the SQP, tracking alone against the hierarchy.

Each example runs as a user runs it (``python examples/NAME.py``, a fresh interpreter);
its last line carries its key figure.
"""

import ast
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from aeromanip.experiment import RunLog, load_scenarios, read_summary, run_scenarios, simulate

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
CLI = [sys.executable, "-m", "aeromanip.cli"]
NUMBER = r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?"


def run_example(name: str, *args: str, timeout: float = 120, env: dict | None = None) -> list[str]:
    """The example's stdout lines (it must exit 0)."""
    proc = subprocess.run(
        [sys.executable, str(EXAMPLES / name), *args],
        capture_output=True, text=True, timeout=timeout, env=env,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout.strip().splitlines()


def numbers(line: str) -> list[float]:
    return [float(v) for v in re.findall(NUMBER, line)]


def after(line: str, label: str) -> float:
    """The number that follows ``label`` in ``line``."""
    m = re.search(re.escape(label) + r"\s*(" + NUMBER + ")", line)
    assert m, f"no {label!r} in {line!r}"
    return float(m.group(1))


def test_user_task_example_holds_the_point_and_the_height():
    last = run_example("user_task.py")[-1].split()
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


def test_user_task_options_from_the_scenario_match_the_cli_run(tmp_path):
    lines = run_example("scenario_user_task.py")
    assert lines[0] == "task 'height' is PlatformHeight(z_ref=1.15)"
    z_ref, z_final, rmse_mm = numbers(lines[-1])
    assert z_ref == 1.15 and abs(z_final - 1.15) < 2e-3 and rmse_mm < 0.5
    # the same scenario through the command line: the option recorded, the same flight
    env = os.environ | {"PYTHONPATH": os.pathsep.join([str(EXAMPLES), *sys.path])}
    toml = str(EXAMPLES / "scenarios" / "user-task.toml")
    out = tmp_path / "cli"
    proc = subprocess.run(
        [*CLI, "run", toml, "--out", str(out), "--quiet", "--no-mcap"],
        capture_output=True, text=True, env=env, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "z_ref = 1.15" in (out / "config.toml").read_text()
    assert abs(RunLog.load(out).column("z")[-1] - z_final) < 1e-3
    bad = subprocess.run(
        [*CLI, "run", toml, "--check", "--set", "tasks.height.z_rf=1", "--out", str(out / "x")],
        capture_output=True, text=True, env=env, timeout=60,
    )  # fmt: skip
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1, bad.stderr
    assert "tasks.height.z_rf: unknown key (PlatformHeight takes z_ref (a number)" in bad.stderr


def test_physics_by_hand_reaches_the_point_on_mujocos_end_effector():
    lines = run_example("physics_by_hand.py")
    (err_mm, duration) = numbers(lines[-1])
    assert duration == 10.0 and err_mm < 5.0  # measured on MuJoCo's (tilted) body, not the model
    *_, (t, _, roll, pitch, _) = [numbers(line) for line in lines[1:-1]]
    assert t == 10.0 and abs(roll) < 1.0 and abs(pitch) < 1.0  # settled: level again


def test_user_reference_is_followed():
    lines = run_example("user_reference.py")
    rmse_mm, max_mm = numbers(lines[-1])
    assert rmse_mm < 1.0 and max_mm < 5.0
    # the printed reference is the circle: radius 0.15 m about (-0.15, 0, 0.6)
    for line in lines[1:-1]:
        _, rx, ry, rz, *_ = numbers(line)
        assert np.hypot(rx + 0.15, ry) == pytest.approx(0.15, abs=1e-3) and rz == 0.6


def test_backend_comparison_costs_agree_with_ipopt():
    lines = run_example("backend_comparison.py")
    rows = {line.split()[0]: numbers(line) for line in lines[1:4]}
    assert set(rows) == {"ipopt", "sqp", "sqp-rti"}
    ipopt = rows["ipopt"]
    for name in ("sqp", "sqp-rti"):
        median_ms, max_ms, cost, rmse_mm = rows[name]
        assert cost == pytest.approx(ipopt[2], rel=1e-3 if name == "sqp" else 1e-2), name
        assert rmse_mm == pytest.approx(ipopt[3], abs=0.01), name
        assert 0 < median_ms <= max_ms
    sqp_ratio, rti_ratio, _ = numbers(lines[-1])
    assert abs(sqp_ratio - 1) < 1e-3 and abs(rti_ratio - 1) < 1e-2


def test_three_levels_keep_level_zero_and_serve_the_lower_ones():
    lines = run_example("hierarchy_three_levels.py")
    alone = numbers(lines[1].removeprefix("tracking alone"))
    three = numbers(lines[2].removeprefix("  three levels"))
    assert len(lines) == 8 and lines[3].startswith("level 0") and lines[5].startswith("level 2")
    # level 0 (tracking) no worse than flying it alone, beyond the hierarchy's tolerance
    assert three[0] <= alone[0] + 0.05  # [mm]
    worsened = after(lines[6], "at most:")
    assert 0 <= worsened < 11 * 1e-6 or abs(worsened) < 1e-9  # abs_tol per stage, N + 1 stages
    assert three[1] < 0.5 * alone[1] and three[2] < alone[2]  # the CoG and posture improve


def test_sweep_results_match_the_same_run_flown_in_process(tmp_path):
    pytest.importorskip("ray")
    out = tmp_path / "sweep"
    env = os.environ | {"RAY_USAGE_STATS_ENABLED": "0"}
    lines = run_example("sweep_local.py", str(out), timeout=180, env=env)
    cog0, cog1 = after(lines[-1], "CoG offset"), after(lines[-1], "(weight 0) ->")
    assert lines[-1].startswith("sweep: 2 runs on 2 workers") and cog1 < cog0
    rows = {float(r.split()[0]): numbers(r)[:3] for r in lines[1:-1]}
    (sc,) = load_scenarios(
        "waypoints", ["duration=6", "tasks.cog.weight=1"], "hierarchical"
    ).values()
    s = simulate(sc).summary()
    assert rows[1.0][1] == pytest.approx(1e3 * s["ee_rmse_m"], abs=1e-3)
    assert rows[1.0][2] == pytest.approx(1e3 * s["cog_xy_mean_m"], abs=0.01)


def test_replay_renders_stills_of_the_saved_run(tmp_path):
    image = pytest.importorskip("PIL.Image")
    lines = run_example("replay_still.py", str(tmp_path))
    assert lines[-1].startswith(f"replay: {tmp_path / 'still-5s.png'}, 640x480 px")
    stills = [
        np.asarray(image.open(tmp_path / f"still-{t}s.png").convert("RGB"), float) for t in (1, 5)
    ]
    assert all(s.shape == (480, 640, 3) and s.std() > 10 for s in stills)  # a picture, not a fill
    assert np.abs(stills[0] - stills[1]).mean() > 1.0  # the robot moved between 1 s and 5 s
    assert read_summary(next((tmp_path / "run").rglob("summary.json")))["steps"] == 12


@pytest.mark.realtime  # two processes against the wall clock, as tests/test_flight_mavlink.py
def test_mavlink_loop_flies_the_sitl_and_its_truth_follows_the_reference(tmp_path):
    pytest.importorskip("pymavlink")
    lines = run_example("mavlink_sitl.py", str(tmp_path), timeout=120)
    last = lines[-1]
    steps, rmse_mm = after(last, "mavlink:"), after(last, "EE RMSE")
    misses, rate_hz = after(last, "mm,"), after(last, "setpoints")
    assert steps == 10 and misses == 0 and rate_hz >= 20
    summary = json.loads((tmp_path / "fly" / "summary.json").read_text())
    assert summary["ending"] == "completed" and summary["flight_ok"]
    truth = RunLog.load(tmp_path / "sitl")  # the vehicle's own log, not the runtime's
    t = truth.column("t_mission")
    mission = np.isfinite(t) & (t >= 0) & (t <= 5.0)
    err = np.stack([truth.column(f"ee_{c}") - truth.column(f"ref_{c}") for c in "xyz"], 1)[mission]
    truth_rmse_mm = 1e3 * float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    assert mission.sum() > 50 and truth_rmse_mm < 20.0
    assert truth_rmse_mm < 3 * rmse_mm + 2.0  # as measured over the link: the same flight


def test_every_example_is_in_the_gallery_and_says_how_to_run_it():
    gallery = (EXAMPLES.parent / "docs" / "gallery.md").read_text()
    files = sorted(EXAMPLES.glob("*.py")) + sorted((EXAMPLES / "scenarios").glob("*.toml"))
    assert len(files) >= 10
    for path in files:
        assert f"examples/{path.relative_to(EXAMPLES)}" in gallery, path.name
        if path.suffix == ".py":
            doc = ast.get_docstring(ast.parse(path.read_text())) or ""
            assert doc.startswith("Example: ") and "Run: ``python examples/" in doc, path.name
            assert "from aeromanip." not in re.sub(
                r"from aeromanip\.(nmpc|sim|experiment|references|tasks|sweep|viz|runtime|"
                r"mavlink|robot) import",
                "",
                path.read_text(),
            ), f"{path.name} imports from a module inside a sub-package"
